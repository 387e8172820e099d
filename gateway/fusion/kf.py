"""Linear Kalman filter on attitude angles of the smart-fishing-rod paper (seed 000), on filterpy, with a numba twin.

Paper model, per sample:
- prediction: the gyro quaternion, first-order Runge-Kutta step q + Δt/2 · q ⊗ (0, ω) then normalised
  (eq. 19-24), turned into roll, pitch, yaw φ_G (eq. 37: φ_G = true angle + gyro error); F = I, process noise Q;
- measurement: the accelerometer/magnetometer angles θ_AM (eq. 38): roll and pitch from gravity, yaw from the
  tilt-compensated field; H = I; the linear Kalman update of eq. 30-34;
- measurement noise R estimated online from successive differences (eq. 39-45): f = Δ_AM − Δ_G,
  cov(f) ≈ 2 E[Δθ_AM²], R = cov(f)/2, with E[·] a running mean of time constant `r_window_s`;
- the fused angles seed the next gyro step ("each fused angle is the next initial angle", section 3.3.4).

Always on (the paper is silent, the angles need it): innovations and differences are wrapped to (−π, π] (roll and
yaw cross ±π); near gimbal lock roll and yaw are ill-defined, so their R is divided by cos²(pitch), which leaves
them to the gyro there. 6D mode: roll and pitch are measured, yaw comes from the gyro alone.

Beyond the paper (off with `KfSettings(paper=True)`): gyro bias learnt as the mean rate while at rest; roll/pitch R
inflated (with a cap) as |a| departs from its rest norm, yaw R as |m| and the dip angle depart from theirs.

Fig. 4's gyro correction (off unless `fig4_kp_rad_s` or `fig4_ki_rad_s2` > 0, in either mode): before the
prediction step the rate is corrected by the cross product of measured and predicted gravity, Mahony-style,
ω' = ω + kp · (â × v̂) + ∫ ki · (â × v̂) dt, with v̂ the up direction of the previous fused angles. The paper gives
no gains; the registry's `kf-paper` uses `FIG4_KP_RAD_S` / `FIG4_KI_RAD_S2` (docs/fusion.md has the measurement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter

from gateway.fusion import quaternion as quat
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.quaternion import njit

# auxiliary state: E[f²] per angle (3), previous measurement angles (3), gyro bias (3), rest timer, have-previous,
# Fig. 4 integral (3, rad/s)
AUX_SIZE = 14
# Fig. 4 gains of the registry's `kf-paper` (the paper gives none): seed 004's Mahony defaults
FIG4_KP_RAD_S = 0.2
FIG4_KI_RAD_S2 = 0.0005
FIG4_INTEGRAL_LIMIT_RAD_S = 0.1


@dataclass(frozen=True)
class KfSettings:
    """Tuning of the angle Kalman filter, one set for every device and trial."""

    gyr_noise_rad_s: float = 0.005
    """Process noise: std of the gyro angle error growth per sample (rad/s); Q = (σ Δt)² I."""
    r_window_s: float = 2.0
    """Time constant of the running mean that estimates cov(f) (eq. 42-44), s."""
    r_init_rad: float = 0.02
    """Measurement-angle std assumed before the estimate has data (rad)."""
    r_min_rad: float = 0.002
    """Floor on the estimated measurement-angle std (rad)."""
    paper: bool = False
    """True: the paper's filter only (no bias learning, no gates). Wrap and gimbal handling stay on."""
    acc_gate: float = 0.03
    """Relative deviation ||a| - g₀|/g₀ at which the roll/pitch noise std has doubled (grows quadratically)."""
    mag_norm_gate: float = 0.05
    """Relative deviation ||m| - m₀|/m₀ at which the yaw noise std has doubled."""
    mag_dip_gate_rad: float = 0.05
    """Dip-angle deviation (rad) at which the yaw noise std has doubled."""
    rest_gyr_rad_s: float = 0.02
    """Rest when |ω - b| stays below this (rad/s) ..."""
    rest_acc: float = 0.02
    """... and ||a| - g₀|/g₀ below this ..."""
    rest_time_s: float = 0.5
    """... for this long (s); at rest the gyro bias follows the measured rate."""
    bias_tau_s: float = 1.0
    """Time constant of the at-rest bias average (s)."""
    acc_gate_max: float = 5.0
    """Cap on the roll/pitch noise std multiplier (0: no cap), so long fast motion still sees some correction."""
    fig4_kp_rad_s: float = 0.0
    """Fig. 4 cross-product gyro correction, proportional gain (rad/s per unit of |â × v̂|); 0: off."""
    fig4_ki_rad_s2: float = 0.0
    """Fig. 4 correction, integral gain (rad/s² per unit error; integral clamped at ±0.1 rad/s); 0: off."""

    def as_array(self) -> FloatArray:
        """Pack for the numba kernels: the paper flag zeroes every extension (not Fig. 4's correction, the paper's)."""
        p = self.paper
        return np.array(
            [
                self.gyr_noise_rad_s,
                self.r_window_s,
                self.r_init_rad,
                self.r_min_rad,
                0.0 if p else self.acc_gate,
                0.0 if p else self.mag_norm_gate,
                0.0 if p else self.mag_dip_gate_rad,
                0.0 if p else self.rest_gyr_rad_s,
                self.rest_acc,
                self.rest_time_s,
                self.bias_tau_s,
                self.acc_gate_max,
                self.fig4_kp_rad_s,
                self.fig4_ki_rad_s2,
            ]
        )


