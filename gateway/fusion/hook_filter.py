"""A hook attitude filter that knows it hangs on a rope: an EKF on the spherical-pendulum state (filterpy + numba).

Why: on a swinging hook the accelerometer measures rope tension, which always points along the rope (body z),
so an AHRS that takes the accelerometer for gravity sees "level" and badly underestimates the swing angle Θ.
Here the tilt comes from the pendulum dynamics instead: gravity sets the rope's angular acceleration, so the
gyroscope (which measures the rope's swing rate) reveals where "down" is, and the tension magnitude
`T/m = g cos Θ + l |n'|²` (accelerometer z) pins the swing amplitude (seed 001 Fig. 1, eq. 6).

State (14): `p = (n_x, n_y)`, the horizontal part of the rope direction `n` (ENU, hook -> boom tip,
`n_z = sqrt(1 - |p|²)`); `v = p'`; the hook heading about the rope `α` (swing-twist split
`q = q_swing(n) ⊗ q_z(α)`, see gateway.fusion.hook) and its rate `α'`; the gyroscope bias `b` (rad/s, body);
the offset of the tension channel (m/s²); the equilibrium `e` of `p` (`-f/g` for a steady horizontal force `f`
per unit mass, e.g. wind); the gyroscope's x/y sensitivity `c` to the z rate (cross-axis coupling: a hook twisting
at ~1 rad/s would otherwise put ~0.005 rad/s of false swing rate into x/y and double the Θ error).

* Predict: RK4 of the pendulum `p'' = -(g/l)(n_z p - e + (p·e) p) - |n'|² p` (boom tip assumed still: trolley
  moves and gusts enter as process noise on `v`), `α` integrates `α'`; `α'`, `b`, offset and `e` random-walk,
  `c` is constant. `e` is observable because tension `g n_z` then has a component at the swing frequency
  ∝ `e · amplitude`.
* Update: gyroscope `ω_b(n, n', α, α') + b + (c_x, c_y, 0) ω_z` (exact kinematics of the split, as in
  devices.hook_physics); accelerometer z `T/m + [ω' × r + ω × (ω × r)]_z + offset` (lever arm `r` of the IMU
  from the rope axis) after subtracting the zero-g offset calibrated at rest; in 9D the magnetometer `Rᵀ m_ref`
  for heading only (its Jacobian is restricted to `α`, so hard-iron errors cannot tilt the estimate; likewise the
  tension row only informs the swing states and its offset).
* Jacobians are forward differences of numba kernels. `update()` feeds them to filterpy's
  ExtendedKalmanFilter; `run()` is a numba twin of the same steps (tests check they agree).
* Adaptive process noise: when the swing-rate innovation fails a χ² gate, its square is added to the rope-rate
  variance (an unmodelled push), so the state follows the gyroscope instead of bending bias and tilt.

Limits: the boom tip's acceleration is not observable from the hook IMU (equivalence principle), so during a
trolley move Θ is the swing about the vertical *assuming a still boom tip*; the estimate re-converges after it.
6D heading is a free gauge (starts at 0), so bearings and torsion are relative to the start heading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.quaternion import njit

N_STATE = 14
_P, _V, _ALPHA, _ALPHA_RATE, _BIAS, _ACC_BIAS = slice(0, 2), slice(2, 4), 4, 5, slice(6, 9), 9


@dataclass(frozen=True)
class HookFilterSettings:
    """Rope and noise model. Noise figures are per-sample standard deviations unless named a PSD."""

    rope_length_m: float = 10.0
    gravity_m_s2: float = 9.80665
    lever_arm_m: tuple[float, float, float] = (0.1, 0.0, 0.0)  # IMU position from the rope axis, body frame
    gyro_noise_rad_s: float = 0.0015  # MPU-6050: 0.05 °/s rms at 100 Hz, plus quantisation and scale errors
    acc_noise_m_s2: float = 0.15  # tension channel: white noise plus unmodelled lever-arm and scale terms
    mag_noise_uT: float = 30.0  # weak on purpose: hard-iron-biased heading fixes would jolt the swing estimate
    swing_accel_psd: float = 1e-4  # (rad/s²)²/Hz: wind, trolley moves and other unmodelled rope accelerations
    torsion_accel_psd: float = 1.0  # (rad/s²)²/Hz: the hook's twist is driven by the rope's torsion spring
    gyro_bias_psd: float = 1e-8  # (rad/s)²/s: bias random walk
    acc_bias_psd: float = 1e-6  # (m/s²)²/s: drift of the tension channel's offset
    equilibrium_psd: float = 1e-6  # rad²/s: drift of the equilibrium tilt (steady wind)
    surprise_gate: float = 16.0  # χ² (2 dof) gate on the swing-rate innovation for adaptive process noise
    init_swing_std: float = 0.02  # rad, per horizontal axis: hanging still at initialisation
    init_rate_std_rad_s: float = 0.02
    init_heading_std_rad: float = 0.05  # 6D: heading is a free gauge, start it tight at 0
    init_bias_std_rad_s: float = 0.03  # MPU-6050 residual start-up bias is about 1 °/s
    init_acc_offset_std_m_s2: float = 0.1  # left after the rest calibration (scale error × g, bias drift)
    init_equilibrium_std: float = 0.002  # rad: steady wind tilt at start
    init_cross_axis_std: float = 0.01  # gyro x/y sensitivity to the z rate (MPU-6050 cross-axis ±2 %)
    moving_swing_std: float = 0.3  # rad, per axis: priors after `assume_moving()` (started while swinging)
    moving_rate_std_rad_s: float = 0.3
    moving_acc_offset_std_m_s2: float = 0.5  # the window's mean tension is not g when swinging


# --- model kernels (numba, scalar code per sample) ---------------------------------------------------------------
# params: [g, l, r_x, r_y, r_z, m_ref_x, m_ref_y, m_ref_z, use_mag, surprise_gate]


@njit
def _attitude_rate(
    px: float, py: float, vx: float, vy: float, alpha: float, alpha_rate: float
) -> tuple[float, float, float, float, float, float, float]:
    """Scalar core of `attitude_and_rate`: `(q_w, q_x, q_y, q_z, ω_x, ω_y, ω_z)`.

    With `q_swing = (a, b, c, 0)` and its rate `(a', b', c', 0)`, the swing part of the body rate is
    `2 vec(q_swing* ⊗ q_swing') = 2 (a b' - b a', a c' - c a', c b' - b c')`; the twist `q_z(α)` turns it by `-α`
    about z and adds `α'` on z."""
    nz = math.sqrt(max(1.0 - px * px - py * py, 1e-6))
    vz = -(px * vx + py * vy) / nz
    s = math.sqrt(2.0 * (1.0 + nz))
    sd = vz / s
    a, b, c = 0.5 * s, -py / s, px / s
    ad, bd, cd = 0.5 * sd, -vy / s + py * sd / (s * s), vx / s - px * sd / (s * s)
    wx, wy, wz = 2.0 * (a * bd - b * ad), 2.0 * (a * cd - c * ad), 2.0 * (c * bd - b * cd)
    ct, st = math.cos(0.5 * alpha), math.sin(0.5 * alpha)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return (a * ct, b * ct + c * st, c * ct - b * st, a * st,
            ca * wx + sa * wy, -sa * wx + ca * wy, wz + alpha_rate)  # fmt: skip


@njit
def attitude_and_rate(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """`q = q_swing(n) ⊗ q_z(α)` and the body rate `2 vec(q* ⊗ q')` in rad/s for one state (14,)."""
    qw, qx, qy, qz, wx, wy, wz = _attitude_rate(x[0], x[1], x[2], x[3], x[4], x[5])
    return np.array([qw, qx, qy, qz]), np.array([wx, wy, wz])


@njit
def _pendulum_accel(
    px: float, py: float, vx: float, vy: float, g_over_l: float, ex: float, ey: float
) -> tuple[float, float]:
    """`p'' = -(g/l)(n_z p - e + (p·e) p) - |n'|² p`: horizontal part of `n''` for a pendulum whose equilibrium
    is tilted to `p = e` by a steady horizontal force `-g e` per unit mass (wind); `e = 0` is the free pendulum."""
    nz = np.sqrt(max(1.0 - px * px - py * py, 1e-6))
    vz = -(px * vx + py * vy) / nz
    k = g_over_l * (nz + px * ex + py * ey) + vx * vx + vy * vy + vz * vz
    return -k * px + g_over_l * ex, -k * py + g_over_l * ey


@njit
def process(x: FloatArray, dt_s: float, g_over_l: float) -> FloatArray:
    """State (14,) after `dt_s`: RK4 of the pendulum (`_pendulum_accel`), α integrates α'."""
    px, py, vx, vy, ex, ey = x[0], x[1], x[2], x[3], x[10], x[11]
    a1x, a1y = _pendulum_accel(px, py, vx, vy, g_over_l, ex, ey)
    h = 0.5 * dt_s
    a2x, a2y = _pendulum_accel(px + h * vx, py + h * vy, vx + h * a1x, vy + h * a1y, g_over_l, ex, ey)
    a3x, a3y = _pendulum_accel(
        px + h * (vx + h * a1x), py + h * (vy + h * a1y), vx + h * a2x, vy + h * a2y, g_over_l, ex, ey
    )
    a4x, a4y = _pendulum_accel(
        px + dt_s * (vx + h * a2x), py + dt_s * (vy + h * a2y), vx + dt_s * a3x, vy + dt_s * a3y, g_over_l, ex, ey
    )
    out = x.copy()
    out[0] = px + dt_s / 6.0 * (vx + 2.0 * (vx + h * a1x) + 2.0 * (vx + h * a2x) + (vx + dt_s * a3x))
    out[1] = py + dt_s / 6.0 * (vy + 2.0 * (vy + h * a1y) + 2.0 * (vy + h * a2y) + (vy + dt_s * a3y))
    out[2] = vx + dt_s / 6.0 * (a1x + 2.0 * a2x + 2.0 * a3x + a4x)
    out[3] = vy + dt_s / 6.0 * (a1y + 2.0 * a2y + 2.0 * a3y + a4y)
    out[4] = x[4] + dt_s * x[5]
    return out


