"""Vertical velocity and height from gravity-compensated specific force (seed 002 eq. 6-8).

    a_up = (q ⊗ f_body ⊗ q*)_z − g          (eq. 6-7: rotate the specific force to ENU, add g_n = [0, 0, −g])
    dV_z/dt = a_up − V_z / tau_v            (eq. 8 integrand; optional leak pulls V_z to 0 with time constant tau_v)
    dH/dt   = V_z − H / tau_h               (eq. 8: H = H0 + ∫ V_z dt; optional leak for long unattended runs)
integrated with the trapezoidal rule between samples (sample 0 holds H0, V0), and V_z = 0 on samples flagged as
rest (zero-velocity update) when rest flags are given.
The Coriolis and transport-rate terms of eq. 7 are left out: below 5 m/s they are < 1e-3 m/s², far under a MEMS
accelerometer's bias. Pure double integration drifts quadratically with any residual acceleration bias; the leak
and zero-velocity options trade that drift for a high-pass on slow true motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gateway.fusion import quaternion as quat
from gateway.fusion.base import FloatArray
from gateway.fusion.quaternion import njit


@dataclass(frozen=True)
class HeightSettings:
    """Integration settings; a tau of 0 (or inf) disables that leak."""

    gravity_m_s2: float = quat.GRAVITY_M_S2
    velocity_leak_tau_s: float = 0.0
    height_leak_tau_s: float = 0.0


def vertical_acceleration(q: ArrayLike, acc_m_s2: ArrayLike, gravity_m_s2: float = quat.GRAVITY_M_S2) -> FloatArray:
    """Up component of the kinematic acceleration (m/s²): rotate specific force to ENU, remove gravity."""
    a: FloatArray = quat.rotate(q, acc_m_s2)[..., 2] - gravity_m_s2
    return a


def gravity_from_rest(q: ArrayLike, acc_m_s2: ArrayLike) -> float:
    """Local g as the accelerometer sees it (m/s²): mean up-component of specific force over rest samples.
    Using it instead of 9.81 removes the vertical part of the accelerometer's scale/offset error."""
    return float(np.mean(quat.rotate(q, acc_m_s2)[..., 2]))


def _leak(tau: float) -> float:
    return 0.0 if tau <= 0.0 or not np.isfinite(tau) else 1.0 / tau


@njit
def _integrate(a_up: FloatArray, rest: NDArray[np.bool_], dt_s: float, v0: float, h0: float, kv: float,
               kh: float) -> FloatArray:
    n = a_up.shape[0]
    out = np.empty((n, 2))
    v, h = v0, h0
    for i in range(n):
        if i > 0:
            v, h = _trapezoid_step(v, h, a_up[i - 1], a_up[i], dt_s, kv, kh)
        if rest[i]:
            v = 0.0
        out[i, 0] = h
        out[i, 1] = v
    return out


@njit
def _trapezoid_step(v: float, h: float, a_prev: float, a: float, dt_s: float, kv: float,
                    kh: float) -> tuple[float, float]:
    """One trapezoidal step of dV/dt = a − kv V, dH/dt = V − kh H (implicit in the leak terms)."""
    v_new = (v * (1.0 - 0.5 * kv * dt_s) + 0.5 * (a_prev + a) * dt_s) / (1.0 + 0.5 * kv * dt_s)
    h_new = (h * (1.0 - 0.5 * kh * dt_s) + 0.5 * (v + v_new) * dt_s) / (1.0 + 0.5 * kh * dt_s)
    return v_new, h_new


def integrate_height(
    q: ArrayLike,
    acc_m_s2: ArrayLike,
    dt_s: float,
    settings: HeightSettings | None = None,
    rest: ArrayLike | None = None,
    v0_m_s: float = 0.0,
    h0_m: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Height (m) and vertical velocity (m/s), shape (N,) each, from attitudes (N, 4) and specific force (N, 3)."""
    s = settings or HeightSettings()
    a_up = np.ascontiguousarray(vertical_acceleration(q, acc_m_s2, s.gravity_m_s2))
    mask = np.zeros(a_up.shape[0], dtype=bool) if rest is None else np.asarray(rest, dtype=bool)
    out = _integrate(a_up, mask, float(dt_s), float(v0_m_s), float(h0_m), _leak(s.velocity_leak_tau_s),
                     _leak(s.height_leak_tau_s))
    return out[:, 0].copy(), out[:, 1].copy()


class HeightEstimator:
    """Streaming form of `integrate_height`: feed attitude and specific force per sample."""

    def __init__(self, settings: HeightSettings | None = None, h0_m: float = 0.0, v0_m_s: float = 0.0) -> None:
        self.settings = settings or HeightSettings()
        self.height_m = h0_m
        self.velocity_m_s = v0_m_s
        self._kv = _leak(self.settings.velocity_leak_tau_s)
        self._kh = _leak(self.settings.height_leak_tau_s)
        self._a_prev: float | None = None

    def update(self, q: ArrayLike, acc_m_s2: ArrayLike, dt_s: float, at_rest: bool = False) -> tuple[float, float]:
        """Advance to this sample (the first one only sets the start); returns (height m, vertical velocity m/s)."""
        a_up = float(vertical_acceleration(q, acc_m_s2, self.settings.gravity_m_s2))
        if self._a_prev is not None:
            self.velocity_m_s, self.height_m = _trapezoid_step(
                self.velocity_m_s, self.height_m, self._a_prev, a_up, float(dt_s), self._kv, self._kh)
        self._a_prev = a_up
        if at_rest:
            self.velocity_m_s = 0.0
        return self.height_m, self.velocity_m_s


def window_errors(
    q: ArrayLike,
    acc_m_s2: ArrayLike,
    ref_z_m: ArrayLike,
    dt_s: float,
    window_s: float,
    mask: ArrayLike,
    gravity_m_s2: float,
    v0_span: int = 5,
) -> FloatArray:
    """Height error (m) at the end of consecutive windows of `window_s` inside `mask`, each started from the
    reference height and the reference vertical velocity (central difference over ±`v0_span` samples): a measure
    of the drift of open-loop integration over short spans, e.g. on BROAD against `opt_pos[:, 2]`."""
    qa, acc, z = np.asarray(q, dtype=np.float64), np.asarray(acc_m_s2, dtype=np.float64), np.asarray(ref_z_m)
    idx = np.flatnonzero(np.asarray(mask, dtype=bool))
    w = int(round(window_s / dt_s))
    settings = HeightSettings(gravity_m_s2=gravity_m_s2)
    errors = []
    if idx.size == 0:
        return np.zeros(0)
    for s0 in range(max(int(idx[0]), v0_span), int(idx[-1]) - w, w):
        seg = z[s0 - v0_span: s0 + w]
        if not np.all(np.isfinite(seg)) or s0 + v0_span >= z.shape[0]:
            continue
        v0 = (z[s0 + v0_span] - z[s0 - v0_span]) / (2 * v0_span * dt_s)
        h, _ = integrate_height(qa[s0: s0 + w], acc[s0: s0 + w], dt_s, settings, v0_m_s=float(v0), h0_m=float(z[s0]))
        errors.append(h[-1] - z[s0 + w - 1])
    return np.asarray(errors, dtype=np.float64)