# --- pure maths (numba-compiled, callable from Python) -------------------------------------------------------------


@njit
def wrap(angle_rad: float) -> float:
    """Wrap to [-π, π)."""
    return (angle_rad + np.pi) % (2.0 * np.pi) - np.pi


@njit
def first_order_step(q: FloatArray, gyr_rad_s: FloatArray, dt_s: float) -> FloatArray:
    """q + Δt/2 · q ⊗ (0, ω) (eq. 19-21), then normalised (eq. 22-24)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    gx, gy, gz = gyr_rad_s[0], gyr_rad_s[1], gyr_rad_s[2]
    h = 0.5 * dt_s
    out = np.array(
        [
            w + (-x * gx - y * gy - z * gz) * h,
            x + (w * gx + y * gz - z * gy) * h,
            y + (w * gy - x * gz + z * gx) * h,
            z + (w * gz + x * gy - y * gx) * h,
        ]
    )
    out /= np.sqrt(np.sum(out * out))
    return out


@njit
def euler_from_quat(q: FloatArray) -> FloatArray:
    """Roll, pitch, yaw (rad) of docs/design.md: R = Rz(yaw) Ry(−pitch) Rx(roll), pitch = elevation of body x."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r10 = 2.0 * (x * y + w * z)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    return np.array([np.arctan2(r21, r22), np.arcsin(min(1.0, max(-1.0, r20))), np.arctan2(r10, r00)])


@njit
def quat_from_euler(angles_rad: FloatArray) -> FloatArray:
    """Inverse of `euler_from_quat`: qz(yaw) ⊗ qy(−pitch) ⊗ qx(roll)."""
    cr, sr = np.cos(0.5 * angles_rad[0]), np.sin(0.5 * angles_rad[0])
    cp, sp = np.cos(0.5 * angles_rad[1]), -np.sin(0.5 * angles_rad[1])
    cy, sy = np.cos(0.5 * angles_rad[2]), np.sin(0.5 * angles_rad[2])
    return np.array(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ]
    )


@njit
def measured_angles(acc_m_s2: FloatArray, mag_uT: FloatArray, use_mag: bool) -> FloatArray:
    """θ_AM: roll and pitch from the specific force; yaw from the field rotated level by roll and pitch (0 in 6D)."""
    ax, ay, az = acc_m_s2[0], acc_m_s2[1], acc_m_s2[2]
    roll = np.arctan2(ay, az)
    pitch = np.arctan2(ax, np.sqrt(ay * ay + az * az))
    yaw = heading_angle(roll, pitch, mag_uT) if use_mag else 0.0
    return np.array([roll, pitch, yaw])


