"""Mahony-style complementary filter (seed 004): PI correction of the gyro from the cross product of measured and
predicted gravity, plus a tilt-compensated magnetometer heading correction in 9D.

Per sample (body rate ω in rad/s, dt in s):
  e_acc = â × v̂                      (seed 004: normalised measured accel × predicted gravity direction)
  e_mag = R(q)ᵀ [0, 0, -δ]            (δ = tilt-compensated heading error, `quaternion.heading_error4`)
  i    += ki · e_acc · dt             (integral: absorbs gyro bias)
  ω'    = ω + kp · e_acc + kp_mag · e_mag + i
  q     = q ⊗ exp(ω' dt / 2)
The heading term turns the estimate about earth Up only, so a disturbed field cannot tilt the inclination.
Gains were tuned once on all 15 BROAD trials together (docs/fusion.md), not per trial.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.fusion import quaternion as quat
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.quaternion import njit

# state vector layout shared by update() and run(): quaternion (4) then integral term (3, rad/s)
N_STATE = 7


@dataclass(frozen=True)
class MahonySettings:
    """PI gains; kp in rad/s per unit of `â × v̂` (≈ rad of tilt error), ki in rad/s² per unit error."""

    kp: float = 0.2  # crossover ~0.03 Hz: BROAD's hand-held motion carries large external accelerations
    ki: float = 0.0005
    kp_mag: float = 0.1  # rad/s per rad of heading error
    acc_reject_m_s2: float = 0.0  # skip the accel correction when ||a| - g| exceeds this; 0 disables
    gravity_m_s2: float = quat.GRAVITY_M_S2
    integral_limit_rad_s: float = 0.1  # clamp of each integral component (a MEMS bias is below this)
    integral_error_max: float = 0.2  # anti-windup: integrate only while |â × v̂| (≈ tilt error in rad) is below this


@njit
def mahony_step(
    state: FloatArray,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    dt_s: float,
    params: FloatArray,
) -> None:
    """Advance `state` (N_STATE,) by one sample in place; `params` = kp, ki, kp_mag, acc_reject, g, i_limit,
    e_max (the settings' fields in order)."""
    kp, ki, kp_mag, acc_reject, g, i_lim = params[0], params[1], params[2], params[3], params[4], params[5]
    e_max = params[6]
    q = state[:4]
    w = gyr_rad_s.copy()
    a_norm = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    if a_norm > 0.0 and (acc_reject <= 0.0 or abs(a_norm - g) < acc_reject):
        e = quat.tilt_error4(q, acc_m_s2)
        integrate = e[0] * e[0] + e[1] * e[1] + e[2] * e[2] < e_max * e_max
        for k in range(3):
            if integrate:
                state[4 + k] = min(max(state[4 + k] + ki * e[k] * dt_s, -i_lim), i_lim)
            w[k] += kp * e[k]
    if use_mag:
        delta = quat.heading_error4(q, mag_uT)
        up = np.zeros(3)
        up[2] = -kp_mag * delta
        w += quat.rotate_inverse4(q, up)
    for k in range(3):
        w[k] += state[4 + k]
    state[:4] = quat.gyro_step4(q, w, dt_s)


@njit
def mahony_run(
    state: FloatArray, gyr: FloatArray, acc: FloatArray, mag: FloatArray, use_mag: bool, dt_s: float, params: FloatArray
) -> FloatArray:
    """`mahony_step` over (N, 3) arrays; returns quaternions (N, 4) and leaves the final state in `state`."""
    n = gyr.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        mahony_step(state, gyr[i], acc[i], mag[i], use_mag, dt_s, params)
        out[i] = state[:4]
    return out


class MahonyFilter(AttitudeFilter):
    """Mahony PI filter (seed 004) with decoupled tilt-compensated heading correction in 9D."""

    name = "mahony"

    def __init__(self, settings: MahonySettings | None = None, *, use_mag: bool = True) -> None:
        super().__init__(use_mag=use_mag)
        self.settings = settings or MahonySettings()
        s = self.settings
        self._params = np.array([s.kp, s.ki, s.kp_mag, s.acc_reject_m_s2, s.gravity_m_s2, s.integral_limit_rad_s,
                                 s.integral_error_max])
        self._state = np.zeros(N_STATE)
        self._state[0] = 1.0

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        q0 = quat.from_acc_mag(acc_m_s2, mag_uT) if self.use_mag and mag_uT is not None else quat.from_acc(acc_m_s2)
        self._state[:] = 0.0
        self._state[:4] = q0

    def update(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float) -> FloatArray:
        use_mag = self.use_mag and mag_uT is not None
        mag = np.asarray(mag_uT, dtype=np.float64) if use_mag else np.zeros(3)
        mahony_step(self._state, np.asarray(gyr_rad_s, dtype=np.float64), np.asarray(acc_m_s2, dtype=np.float64),
                    mag, use_mag, float(dt_s), self._params)
        return self.quaternion

    def run(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float) -> FloatArray:
        use_mag = self.use_mag and mag_uT is not None
        gyr = np.ascontiguousarray(gyr_rad_s, dtype=np.float64)
        mag = np.ascontiguousarray(mag_uT, dtype=np.float64) if use_mag else np.zeros_like(gyr)
        quat.check_samples(gyr, acc_m_s2, mag)
        return mahony_run(self._state, gyr, np.ascontiguousarray(acc_m_s2, dtype=np.float64), mag, use_mag,
                          float(dt_s), self._params)

    @property
    def quaternion(self) -> FloatArray:
        return self._state[:4].copy()

    @property
    def integral_rad_s(self) -> FloatArray:
        """Integral term (rad/s), the filter's running estimate of minus the gyro bias on the observable axes."""
        return self._state[4:].copy()