@njit
def measurement(x: FloatArray, params: FloatArray) -> FloatArray:
    """Predicted `[gyr (3), acc_z (1), mag (3, zero unless params[8])]` (7,) for one state (14,).

    acc_z is the tension `l |n'|² + g n_z` plus the lever-arm terms `[ω' × r + ω × (ω × r)]_z`, with `ω'` the
    body-rate derivative along the pendulum's own motion (central difference over ±1 ms, twist acceleration 0).
    Scalar code (no temporary arrays): it runs ~10 times per sample inside the Jacobian.
    """
    g, l = params[0], params[1]
    rx, ry, rz = params[2], params[3], params[4]
    px, py, vx, vy, alpha, alpha_rate = x[0], x[1], x[2], x[3], x[4], x[5]
    qw, qx, qy, qz, wx, wy, wz = _attitude_rate(px, py, vx, vy, alpha, alpha_rate)
    nz = math.sqrt(max(1.0 - px * px - py * py, 1e-6))
    vz = -(px * vx + py * vy) / nz
    ax, ay = _pendulum_accel(px, py, vx, vy, g / l, x[10], x[11])
    h = 1e-3
    _, _, _, _, px_, py_, pz_ = _attitude_rate(px + h * vx, py + h * vy, vx + h * ax, vy + h * ay,
                                               alpha + h * alpha_rate, alpha_rate)  # fmt: skip
    _, _, _, _, mx_, my_, mz_ = _attitude_rate(px - h * vx, py - h * vy, vx - h * ax, vy - h * ay,
                                               alpha - h * alpha_rate, alpha_rate)  # fmt: skip
    dwx, dwy = (px_ - mx_) / (2.0 * h), (py_ - my_) / (2.0 * h)
    lever_z = dwx * ry - dwy * rx + wz * (wx * rx + wy * ry + wz * rz) - rz * (wx * wx + wy * wy + wz * wz)
    out = np.zeros(7)
    out[0], out[1], out[2] = wx + x[6] + x[12] * wz, wy + x[7] + x[13] * wz, wz + x[8]
    out[3] = l * (vx * vx + vy * vy + vz * vz) + g * nz + lever_z + x[9]
    if params[8] > 0.0:  # Rᵀ m_ref
        mx, my, mz = params[5], params[6], params[7]
        xx, yy, zz, xy, xz, yz = qx * qx, qy * qy, qz * qz, qx * qy, qx * qz, qy * qz
        wx_, wy_, wz_ = qw * qx, qw * qy, qw * qz
        out[4] = (1.0 - 2.0 * (yy + zz)) * mx + 2.0 * (xy + wz_) * my + 2.0 * (xz - wy_) * mz
        out[5] = 2.0 * (xy - wz_) * mx + (1.0 - 2.0 * (xx + zz)) * my + 2.0 * (yz + wx_) * mz
        out[6] = 2.0 * (xz + wy_) * mx + 2.0 * (yz - wx_) * my + (1.0 - 2.0 * (xx + yy)) * mz
    return out