@njit
def heading_angle(roll_rad: float, pitch_rad: float, mag_uT: FloatArray) -> float:
    """Yaw (rad) that turns the field, levelled with the given roll and pitch, to North (tilt compensation)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    mx, my, mz = mag_uT[0], mag_uT[1], mag_uT[2]
    # level frame: m_l = Ry(−pitch) Rx(roll) m
    my_l = cr * my - sr * mz
    mz_r = sr * my + cr * mz
    mx_l = cp * mx - sp * mz_r
    # Rz(yaw) m_l must point North (+y): yaw + bearing(m_l) = π/2
    return wrap(0.5 * np.pi - np.arctan2(my_l, mx_l))


@njit
def noise_estimate(mean_f2: float, f: float, alpha: float) -> float:
    """Running mean of f² (eq. 42-44, f has zero mean): E ← E + α (f² − E); R = E/2 (eq. 45)."""
    return mean_f2 + alpha * (f * f - mean_f2)


@njit
def fig4_corrected_rate(
    q: FloatArray, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, aux: FloatArray, dt_s: float, kp: float, ki: float
) -> FloatArray:
    """ω + kp·e + ∫ki·e dt with e = â × v̂ (Fig. 4; seed 004's Mahony step); the integral lives in aux[11:14]."""
    if kp <= 0.0 and ki <= 0.0:
        return gyr_rad_s
    e = quat.tilt_error4(q, acc_m_s2)
    out = gyr_rad_s.copy()
    for k in range(3):
        if ki > 0.0:
            lim = FIG4_INTEGRAL_LIMIT_RAD_S
            aux[11 + k] = min(max(aux[11 + k] + ki * e[k] * dt_s, -lim), lim)
        out[k] += kp * e[k] + aux[11 + k]
    return out


@njit
def prepare(
    x: FloatArray,
    aux: FloatArray,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    dt_s: float,
    ref: FloatArray,
    params: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Everything around the Kalman equations for one sample: prediction φ_G, measurement z, H, R, new aux.

    `x` = fused roll, pitch, yaw of the previous sample; `ref` = [g₀ (m/s²), m₀ (µT), dip₀ (rad)].
    z is unwrapped to lie within π of φ_G, so the filter's plain z − Hx is the wrapped innovation.
    """
    aux = aux.copy()
    acc_norm = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    acc_dev = abs(acc_norm - ref[0]) / ref[0]
    # rest detection and at-rest bias (beyond the paper)
    if params[7] > 0.0:
        w = gyr_rad_s - aux[6:9]
        if np.sqrt(np.sum(w * w)) < params[7] and acc_dev < params[8]:
            aux[9] += dt_s
        else:
            aux[9] = 0.0
        if aux[9] >= params[9]:
            aux[6:9] += min(1.0, dt_s / params[10]) * (gyr_rad_s - aux[6:9])
    # prediction (eq. 19-24, 37), with the rate corrected by Fig. 4's cross product when its gains are set
    q_prev = quat_from_euler(x)
    rate = fig4_corrected_rate(q_prev, gyr_rad_s - aux[6:9], acc_m_s2, aux, dt_s, params[12], params[13])
    phi_g = euler_from_quat(first_order_step(q_prev, rate, dt_s))
    theta_am = measured_angles(acc_m_s2, mag_uT, use_mag)
    n_ang = 3 if use_mag else 2
    # online R (eq. 39-45)
    alpha = min(1.0, dt_s / params[1])
    r_min2 = params[3] ** 2
    r_diag = np.empty(3)
    for i in range(3):
        if aux[10] > 0.0 and i < n_ang:
            f = wrap(theta_am[i] - aux[3 + i]) - wrap(phi_g[i] - x[i])
            aux[i] = noise_estimate(aux[i], f, alpha)
        r_diag[i] = max(0.5 * aux[i], r_min2)
    aux[3:6] = theta_am
    aux[10] = 1.0
    # gimbal lock: roll and yaw measurement errors grow like 1/cos(pitch)
    cos2 = max(np.cos(phi_g[1]) ** 2, 1e-6)
    r_diag[0] /= cos2
    r_diag[2] /= cos2
    # gates (beyond the paper)
    if params[4] > 0.0:
        infl = 1.0 + (acc_dev / params[4]) ** 2
        infl = (min(infl, params[11]) if params[11] > 0.0 else infl) ** 2
        r_diag[0] *= infl
        r_diag[1] *= infl
    if use_mag and (params[5] > 0.0 or params[6] > 0.0):
        mag_norm = np.sqrt(mag_uT[0] ** 2 + mag_uT[1] ** 2 + mag_uT[2] ** 2)
        norms = acc_norm * mag_norm  # 0 in free fall or for a zero field: no dip to read (taken as 0, far from dip₀)
        dot = acc_m_s2[0] * mag_uT[0] + acc_m_s2[1] * mag_uT[1] + acc_m_s2[2] * mag_uT[2]
        dot = dot / norms if norms > 0.0 else 0.0
        dip = np.arcsin(min(1.0, max(-1.0, dot)))
        sig = 1.0
        if params[5] > 0.0:
            sig += (abs(mag_norm - ref[1]) / ref[1] / params[5]) ** 2
        if params[6] > 0.0:
            sig += ((dip - ref[2]) / params[6]) ** 2
        r_diag[2] *= sig * sig
    z = np.empty(n_ang)
    h = np.zeros((n_ang, 3))
    r = np.zeros((n_ang, n_ang))
    for i in range(n_ang):
        z[i] = phi_g[i] + wrap(theta_am[i] - phi_g[i])
        h[i, i] = 1.0
        r[i, i] = r_diag[i]
    return phi_g, z, h, r, aux


@njit
def finish(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Wrap the fused angles (pitch is clipped to ±π/2) and return them with their quaternion."""
    out = np.array([wrap(x[0]), min(0.5 * np.pi, max(-0.5 * np.pi, x[1])), wrap(x[2])])
    return out, quat_from_euler(out)


@njit
def kf_run(
    x0: FloatArray,
    p0: FloatArray,
    aux0: FloatArray,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    dt_s: float,
    ref: FloatArray,
    params: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Batch filter, the same operations as `KalmanAngleFilter.update` with filterpy's formulas (Joseph form)."""
    n = gyr_rad_s.shape[0]
    out = np.empty((n, 4))
    x = x0.copy()
    p = p0.copy()
    aux = aux0.copy()
    qmat = (params[0] * dt_s) ** 2 * np.eye(3)
    eye3 = np.eye(3)
    for i in range(n):
        x, z, h, r, aux = prepare(x, aux, gyr_rad_s[i], acc_m_s2[i], mag_uT[i], use_mag, dt_s, ref, params)
        p = eye3 @ p @ eye3.T + qmat
        pht = p @ h.T
        k = pht @ np.linalg.inv(h @ pht + r)
        x = x + k @ (z - h @ x)
        i_kh = eye3 - k @ h
        p = i_kh @ p @ i_kh.T + k @ r @ k.T
        x, out[i] = finish(x)
    return out, x, p, aux


# --- filterpy-backed filter ------------------------------------------------------------------------------------------


class KalmanAngleFilter(AttitudeFilter):
    """Angle Kalman filter of seed 000 (see module docstring); `update()` runs filterpy, `run()` the numba twin."""

    name = "kf"

    def __init__(self, settings: KfSettings | None = None, *, use_mag: bool = True) -> None:
        super().__init__(use_mag=use_mag)
        self.settings = settings or KfSettings()
        self._params = self.settings.as_array()
        self._kf = KalmanFilter(dim_x=3, dim_z=3)
        self._kf.x = np.zeros(3)
        self._kf.F = np.eye(3)
        self._ref = np.array([9.81, 50.0, 0.0])
        self._aux = np.zeros(AUX_SIZE)
        self._q = np.array([1.0, 0.0, 0.0, 0.0])
        self._reset()

    def _reset(self) -> None:
        self._kf.P = (self.settings.r_init_rad**2) * np.eye(3)
        self._aux = np.zeros(AUX_SIZE)
        self._aux[:3] = 2.0 * self.settings.r_init_rad**2

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        """Angles from the rest means (eq. 17-18 via θ_AM); learn g₀, m₀ and the dip angle for the gates."""
        use_mag = self.use_mag and mag_uT is not None
        acc = np.asarray(acc_m_s2, dtype=np.float64)
        mag = np.asarray(mag_uT, dtype=np.float64) if use_mag else np.zeros(3)
        self._reset()
        self._kf.x, self._q = finish(measured_angles(acc, mag, use_mag))
        g0 = float(np.linalg.norm(acc))
        if use_mag:
            m0 = float(np.linalg.norm(mag))
            dip0 = float(np.arcsin(np.clip(np.dot(acc, mag) / (g0 * m0), -1.0, 1.0)))
            self._ref = np.array([g0, m0, dip0])
        else:
            self._ref = np.array([g0, 50.0, 0.0])

    @property
    def quaternion(self) -> FloatArray:
        return self._q.copy()

    @property
    def angles_rad(self) -> FloatArray:
        """Fused roll, pitch, yaw (rad), the filter's state."""
        a: FloatArray = np.asarray(self._kf.x, dtype=np.float64).copy()
        return a

    @property
    def measurement_noise_rad2(self) -> FloatArray:
        """Current online estimate R = cov(f)/2 per angle (rad², before gates and gimbal scaling; eq. 45)."""
        return 0.5 * self._aux[:3]

    @property
    def fig4_integral_rad_s(self) -> FloatArray:
        """Integral of Fig. 4's cross-product correction (rad/s; minus the gyro bias on the tilt axes), 0 when off."""
        return self._aux[11:14].copy()

    @property
    def gyro_bias_rad_s(self) -> FloatArray:
        """At-rest gyro-bias estimate (zero when `paper=True`)."""
        return self._aux[6:9].copy()

    def update(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Gyro prediction of the angles, then the linear update with the acc/mag angles and the online R."""
        kf = self._kf
        use_mag = self.use_mag and mag_uT is not None
        mag = np.asarray(mag_uT, dtype=np.float64) if use_mag else np.zeros(3)
        phi_g, z, h, r, self._aux = prepare(
            kf.x,
            self._aux,
            np.asarray(gyr_rad_s, dtype=np.float64),
            np.asarray(acc_m_s2, dtype=np.float64),
            mag,
            use_mag,
            dt_s,
            self._ref,
            self._params,
        )
        kf.x = phi_g
        kf.predict(Q=(self._params[0] * dt_s) ** 2 * np.eye(3))
        kf.dim_z = z.shape[0]  # 2 in 6D (roll, pitch), 3 in 9D: filterpy checks z against dim_z
        kf.update(z, R=r, H=h)
        kf.x, self._q = finish(kf.x)
        return self.quaternion

    def run(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Same filter over whole (N, 3) arrays with the numba kernel; leaves the state at the last sample."""
        use_mag = self.use_mag and mag_uT is not None
        mag = np.ascontiguousarray(mag_uT, dtype=np.float64) if use_mag else np.zeros_like(acc_m_s2)
        out, x, p, self._aux = kf_run(
            np.asarray(self._kf.x, dtype=np.float64),
            self._kf.P,
            self._aux,
            np.ascontiguousarray(gyr_rad_s, dtype=np.float64),
            np.ascontiguousarray(acc_m_s2, dtype=np.float64),
            mag,
            use_mag,
            float(dt_s),
            self._ref,
            self._params,
        )
        self._kf.x, self._kf.P = x, p
        self._q = out[-1].copy() if out.shape[0] else self._q
        return out
