"""Complementary filters of seed 002: plain (eq. 5) and adaptive (PI in the low-pass path, gains scheduled from the
motion state seen in the accelerometer).

Seed 002 eq. 5 blends the accelerometer attitude through the low-pass K/(s+K) and the gyro through the high-pass
s/(s+K): dθ̂/dt = ω + K (θ_acc − θ̂). We apply it on the rotation group instead of on Euler angles (no gimbal lock
in BROAD's full rotations): with e the exact tilt error (rotation vector, rad, body frame) between measured and
predicted gravity,
    plain:     ω' = ω + K · e
    adaptive:  ω' = ω + Kp(m) · e + i,   i += Ki(m) · e · dt
and q = q ⊗ exp(ω' dt / 2). Each tilt axis then sees exactly K/(s+K) on the accelerometer angle and s/(s+K) on the
gyro. The motion state m is a low-passed | |a| − g | (m/s²); the schedule w = 1 / (1 + (m / m0)²) moves Kp from
`kp_still` (w = 1: trust the accelerometer) to `kp_moving` (w → 0: trust the gyro) and scales Ki by w, so the
integral (gyro bias) only learns while still. The paper gives no formula for the schedule; this one is ours.
In 9D both add a yaw correction from the tilt-compensated magnetometer heading (seed 004) with gain `k_mag`,
about earth Up only, so a disturbed field never tilts the estimate. 6D yaw is gyro only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.fusion import quaternion as quat
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.quaternion import njit

# state: quaternion (4), integral (3, rad/s), motion state m (m/s²), last scheduled Kp (rad/s)
N_STATE = 9
S_MOTION = 7
S_KP = 8
# params: kp_still, kp_moving, ki_still, m0, motion_tau, k_mag, g, integral limit, integral error max
N_PARAMS = 9


@dataclass(frozen=True)
class ComplementarySettings:
    """Plain filter of seed 002 eq. 5: one crossover K (rad/s); k_mag is the 9D heading crossover (rad/s)."""

    k_rad_s: float = 0.2
    k_mag_rad_s: float = 0.1
    gravity_m_s2: float = quat.GRAVITY_M_S2

    def to_params(self) -> FloatArray:
        return np.array([self.k_rad_s, self.k_rad_s, 0.0, np.inf, 0.0, self.k_mag_rad_s, self.gravity_m_s2, 0.0, 0.0])


@dataclass(frozen=True)
class AdaptiveSettings:
    """Adaptive filter of seed 002: PI gains scheduled by the accelerometer's motion state."""

    kp_still_rad_s: float = 1.0  # crossover when still: follow the accelerometer closely
    kp_moving_rad_s: float = 0.02  # crossover in fast motion: mostly gyro
    ki_still_rad_s2: float = 0.01  # integral gain when still (learns the gyro bias)
    motion_scale_m_s2: float = 2.0  # m0: | |a| - g | at which the scheduling weight is 1/2
    motion_tau_s: float = 1.0  # smoothing of the motion state (rise is immediate, decay with this constant)
    k_mag_rad_s: float = 0.1
    integral_limit_rad_s: float = 0.05
    integral_error_max_rad: float = 0.2  # anti-windup: integrate only while the tilt error is below this
    gravity_m_s2: float = quat.GRAVITY_M_S2

    def to_params(self) -> FloatArray:
        return np.array([self.kp_still_rad_s, self.kp_moving_rad_s, self.ki_still_rad_s2, self.motion_scale_m_s2,
                         self.motion_tau_s, self.k_mag_rad_s, self.gravity_m_s2, self.integral_limit_rad_s,
                         self.integral_error_max_rad])


@njit
def tilt_rotvec4(q: FloatArray, acc_m_s2: FloatArray) -> FloatArray:
    """Exact tilt error (body rotation vector, rad) turning predicted gravity direction v̂ onto measured â."""
    c = quat.tilt_error4(q, acc_m_s2)  # â × v̂ = sin(angle) · axis
    s = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    if s < 1e-12:
        return c
    n = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    v_up = np.zeros(3)
    v_up[2] = 1.0
    v = quat.rotate_inverse4(q, v_up)
    cos = (acc_m_s2[0] * v[0] + acc_m_s2[1] * v[1] + acc_m_s2[2] * v[2]) / n
    out: FloatArray = c * (np.arctan2(s, cos) / s)
    return out