@njit
def process_jacobian(x: FloatArray, dt_s: float, g_over_l: float) -> FloatArray:
    """Jacobian (14, 14) of `process` at `x`: forward differences (step 1e-7) in the pendulum columns `p, v, e`;
    the rest is exact (α integrates α'; α', bias, offset and `e` random-walk)."""
    eps = 1e-7
    f0 = process(x, dt_s, g_over_l)
    f_jac = np.eye(N_STATE)
    f_jac[4, 5] = dt_s
    xp = x.copy()
    for j in (0, 1, 2, 3, 10, 11):
        xp[j] += eps
        f_jac[:, j] = (process(xp, dt_s, g_over_l) - f0) / eps
        xp[j] = x[j]
    return f_jac


@njit
def measurement_jacobian(x: FloatArray, params: FloatArray) -> tuple[FloatArray, FloatArray]:
    """`(h(x), ∂h/∂x)` (7,), (7, 12) by forward differences (exact in the linear bias and offset columns); the
    magnetometer rows only see the heading α."""
    eps = 1e-7
    h0 = measurement(x, params)
    h_jac = np.zeros((7, N_STATE))
    xp = x.copy()
    for j in (0, 1, 2, 3, 4, 5, 10, 11):
        xp[j] += eps
        h_jac[:, j] = (measurement(xp, params) - h0) / eps
        xp[j] = x[j]
    for j in range(3):  # the gyroscope bias and the tension offset enter linearly
        h_jac[j, 6 + j] = 1.0
    h_jac[3, 9] = 1.0
    wz = h0[2] - x[8]  # cross-axis sensitivity: the twist rate leaks into x and y
    h_jac[0, 12], h_jac[1, 13] = wz, wz
    for j in range(N_STATE):
        if j != 4:  # heading-only magnetometer: hard iron must not tilt the rope estimate
            h_jac[4:, j] = 0.0
        if 4 <= j <= 8:  # tension informs swing and its own offset only; lever terms must not steer twist/bias
            h_jac[3, j] = 0.0
    return h0, h_jac


