"""The gyroscope's bias from how the magnetic field turns in the body frame over a short window (pure numpy).

Why: a hook already swinging when the gateway starts cannot give its gyro bias from a rest window, and over the
0.5-s warm-up the swing rate's level and the bias are one number to the gyroscope. The filter then carried the
bias (about 1 °/s on an MPU-6050, 2.2 °/s on fresh crane 2519) into the start swing: Θ read about 1° off for the
first 1.5 s of a 24-m rope's slow swing, until the pendulum's curvature had told the two apart. The
magnetometer sees the same turn without a bias: the earth's field is fixed, so in the body frame it turns by the
true rotation. Its hard iron is fixed in the body too, so it is fitted beside the field, not taken for a turn.

Model, sample k of the window (frame 0 = the body at the first sample): the body turns by `R_k` (the gyroscope
integrated, body k → body 0); with a bias `b` the true turn is `(I - [A_k b]×) R_k` to first order, with
`A_k = Σ_{0<j≤k} R_j dt`. So the field reads `m_k = R_kᵀ m_0 - R_kᵀ [m_0]× A_k b + h + noise`: linear in the field
at the start `m_0`, the bias `b` and the hard iron `h` once `m_0` in the bias term is taken from a first pass.
Priors on `b` and `h` keep what the window cannot see (the bias along the field, hard iron on a hook that does not
turn) at their prior; the fit's residual gives the field noise, so a field that does not just turn (a disturbance
near steel) widens the answer instead of misleading it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.fusion.base import FloatArray
from gateway.fusion.quaternion import exp_gyro_step, multiply, to_matrix

MIN_SAMPLES = 20
"""Fewer samples than this (0.2 s at 100 Hz) say too little about a turn."""


@dataclass(frozen=True)
class FieldBias:
    """A bias estimate from the field's turn: `bias_rad_s` (3,), body; `cov` (3, 3), rad²/s²; `residual_uT`, the
    fit's rms residual per axis (the field noise it assumed, at least `noise_floor_uT`)."""

    bias_rad_s: FloatArray
    cov: FloatArray
    residual_uT: float


def body_turns(gyr_rad_s: FloatArray, dt_s: float) -> FloatArray:
    """Rotation matrices (N, 3, 3) from the body at sample k to the body at sample 0, the gyroscope integrated
    per step at the mean of the step's two samples (a swing's rate changes by 0.2 °/s a step on a 2-m rope, and
    either sample alone reads that as a bias of half of it)."""
    n = gyr_rad_s.shape[0]
    steps = exp_gyro_step(0.5 * (gyr_rad_s[:-1] + gyr_rad_s[1:]), dt_s)
    q = np.empty((n, 4))
    q[0] = (1.0, 0.0, 0.0, 0.0)
    for k in range(1, n):
        q[k] = multiply(q[k - 1], steps[k - 1])
    out: FloatArray = to_matrix(q)
    return out


def gyro_bias_from_field(gyr_rad_s: FloatArray, mag_uT: FloatArray, dt_s: float, bias_std_rad_s: float,
                         hard_iron_std_uT: float, noise_floor_uT: float = 0.1,
                         iterations: int = 2) -> FieldBias | None:  # fmt: skip
    """The gyroscope's bias (body, rad/s) that makes its integrated turn match the field's over the window
    (N, 3) samples of both, with priors N(0, `bias_std_rad_s`²) per axis on the bias and N(0, `hard_iron_std_uT`²)
    on the hard iron (module docstring). None if the window is too short or the field is too weak to read.

    The bias enters the next pass's integration, so a bias of several °/s on a hook twisting fast is not left to
    the first-order model alone."""
    gyr = np.asarray(gyr_rad_s, dtype=np.float64)
    mag = np.asarray(mag_uT, dtype=np.float64)
    n = min(gyr.shape[0], mag.shape[0])
    if n < MIN_SAMPLES or bias_std_rad_s <= 0.0:
        return None
    gyr, mag = gyr[:n], mag[:n]
    bias = np.zeros(3)
    residual = noise_floor_uT
    for _ in range(max(1, iterations)):
        turns = body_turns(gyr - bias, dt_s)  # (N, 3, 3): body k -> body 0
        m0 = np.einsum("kij,kj->i", turns, mag) / n  # the field in frame 0, hard iron and bias left in
        if float(np.linalg.norm(m0)) < 5.0:  # no field to read a turn from (µT; the earth's is 25-65)
            return None
        ahead = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(turns[1:], axis=0) * dt_s])  # A_k
        skew = np.array([[0.0, -m0[2], m0[1]], [m0[2], 0.0, -m0[0]], [-m0[1], m0[0], 0.0]])
        rt = np.transpose(turns, (0, 2, 1))  # R_kᵀ
        jac = np.concatenate([rt, -rt @ skew @ ahead, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)  # (N, 3, 9)
        jac = jac.reshape(3 * n, 9)
        y = mag.reshape(3 * n)
        prior = np.zeros(9)
        prior[3:6] = 1.0 / bias_std_rad_s**2
        prior[6:9] = 1.0 / max(hard_iron_std_uT, 1e-6) ** 2
        centre = np.zeros(9)
        centre[3:6] = -bias  # the prior is on the whole bias, this pass fits its change
        info = jac.T @ jac
        for _ in range(2):  # the noise from the fit's own residual, then the fit weighted by it
            var = residual**2
            theta = np.linalg.solve(info / var + np.diag(prior), jac.T @ y / var + prior * centre)
            residual = max(noise_floor_uT, float(np.sqrt(np.mean((y - jac @ theta) ** 2) * 3 * n / max(3 * n - 9, 1))))
        step = theta[3:6]
        cov = np.linalg.inv(info / residual**2 + np.diag(prior))[3:6, 3:6]
        bias = bias + step
        if float(np.max(np.abs(step))) < 1e-5:
            break
    return FieldBias(bias, cov, residual)