@njit
def complementary_step(
    state: FloatArray,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    dt_s: float,
    params: FloatArray,
) -> None:
    """One sample of the plain (ki = 0, m0 = inf) or adaptive filter; updates `state` (N_STATE,) in place."""
    kp_still, kp_moving, ki_still, m0, tau, k_mag, g, i_lim = (
        params[0], params[1], params[2], params[3], params[4], params[5], params[6], params[7])
    e_max = params[8]
    q = state[:4]
    w = gyr_rad_s.copy()
    a_norm = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    if a_norm > 0.0:
        dev = abs(a_norm - g)
        if tau > 0.0 and dev < state[S_MOTION]:
            state[S_MOTION] += (dev - state[S_MOTION]) * min(1.0, dt_s / tau)
        else:
            state[S_MOTION] = dev
        r = state[S_MOTION] / m0
        weight = 1.0 / (1.0 + r * r)
        kp = kp_moving + (kp_still - kp_moving) * weight
        ki = ki_still * weight
        state[S_KP] = kp
        e = tilt_rotvec4(q, acc_m_s2)
        if e[0] * e[0] + e[1] * e[1] + e[2] * e[2] >= e_max * e_max:
            ki = 0.0
        for k in range(3):
            if ki > 0.0:
                state[4 + k] = min(max(state[4 + k] + ki * e[k] * dt_s, -i_lim), i_lim)
            w[k] += kp * e[k]
    if use_mag:
        up = np.zeros(3)
        up[2] = -k_mag * quat.heading_error4(q, mag_uT)
        w += quat.rotate_inverse4(q, up)
    for k in range(3):
        w[k] += state[4 + k]
    state[:4] = quat.gyro_step4(q, w, dt_s)


@njit
def complementary_run(
    state: FloatArray, gyr: FloatArray, acc: FloatArray, mag: FloatArray, use_mag: bool, dt_s: float, params: FloatArray
) -> FloatArray:
    """`complementary_step` over (N, 3) arrays; returns (N, 4), final state left in `state`."""
    n = gyr.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        complementary_step(state, gyr[i], acc[i], mag[i], use_mag, dt_s, params)
        out[i] = state[:4]
    return out


class _ComplementaryBase(AttitudeFilter):
    def __init__(self, params: FloatArray, *, use_mag: bool) -> None:
        super().__init__(use_mag=use_mag)
        self._params = params
        self._state = np.zeros(N_STATE)
        self._state[0] = 1.0

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        q0 = quat.from_acc_mag(acc_m_s2, mag_uT) if self.use_mag and mag_uT is not None else quat.from_acc(acc_m_s2)
        self._state[:] = 0.0
        self._state[:4] = q0

    def update(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float) -> FloatArray:
        use_mag = self.use_mag and mag_uT is not None
        mag = np.asarray(mag_uT, dtype=np.float64) if use_mag else np.zeros(3)
        complementary_step(self._state, np.asarray(gyr_rad_s, dtype=np.float64),
                           np.asarray(acc_m_s2, dtype=np.float64), mag, use_mag, float(dt_s), self._params)
        return self.quaternion

    def run(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float) -> FloatArray:
        use_mag = self.use_mag and mag_uT is not None
        gyr = np.ascontiguousarray(gyr_rad_s, dtype=np.float64)
        mag = np.ascontiguousarray(mag_uT, dtype=np.float64) if use_mag else np.zeros_like(gyr)
        quat.check_samples(gyr, acc_m_s2, mag)
        return complementary_run(self._state, gyr, np.ascontiguousarray(acc_m_s2, dtype=np.float64), mag, use_mag,
                                 float(dt_s), self._params)

    @property
    def quaternion(self) -> FloatArray:
        return self._state[:4].copy()

    @property
    def motion_m_s2(self) -> float:
        """Current motion state m = smoothed | |a| − g | in m/s²."""
        return float(self._state[S_MOTION])

    @property
    def kp_rad_s(self) -> float:
        """Proportional gain used on the last sample (rad/s)."""
        return float(self._state[S_KP])


class ComplementaryFilter(_ComplementaryBase):
    """Plain complementary filter (seed 002 eq. 5) on SO(3), fixed crossover K."""

    name = "complementary"

    def __init__(self, settings: ComplementarySettings | None = None, *, use_mag: bool = True) -> None:
        self.settings = settings or ComplementarySettings()
        super().__init__(self.settings.to_params(), use_mag=use_mag)


class AdaptiveComplementaryFilter(_ComplementaryBase):
    """Adaptive complementary filter (seed 002): PI low-pass path, Kp/Ki scheduled by accelerometer motion state."""

    name = "adaptive"

    def __init__(self, settings: AdaptiveSettings | None = None, *, use_mag: bool = True) -> None:
        self.settings = settings or AdaptiveSettings()
        super().__init__(self.settings.to_params(), use_mag=use_mag)