@njit
def _post_update(x: FloatArray) -> None:
    """Keep the rope below horizontal and wrap the heading."""
    norm = np.sqrt(x[0] * x[0] + x[1] * x[1])
    if norm > 0.99:
        x[0] *= 0.99 / norm
        x[1] *= 0.99 / norm
    x[4] = (x[4] + np.pi) % (2.0 * np.pi) - np.pi


@njit
def inflate_on_surprise(p_pred: FloatArray, h_jac: FloatArray, hx: FloatArray, z: FloatArray, params: FloatArray,
                        r_diag: FloatArray) -> FloatArray:
    """Adaptive process noise: if the swing-rate innovation fails a χ² gate (an unmodelled trolley move or gust
    accelerated the rope), add its square to the rope-rate variance, so the estimate follows the gyroscope
    instead of bending the bias and tilt states. Returns the (possibly) inflated covariance."""
    y = z[:2] - hx[:2]
    hs = h_jac[:2]
    s = hs @ p_pred @ hs.T + np.diag(r_diag[:2])
    d2 = y @ np.linalg.solve(s, y)
    out = p_pred.copy()
    if d2 > params[9]:
        extra = (y[0] * y[0] + y[1] * y[1]) * (1.0 - params[9] / d2)
        out[2, 2] += extra
        out[3, 3] += extra
    return out


@njit
def ekf_step(
    x: FloatArray, p: FloatArray, z: FloatArray, dt_s: float, params: FloatArray, q_psd: FloatArray, r_diag: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """One predict + update in filterpy's operation order (Joseph form); `z` and `r_diag` are (4,) or (7,)."""
    m = z.shape[0]
    g_over_l = params[0] / params[1]
    f_jac = process_jacobian(x, dt_s, g_over_l)
    x_pred = process(x, dt_s, g_over_l)
    p_pred = f_jac @ p @ f_jac.T + np.diag(q_psd * dt_s)
    h_full, h_jac_full = measurement_jacobian(x_pred, params)
    hx, h_jac = h_full[:m], h_jac_full[:m]
    p_pred = inflate_on_surprise(p_pred, h_jac, hx, z, params, r_diag)
    rmat = np.diag(r_diag)
    pht = p_pred @ h_jac.T
    k = pht @ np.linalg.inv(h_jac @ pht + rmat)
    x_new = x_pred + k @ (z - hx)
    i_kh = np.eye(N_STATE) - k @ h_jac
    p_new = i_kh @ p_pred @ i_kh.T + k @ rmat @ k.T
    _post_update(x_new)
    return x_new, p_new


@njit
def ekf_run(
    x0: FloatArray, p0: FloatArray, z: FloatArray, dt_s: float, params: FloatArray, q_psd: FloatArray,
    r_diag: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Batch filter over measurements z (N, 4 or 7): quaternions (N, 4), final state and covariance."""
    n = z.shape[0]
    out = np.empty((n, 4))
    x, p = x0.copy(), p0.copy()
    for i in range(n):
        x, p = ekf_step(x, p, z[i], dt_s, params, q_psd, r_diag)
        out[i] = attitude_and_rate(x)[0]
    return out, x, p


class HookFilter(AttitudeFilter):
    """Pendulum-aware EKF for the crane hook (see the module docstring). `update()` runs filterpy's
    ExtendedKalmanFilter on the numba model; `run()` the numba twin `ekf_run` (same operation order).
    State: `self.ekf.x` (14,), `self.ekf.P` (14, 14)."""

    name = "hook"

    def __init__(self, settings: HookFilterSettings | None = None, *, use_mag: bool = True) -> None:
        super().__init__(use_mag=use_mag)
        self.settings = s = settings if settings is not None else HookFilterSettings()
        self.ekf = ExtendedKalmanFilter(dim_x=N_STATE, dim_z=4)
        self.acc_z_offset_m_s2 = 0.0
        self.mag_ref_uT: FloatArray | None = None
        self._q_psd = np.array(
            [0.0, 0.0, s.swing_accel_psd, s.swing_accel_psd, 0.0, s.torsion_accel_psd]
            + [s.gyro_bias_psd] * 3
            + [s.acc_bias_psd]
            + [s.equilibrium_psd] * 2
            + [0.0] * 2
        )
        self._initialised = False
        self._reset(heading_rad=0.0, heading_std_rad=s.init_heading_std_rad)

    def _params(self, use_mag: bool) -> FloatArray:
        s = self.settings
        m = self.mag_ref_uT if (use_mag and self.mag_ref_uT is not None) else np.zeros(3)
        flag = 1.0 if (use_mag and self.mag_ref_uT is not None) else 0.0
        return np.array([s.gravity_m_s2, s.rope_length_m, *s.lever_arm_m, *m, flag, s.surprise_gate])

    def _r_diag(self, m: int) -> FloatArray:
        s = self.settings
        sig = [s.gyro_noise_rad_s] * 3 + [s.acc_noise_m_s2] + [s.mag_noise_uT] * 3
        out: FloatArray = np.square(np.array(sig[:m]))
        return out

    def _reset(self, heading_rad: float, heading_std_rad: float) -> None:
        s = self.settings
        self.ekf.x = np.zeros(N_STATE)
        self.ekf.x[_ALPHA] = heading_rad
        std = np.array(
            [s.init_swing_std] * 2
            + [s.init_rate_std_rad_s] * 2
            + [heading_std_rad, 0.05]
            + [s.init_bias_std_rad_s] * 3
            + [s.init_acc_offset_std_m_s2]
            + [s.init_equilibrium_std] * 2
            + [s.init_cross_axis_std] * 2
        )
        self.ekf.P = np.diag(std**2)

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        """Hanging still: swing 0, the accelerometer's zero-g offset along the rope, heading from the magnetometer.

        The mean specific force at rest is `g` along body z, so `acc_z - g` is stored as the tension channel's
        offset. With a magnetometer the heading is `atan2(m_x, m_y)` (the field's horizontal part points North)
        and the reference field is `(0, |m_h|, m_z)`.
        """
        acc = np.asarray(acc_m_s2, dtype=np.float64)
        self.acc_z_offset_m_s2 = float(acc[2] - self.settings.gravity_m_s2)
        if self.use_mag and mag_uT is not None:
            m = np.asarray(mag_uT, dtype=np.float64)
            self.mag_ref_uT = np.array([0.0, math.hypot(m[0], m[1]), m[2]])
            self._reset(math.atan2(m[0], m[1]), 0.2)
        else:
            self.mag_ref_uT = None
            self._reset(0.0, self.settings.init_heading_std_rad)
        self._initialised = True

    def update(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Predict by `dt_s`, then correct with gyroscope, tension and (9D) magnetometer; returns q (4,)."""
        if not self._initialised:
            self.initialise(acc_m_s2, mag_uT)
        use_mag = self.use_mag and mag_uT is not None and self.mag_ref_uT is not None
        params = self._params(use_mag)
        g_over_l = params[0] / params[1]
        f_jac = process_jacobian(self.ekf.x, dt_s, g_over_l)
        self.ekf.x = process(self.ekf.x, dt_s, g_over_l)
        self.ekf.P = f_jac @ self.ekf.P @ f_jac.T + np.diag(self._q_psd * dt_s)
        z: list[FloatArray] = [
            np.asarray(gyr_rad_s, dtype=np.float64), np.array([float(acc_m_s2[2]) - self.acc_z_offset_m_s2])
        ]
        if use_mag:
            z.append(np.asarray(mag_uT, dtype=np.float64))
        zv: FloatArray = np.concatenate(z)
        m = zv.shape[0]
        hx, h_jac = measurement_jacobian(self.ekf.x, params)
        self.ekf.P = inflate_on_surprise(self.ekf.P, h_jac[:m], hx[:m], zv, params, self._r_diag(m))
        self.ekf.update(zv, lambda _x: h_jac[:m], lambda _x: hx[:m], R=np.diag(self._r_diag(m)))
        _post_update(self.ekf.x)
        return self.quaternion

    def run(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Whole arrays (N, 3) through the numba twin of `update()`; returns (N, 4)."""
        if not self._initialised:
            self.initialise(acc_m_s2[0], None if mag_uT is None else mag_uT[0])
        use_mag = self.use_mag and mag_uT is not None and self.mag_ref_uT is not None
        cols = [np.asarray(gyr_rad_s, dtype=np.float64), np.asarray(acc_m_s2, dtype=np.float64)[:, 2:3]]
        cols[1] = cols[1] - self.acc_z_offset_m_s2
        if use_mag:
            cols.append(np.asarray(mag_uT, dtype=np.float64))
        z = np.ascontiguousarray(np.concatenate(cols, axis=1))
        quats, self.ekf.x, self.ekf.P = ekf_run(
            self.ekf.x, self.ekf.P, z, dt_s, self._params(use_mag), self._q_psd, self._r_diag(z.shape[1])
        )
        return quats

    @property
    def quaternion(self) -> FloatArray:
        return attitude_and_rate(self.ekf.x)[0]

    def seed_gyro_bias(self, bias_rad_s: FloatArray, std_rad_s: float = 0.002, axes: tuple[int, ...] = (0, 1, 2)
                       ) -> None:  # fmt: skip
        """Start the bias estimate of body `axes` from a rest window's mean gyro (and trust it to `std_rad_s`).

        A hook that hangs still but twists (gusts turn it about the rope) still gives the x/y bias: seed (0, 1)."""
        idx = [_BIAS.start + a for a in axes]
        self.ekf.x[idx] = np.asarray(bias_rad_s, dtype=np.float64)[list(axes)]
        self.ekf.P[idx, :] = 0.0
        self.ekf.P[:, idx] = 0.0
        self.ekf.P[idx, idx] = std_rad_s**2

    def assume_moving(self) -> None:
        """The initialisation window was not at rest (the hook was already swinging): widen the swing, rope-rate and
        tension-offset priors to `settings.moving_*`, so the pendulum dynamics find the swing instead of a tight
        "hanging still" prior holding it near plumb for many periods."""
        s = self.settings
        for i, std in ((0, s.moving_swing_std), (1, s.moving_swing_std), (2, s.moving_rate_std_rad_s),
                       (3, s.moving_rate_std_rad_s), (_ACC_BIAS, s.moving_acc_offset_std_m_s2)):  # fmt: skip
            self.ekf.P[i, :] = 0.0
            self.ekf.P[:, i] = 0.0
            self.ekf.P[i, i] = std**2

    @property
    def gyro_bias_rad_s(self) -> FloatArray:
        """Current gyroscope bias estimate, rad/s, body frame."""
        out: FloatArray = self.ekf.x[_BIAS].copy()
        return out
