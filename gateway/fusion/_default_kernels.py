"""Numba kernels of the default attitude filter: one flat state vector per device, one code path for 1 or N devices.

The method follows the ideas of VQF (D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation with bias
estimation and magnetic disturbance rejection", Information Fusion 91:187-204, 2023, doi:10.1016/j.inffus.2022.10.014):

1. strapdown integration of the bias- and scale-corrected gyroscope into an almost-inertial frame I;
2. the accelerometer is rotated into I and low-pass filtered there, so body rotation does not smear it; samples of a
   shock (|a| far from g: a tap rings the structure, aliased) are skipped;
3. the filtered specific force, rotated by the inclination correction, is turned fully vertical each sample, which
   gives the 6D frame E6;
4. the inclination corrections are explained by a gyro bias seen through the (equally filtered) rotation matrix,
   estimated by a Kalman filter in motion and directly from the low-passed gyro at rest. Our addition: per-axis
   gyro scale errors seen through the filtered R·diag(rate) join the same filter (6 states, not the paper's 3);
5. heading: one angle delta between E6 and ENU, pulled towards the magnetometer's horizontal direction with the gain
   of a scalar Kalman filter (steady state: time constant tau_mag; larger after a rejection), frozen while the field's
   norm or dip (optionally: its bearing in E6) departs from a tracked reference.

All time constants are in seconds, so one set of defaults serves 50 Hz .. 1 kHz. Everything here is scalar code on
flat float64 arrays: no allocation per sample. A device's whole filter (state, settings, coefficients, scratch) is one
context vector (`X_*` layout), so `_step_context` streams one device from a call with six arguments and
`step_contexts` runs the same compiled code per row of N stacked contexts. The per-sample helpers are inlined at numba
IR level (`inline="always"`): a regular call that takes arrays pays reference-count updates on every sample, which
cost the kernel about a fifth of its speed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange

GRAVITY_M_S2 = 9.81

# ---- settings vector (built by DefaultSettings.to_array) ----
P_TAU_ACC = 0  # s, accelerometer low-pass in I
P_TAU_MAG = 1  # s, heading correction time constant
P_REST_TAU = 2  # s, low-pass used by rest detection
P_REST_GYR_TH = 3  # rad/s
P_REST_ACC_TH = 4  # m/s²
P_REST_MIN = 5  # s
P_BIAS_CLIP = 6  # rad/s
P_BIAS_SIGMA_INIT = 7  # rad/s
P_BIAS_FORGET = 8  # s
P_BIAS_SIGMA_MOTION = 9  # rad/s
P_BIAS_VERT_FACTOR = 10  # 1
P_BIAS_SIGMA_REST = 11  # rad/s
P_MAG_CUR_TAU = 12  # s, low-pass of the current field norm and dip
P_MAG_REF_TAU = 13  # s, adaptation of the accepted reference
P_MAG_NORM_TH = 14  # 1, relative
P_MAG_DIP_TH = 15  # rad
P_MAG_NEW_T = 16  # s, a new steady field is accepted after this long (while rotating)
P_MAG_NEW_FIRST_T = 17  # s, same, when no reference was ever accepted
P_MAG_NEW_MIN_GYR = 18  # rad/s
P_MAG_MIN_UNDIST_T = 19  # s
P_MAG_MAX_REJECT_T = 20  # s
P_MAG_REJECT_FACTOR = 21  # 1
P_MOTION_BIAS_ON = 22
P_REST_BIAS_ON = 23
P_MAG_REJECT_ON = 24
P_BIAS_WALK = 25  # rad/s, bias standard deviation gained per `P_BIAS_FORGET` seconds
P_SCALE_ON = 26
P_SCALE_SIGMA_INIT = 27  # 1, prior std of the per-axis gyro scale correction
P_SCALE_WALK = 28  # 1, std gained per `P_BIAS_FORGET` seconds
P_SCALE_CLIP = 29  # 1
P_MAG_BEAR_TAU = 30  # s, the field's bearing in E6 is compared with its own average over about this long
P_MAG_BEAR_TH = 31  # rad, a bearing further than this from that average marks a disturbance; <= 0 disables
P_ACC_SPIKE_TH = 32  # m/s², a specific force this far from g is a shock (tap), not a reading; <= 0 disables
P_MAG_BEAR_LAG = 33  # s, allowance for magnetometer/gyro timing: the threshold grows by |rate| × this
P_MAG_HEADING_KF_ON = 34  # heading gain from a scalar Kalman filter (faster after a rejection); 0 = fixed gain
N_PARAMS = 35

# ---- state vector ----
S_QG = 0  # 4: strapdown quaternion body -> I
S_QI = 4  # 4: inclination correction I -> E6
S_DELTA = 8  # rad, heading of E6 in ENU
S_ACC_LP = 9  # 3 (output) + 6 (filter memory): specific force in I, low-passed
S_R_LP = 18  # 9 (output) + 18: rotation matrix E6<-body, low-passed like the acceleration
S_RB_LP = 45  # 2 (output) + 4: horizontal part of R·bias, low-passed
S_BIAS = 51  # 3, rad/s
S_SCALE = 54  # 3, per-axis gyro scale correction k: rate = (gyr - bias) * (1 + k)
S_BIAS_P = 57  # 36, covariance of (bias rad/s, k), row-major 6x6
S_REST_GYR = 93  # 3 + 6: gyro low-pass for rest detection
S_REST_ACC = 102  # 3 + 6: accelerometer low-pass for rest detection
S_REST_T = 111  # s of rest so far
S_REST = 112  # 1.0 at rest
S_MAG_CUR = 113  # 2 (norm uT, dip rad) + 4
S_MAG_REF_NORM = 119
S_MAG_REF_DIP = 120
S_MAG_UNDIST_T = 121
S_MAG_REJECT_T = 122
S_MAG_CAND_NORM = 123
S_MAG_CAND_DIP = 124
S_MAG_CAND_T = 125
S_MAG_DIST = 126  # 1.0 while the field is judged disturbed
S_K_MAG_INIT = 127  # fast initial heading gain (running mean), 0 when done
S_RU_LP = 128  # 9 + 18: R·diag(rate), low-passed (how a scale error shows in the earth frame)
S_RUK_LP = 155  # 2 + 4: horizontal part of R·diag(rate)·k, low-passed
S_MAG_BEAR = 161  # 2: the field's bearing in E6 (rad), smoothed like norm and dip, and its slow average
S_MAG_P = 163  # heading variance in units of the magnetometer's (NaN: steady state)
S_HEAD = 164  # 3: the heading delta for which the next two hold, cos(delta/2), sin(delta/2) (output rotation)
N_STATE = 167

# ---- per-call coefficients (derived from settings and dt) ----
C_ACC = 0  # 5: b0 b1 b2 a1 a2
C_REST = 5  # 5
C_MAG = 10  # 5
C_K_MAG = 15
C_K_REF = 16
C_BIAS_V = 17
C_BIAS_P0 = 18
C_W_MOTION = 19
C_W_VERT = 20
C_W_REST = 21
C_SCALE_V = 22
C_SCALE_P0 = 23
C_K_BEAR_FAST = 24  # first-order gains of the two bearing averages
C_K_BEAR_SLOW = 25
N_COEFFS = 26

W_Q6 = 80  # 4: body -> E6 quaternion of the current sample (NaN in [0]: not computed yet)
N_WORK = 84

# ---- context vector: all one device's filter holds (state, settings, coefficients, scratch) in one float64 array,
# so a call for a 10-sample packet passes one array instead of seven and numba's dispatcher checks fewer arguments
X_STATE = 0  # N_STATE
X_PRM = X_STATE + N_STATE  # N_PARAMS
X_COEFFS = X_PRM + N_PARAMS  # N_COEFFS
X_WORK = X_COEFFS + N_COEFFS  # N_WORK
X_DT = X_WORK + N_WORK  # s, the device's sample period
X_COEFFS_DT = X_DT + 1  # s, the period the coefficients were derived for (NaN: none yet)
X_Q = X_COEFFS_DT + 1  # 4: the last output quaternion
X_USE_MAG = X_Q + 4  # 1.0: 9D (batch rows; a single device passes the flag per call)
X_ACTIVE = X_USE_MAG + 1  # 1.0: the row takes part in this step (batch rows)
N_CTX = X_ACTIVE + 1


def new_state(settings: np.ndarray) -> np.ndarray:
    """A fresh state vector: identity attitude, zero bias with its initial uncertainty, filters uninitialised."""
    s = np.zeros(N_STATE)
    s[S_QG] = 1.0
    s[S_QI] = 1.0
    lowpasses = (
        (S_ACC_LP, 3), (S_R_LP, 9), (S_RB_LP, 2), (S_REST_GYR, 3), (S_REST_ACC, 3), (S_MAG_CUR, 2), (S_RU_LP, 9),
        (S_RUK_LP, 2),
    )
    for base, n in lowpasses:
        s[base + n : base + 3 * n] = np.nan  # NaN memory = "initialise from the first input"
    for i in range(3):
        s[S_BIAS_P + 7 * i] = settings[P_BIAS_SIGMA_INIT] ** 2
        s[S_BIAS_P + 7 * (i + 3)] = settings[P_SCALE_SIGMA_INIT] ** 2 if settings[P_SCALE_ON] != 0.0 else 0.0
    s[S_MAG_DIST] = 1.0
    s[S_MAG_REJECT_T] = settings[P_MAG_MAX_REJECT_T]
    s[S_MAG_CAND_NORM] = -1.0
    s[S_K_MAG_INIT] = 1.0
    s[S_MAG_BEAR : S_MAG_BEAR + 2] = np.nan  # set from the first field
    s[S_MAG_P] = np.nan
    s[S_HEAD : S_HEAD + 3] = (0.0, 1.0, 0.0)
    return s


@njit(cache=True, error_model="numpy")
def _qmul(
    aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float, bz: float
) -> tuple[float, float, float, float]:
    """Hamilton product a ⊗ b, scalar first."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True, error_model="numpy")
def _rotate(
    w: float, x: float, y: float, z: float, vx: float, vy: float, vz: float
) -> tuple[float, float, float]:
    """q ⊗ v ⊗ q* for a unit quaternion q."""
    return (
        (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y - w * z) * vy + 2.0 * (x * z + w * y) * vz,
        2.0 * (x * y + w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy + 2.0 * (y * z - w * x) * vz,
        2.0 * (x * z - w * y) * vx + 2.0 * (y * z + w * x) * vy + (1.0 - 2.0 * (x * x + y * y)) * vz,
    )


@njit(cache=True, error_model="numpy", inline="always")
def _normalise_q(s: np.ndarray, k: int) -> None:
    r = 1.0 / math.sqrt(s[k] ** 2 + s[k + 1] ** 2 + s[k + 2] ** 2 + s[k + 3] ** 2)
    s[k] *= r
    s[k + 1] *= r
    s[k + 2] *= r
    s[k + 3] *= r


@njit(cache=True, error_model="numpy")
def _butter2(tau_s: float, dt_s: float, c: np.ndarray, k: int) -> None:
    """Second-order Butterworth low-pass, cutoff fc = 1/(2π·tau), bilinear transform with pre-warping.

    Writes b0 b1 b2 a1 a2 to c[k:k+5]; falls back to pass-through when fc nears Nyquist (tau < dt/π).
    """
    if tau_s * math.pi < dt_s:
        c[k], c[k + 1], c[k + 2], c[k + 3], c[k + 4] = 1.0, 0.0, 0.0, 0.0, 0.0
        return
    w = math.tan(0.5 * dt_s / tau_s)  # tan(π fc dt)
    d = w * w + math.sqrt(2.0) * w + 1.0
    b0 = w * w / d
    c[k] = b0
    c[k + 1] = 2.0 * b0
    c[k + 2] = b0
    c[k + 3] = 2.0 * (w * w - 1.0) / d
    c[k + 4] = (w * w - math.sqrt(2.0) * w + 1.0) / d


@njit(cache=True, error_model="numpy", inline="always")
def _lowpass(x: float, c: np.ndarray, kc: int, s: np.ndarray, ks: int) -> float:
    """One step of the biquad (transposed direct form II) whose memory is s[ks], s[ks+1].

    NaN memory is replaced by the steady state for input x, so a filter starts at its first sample without a jump.
    """
    b0 = c[kc]
    if math.isnan(s[ks]):
        s[ks] = (1.0 - b0) * x
        s[ks + 1] = (c[kc + 2] - c[kc + 4]) * x
    y: float = b0 * x + s[ks]
    s[ks] = c[kc + 1] * x - c[kc + 3] * y + s[ks + 1]
    s[ks + 1] = c[kc + 2] * x - c[kc + 4] * y
    return y


@njit(cache=True, error_model="numpy", inline="always")
def _lowpass_vec(x: np.ndarray, xo: int, n: int, c: np.ndarray, kc: int, s: np.ndarray, base: int) -> None:
    """Filter x[xo:xo+n] in place with the n-channel filter stored at s[base:base+3n] (outputs, then 2 memories
    each). The channels start together, so one NaN test serves all; coefficients are read once."""
    b0, b1, b2, a1, a2 = c[kc], c[kc + 1], c[kc + 2], c[kc + 3], c[kc + 4]
    m = base + n
    if math.isnan(s[m]):
        for i in range(n):
            s[m + 2 * i] = (1.0 - b0) * x[xo + i]
            s[m + 2 * i + 1] = (b2 - a2) * x[xo + i]
    for i in range(n):
        xi = x[xo + i]
        k = m + 2 * i
        y = b0 * xi + s[k]
        s[k] = b1 * xi - a1 * y + s[k + 1]
        s[k + 1] = b2 * xi - a2 * y
        s[base + i] = y
        x[xo + i] = y


@njit(cache=True, error_model="numpy")
def _gain(tau_s: float, dt_s: float) -> float:
    """First-order gain k = 1 - exp(-dt/tau); tau < 0 disables (k = 0), tau = 0 passes through (k = 1)."""
    if tau_s < 0.0:
        return 0.0
    if tau_s == 0.0:
        return 1.0
    return 1.0 - math.exp(-dt_s / tau_s)


@njit(cache=True, error_model="numpy")
def coefficients(prm: np.ndarray, dt_s: float, c: np.ndarray) -> None:
    """Derive the per-rate coefficients from the settings vector and the sample period."""
    _butter2(prm[P_TAU_ACC], dt_s, c, C_ACC)
    _butter2(prm[P_REST_TAU], dt_s, c, C_REST)
    _butter2(prm[P_MAG_CUR_TAU], dt_s, c, C_MAG)
    c[C_K_MAG] = _gain(prm[P_TAU_MAG], dt_s)
    c[C_K_REF] = _gain(prm[P_MAG_REF_TAU], dt_s)
    # Random-walk bias: its variance grows by v per sample, walk² per `forget` seconds (capped at sigma_init²);
    # the measurement noise w = p(p+v)/v makes the steady-state posterior variance exactly p.
    v = prm[P_BIAS_WALK] ** 2 * dt_s / prm[P_BIAS_FORGET]
    c[C_BIAS_V] = v
    c[C_BIAS_P0] = prm[P_BIAS_SIGMA_INIT] ** 2
    pm = prm[P_BIAS_SIGMA_MOTION] ** 2
    c[C_W_MOTION] = pm * (pm + v) / v
    c[C_W_VERT] = c[C_W_MOTION] / max(prm[P_BIAS_VERT_FACTOR], 1e-10)
    pr = prm[P_BIAS_SIGMA_REST] ** 2
    c[C_W_REST] = pr * (pr + v) / v
    on = prm[P_SCALE_ON] != 0.0
    c[C_SCALE_V] = prm[P_SCALE_WALK] ** 2 * dt_s / prm[P_BIAS_FORGET] if on else 0.0
    c[C_SCALE_P0] = prm[P_SCALE_SIGMA_INIT] ** 2 if on else 0.0
    c[C_K_BEAR_FAST] = _gain(prm[P_MAG_CUR_TAU], dt_s)
    c[C_K_BEAR_SLOW] = _gain(prm[P_MAG_BEAR_TAU], dt_s)


@njit(cache=True, error_model="numpy")
def _wrap(a: float) -> float:
    if a > math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


@njit(cache=True, error_model="numpy", inline="always")
def _predict_bias(s: np.ndarray, c: np.ndarray) -> None:
    """Bounded random walk of bias and scale: the variances grow until they reach their prior."""
    for i in range(3):
        if s[S_BIAS_P + 7 * i] < c[C_BIAS_P0]:
            s[S_BIAS_P + 7 * i] += c[C_BIAS_V]
        if s[S_BIAS_P + 7 * (i + 3)] < c[C_SCALE_P0]:
            s[S_BIAS_P + 7 * (i + 3)] += c[C_SCALE_V]


@njit(cache=True, error_model="numpy")  # not inlined: once per sample, and inlining doubled compile time
def _bias_update(s: np.ndarray, prm: np.ndarray, c: np.ndarray, wk: np.ndarray) -> None:
    """Kalman update of x = (bias rad/s, scale k): the paper's bias filter, extended by the scale states.

    Innovation e = wk[0:3], measurement matrix H = wk[3:21] (3x6 row-major), noise variances wk[21:24].
    Scratch (no allocation per sample): P H^T at wk[24:42], S at wk[42:51], S^-1 at wk[51:60], K at wk[60:78].
    """
    _predict_bias(s, c)
    p = S_BIAS_P
    for i in range(6):  # P H^T (6x3)
        for j in range(3):
            acc = 0.0
            for m in range(6):
                acc += s[p + 6 * i + m] * wk[3 + 6 * j + m]
            wk[24 + 3 * i + j] = acc
    for i in range(3):  # S = H P H^T + W (3x3, symmetric: upper triangle, mirrored)
        for j in range(i, 3):
            acc = 0.0
            for m in range(6):
                acc += wk[3 + 6 * i + m] * wk[24 + 3 * m + j]
            wk[42 + 3 * i + j] = acc
            wk[42 + 3 * j + i] = acc
        wk[42 + 4 * i] += wk[21 + i]
    a, b, cc = wk[42], wk[43], wk[44]  # S^-1 by cofactors
    d, e, f = wk[45], wk[46], wk[47]
    g, h, k = wk[48], wk[49], wk[50]
    c00 = e * k - f * h
    c01 = f * g - d * k
    c02 = d * h - e * g
    inv_det = 1.0 / (a * c00 + b * c01 + cc * c02)
    wk[51] = c00 * inv_det
    wk[52] = (cc * h - b * k) * inv_det
    wk[53] = (b * f - cc * e) * inv_det
    wk[54] = c01 * inv_det
    wk[55] = (a * k - cc * g) * inv_det
    wk[56] = (cc * d - a * f) * inv_det
    wk[57] = c02 * inv_det
    wk[58] = (b * g - a * h) * inv_det
    wk[59] = (a * e - b * d) * inv_det
    for i in range(6):  # K = P H^T S^-1 (6x3)
        for j in range(3):
            acc = 0.0
            for m in range(3):
                acc += wk[24 + 3 * i + m] * wk[51 + 3 * m + j]
            wk[60 + 3 * i + j] = acc
    clip_b = prm[P_BIAS_CLIP]
    clip_k = prm[P_SCALE_CLIP]
    e0 = min(max(wk[0], -clip_b), clip_b)
    e1 = min(max(wk[1], -clip_b), clip_b)
    e2 = min(max(wk[2], -clip_b), clip_b)
    for i in range(6):  # x += K e, clipped
        dx = wk[60 + 3 * i] * e0 + wk[61 + 3 * i] * e1 + wk[62 + 3 * i] * e2
        if i < 3:
            s[S_BIAS + i] = min(max(s[S_BIAS + i] + dx, -clip_b), clip_b)
        else:
            s[S_SCALE + i - 3] = min(max(s[S_SCALE + i - 3] + dx, -clip_k), clip_k)
    for i in range(6):  # P -= K (P H^T)^T, symmetric: upper triangle, mirrored
        for j in range(i, 6):
            v = s[p + 6 * i + j] - (
                wk[60 + 3 * i] * wk[24 + 3 * j] + wk[61 + 3 * i] * wk[25 + 3 * j] + wk[62 + 3 * i] * wk[26 + 3 * j]
            )
            s[p + 6 * i + j] = v
            s[p + 6 * j + i] = v


@njit(cache=True, error_model="numpy", inline="always")
def _step_sample(
    s: np.ndarray, prm: np.ndarray, c: np.ndarray, wk: np.ndarray,
    gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
    mx: float, my: float, mz: float, use_mag: bool, dt_s: float,
) -> None:
    """Advance one device's state by one sample (gyro rad/s, specific force m/s², field uT).

    A non-finite gyro sample is skipped (the state stays); a non-finite or zero acc / mag sample means "no reading".
    """
    wk[W_Q6] = math.nan
    if not math.isfinite(gx + gy + gz):
        return
    if not math.isfinite(ax + ay + az):
        ax = ay = az = 0.0
    spike = prm[P_ACC_SPIKE_TH]
    if spike > 0.0:  # | |a| - g | > spike, without a square root
        a2 = ax * ax + ay * ay + az * az
        if a2 > (GRAVITY_M_S2 + spike) ** 2 or (spike < GRAVITY_M_S2 and a2 < (GRAVITY_M_S2 - spike) ** 2):
            ax = ay = az = 0.0  # a shock: the structure rings, and aliased samples of it do not average out
    rest_on = prm[P_REST_BIAS_ON] != 0.0
    # -- rest detection, gyro half: deviation from its own low-pass, and a low-pass that must look like a bias
    if rest_on or prm[P_MAG_REJECT_ON] != 0.0:
        wk[0], wk[1], wk[2] = gx, gy, gz
        _lowpass_vec(wk, 0, 3, c, C_REST, s, S_REST_GYR)
        dev2 = (gx - wk[0]) ** 2 + (gy - wk[1]) ** 2 + (gz - wk[2]) ** 2
        big = max(abs(wk[0]), max(abs(wk[1]), abs(wk[2]))) > prm[P_BIAS_CLIP]
        if dev2 >= prm[P_REST_GYR_TH] ** 2 or big:
            s[S_REST_T] = 0.0
            s[S_REST] = 0.0
    # -- strapdown integration of the bias-free rate (exact for constant rate over dt)
    ux = gx - s[S_BIAS]  # bias-free rate before the scale correction
    uy = gy - s[S_BIAS + 1]
    uz = gz - s[S_BIAS + 2]
    wx = ux * (1.0 + s[S_SCALE])
    wy = uy * (1.0 + s[S_SCALE + 1])
    wz = uz * (1.0 + s[S_SCALE + 2])
    h2 = 0.25 * (wx * wx + wy * wy + wz * wz) * dt_s * dt_s  # (half the rotation angle)²
    if h2 < 0.0025:  # below 0.05 rad per half step (28 °/s·ms): Taylor series, error < 1e-15
        cs = 1.0 - 0.5 * h2 * (1.0 - h2 / 12.0 * (1.0 - h2 / 30.0))
        sc = 0.5 * dt_s * (1.0 - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0)))  # sin(half) / |w|
    else:
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        half = 0.5 * wn * dt_s
        cs = math.cos(half)
        sc = math.sin(half) / wn
    q = _qmul(s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3], cs, sc * wx, sc * wy, sc * wz)
    s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3] = q
    _normalise_q(s, S_QG)
    if ax == 0.0 and ay == 0.0 and az == 0.0:
        return  # no accelerometer sample
    # -- rest detection, accelerometer half
    if rest_on:
        wk[0], wk[1], wk[2] = ax, ay, az
        _lowpass_vec(wk, 0, 3, c, C_REST, s, S_REST_ACC)
        dev2 = (ax - wk[0]) ** 2 + (ay - wk[1]) ** 2 + (az - wk[2]) ** 2
        if dev2 >= prm[P_REST_ACC_TH] ** 2:
            s[S_REST_T] = 0.0
            s[S_REST] = 0.0
        else:
            s[S_REST_T] += dt_s
            if s[S_REST_T] >= prm[P_REST_MIN]:
                s[S_REST] = 1.0
    # -- inclination: low-pass the specific force in I, rotate to E6, turn it fully vertical
    fx, fy, fz = _rotate(s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3], ax, ay, az)
    wk[0], wk[1], wk[2] = fx, fy, fz
    _lowpass_vec(wk, 0, 3, c, C_ACC, s, S_ACC_LP)
    ex, ey, ez = _rotate(s[S_QI], s[S_QI + 1], s[S_QI + 2], s[S_QI + 3], wk[0], wk[1], wk[2])
    en = math.sqrt(ex * ex + ey * ey + ez * ez)
    if en == 0.0:
        return
    ex /= en
    ey /= en
    ez /= en
    cw = math.sqrt(max(0.5 * (ez + 1.0), 0.0))
    if cw > 1e-6:  # shortest rotation taking (ex, ey, ez) onto +z
        q = _qmul(cw, 0.5 * ey / cw, -0.5 * ex / cw, 0.0, s[S_QI], s[S_QI + 1], s[S_QI + 2], s[S_QI + 3])
    else:  # upside down: any half-turn about a horizontal axis
        q = _qmul(0.0, 1.0, 0.0, 0.0, s[S_QI], s[S_QI + 1], s[S_QI + 2], s[S_QI + 3])
    s[S_QI], s[S_QI + 1], s[S_QI + 2], s[S_QI + 3] = q
    _normalise_q(s, S_QI)
    qw, qx, qy, qz = _qmul(
        s[S_QI], s[S_QI + 1], s[S_QI + 2], s[S_QI + 3], s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3]
    )
    wk[W_Q6], wk[W_Q6 + 1], wk[W_Q6 + 2], wk[W_Q6 + 3] = qw, qx, qy, qz
    # -- gyro bias and scale (measurement: the inclination correction just applied, or the gyro at rest)
    motion_on = prm[P_MOTION_BIAS_ON] != 0.0
    if motion_on or rest_on:
        # rotation matrix E6 <- body, row-major, into wk[3:12]
        wk[3] = 1.0 - 2.0 * (qy * qy + qz * qz)
        wk[4] = 2.0 * (qx * qy - qw * qz)
        wk[5] = 2.0 * (qx * qz + qw * qy)
        wk[6] = 2.0 * (qx * qy + qw * qz)
        wk[7] = 1.0 - 2.0 * (qx * qx + qz * qz)
        wk[8] = 2.0 * (qy * qz - qw * qx)
        wk[9] = 2.0 * (qx * qz - qw * qy)
        wk[10] = 2.0 * (qy * qz + qw * qx)
        wk[11] = 1.0 - 2.0 * (qx * qx + qy * qy)
        bx, by, bz = s[S_BIAS], s[S_BIAS + 1], s[S_BIAS + 2]
        kx, ky, kz = s[S_SCALE], s[S_SCALE + 1], s[S_SCALE + 2]
        scale_on = prm[P_SCALE_ON] != 0.0
        # horizontal earth-frame rates the current bias and scale estimates already remove, filtered like the
        # acceleration so they line up in time with the corrections they explain
        wk[21] = wk[3] * bx + wk[4] * by + wk[5] * bz
        wk[22] = wk[6] * bx + wk[7] * by + wk[8] * bz
        _lowpass_vec(wk, 21, 2, c, C_ACC, s, S_RB_LP)
        rb0, rb1 = wk[21], wk[22]
        if scale_on:
            wk[21] = wk[3] * ux * kx + wk[4] * uy * ky + wk[5] * uz * kz
            wk[22] = wk[6] * ux * kx + wk[7] * uy * ky + wk[8] * uz * kz
            _lowpass_vec(wk, 21, 2, c, C_ACC, s, S_RUK_LP)
            ruk0, ruk1 = wk[21], wk[22]
            for i in range(3):  # R diag(u) at wk[24:33], low-passed into the state, then into H below
                wk[24 + 3 * i] = wk[3 + 3 * i] * ux
                wk[25 + 3 * i] = wk[4 + 3 * i] * uy
                wk[26 + 3 * i] = wk[5 + 3 * i] * uz
            _lowpass_vec(wk, 24, 9, c, C_ACC, s, S_RU_LP)
        else:
            ruk0 = ruk1 = 0.0
        _lowpass_vec(wk, 3, 9, c, C_ACC, s, S_R_LP)
        # H = [LP(R), -LP(R diag u)] (3x6) at wk[3:21]
        for i in range(3):
            for j in range(3):
                wk[3 + 6 * i + j] = s[S_R_LP + 3 * i + j]
                wk[6 + 6 * i + j] = -s[S_RU_LP + 3 * i + j] if scale_on else 0.0
        if rest_on and s[S_REST] != 0.0:
            # at rest the low-passed gyro is the bias; the scale is not observed
            wk[0] = s[S_REST_GYR] - bx
            wk[1] = s[S_REST_GYR + 1] - by
            wk[2] = s[S_REST_GYR + 2] - bz
            for i in range(18):
                wk[3 + i] = 0.0
            wk[3] = wk[10] = wk[17] = 1.0
            wk[21] = wk[22] = wk[23] = c[C_W_REST]
            _bias_update(s, prm, c, wk)
        elif motion_on:
            # the correction just applied is an earth-frame rate (-ey, ex, 0)/dt; predicted: H x, with the
            # current estimates' own contribution (rb - ruk) already removed from the integrated rate
            for i in range(3):
                hx = 0.0
                for j in range(3):
                    hx += wk[3 + 6 * i + j] * s[S_BIAS + j] + wk[6 + 6 * i + j] * s[S_SCALE + j]
                wk[i] = -hx
            wk[0] += -ey / dt_s + rb0 - ruk0
            wk[1] += ex / dt_s + rb1 - ruk1
            wk[21] = wk[22] = c[C_W_MOTION]
            wk[23] = c[C_W_VERT]
            _bias_update(s, prm, c, wk)
        else:  # only rest estimation, not at rest: the uncertainty still grows
            _predict_bias(s, c)
    if use_mag and not (mx == 0.0 and my == 0.0 and mz == 0.0) and math.isfinite(mx + my + mz):
        _mag_step(s, prm, c, qw, qx, qy, qz, mx, my, mz, dt_s)


@njit(cache=True, error_model="numpy", inline="always")
def _mag_step(
    s: np.ndarray, prm: np.ndarray, c: np.ndarray, qw: float, qx: float, qy: float, qz: float,
    mx: float, my: float, mz: float, dt_s: float,
) -> None:
    """Heading correction (body -> E6 attitude q) with magnetic disturbance detection by field norm and dip."""
    hx, hy, hz = _rotate(qw, qx, qy, qz, mx, my, mz)
    norm = math.sqrt(hx * hx + hy * hy + hz * hz)
    if not norm > 1e-9:
        return  # no usable field
    bearing = math.atan2(hx, hy)  # ENU: the horizontal field points North (+y)
    if prm[P_MAG_REJECT_ON] != 0.0:
        dip = -math.asin(max(-1.0, min(1.0, hz / norm)))
        norm = _lowpass(norm, c, C_MAG, s, S_MAG_CUR + 2)
        dip = _lowpass(dip, c, C_MAG, s, S_MAG_CUR + 4)
        s[S_MAG_CUR], s[S_MAG_CUR + 1] = norm, dip
        th_n = prm[P_MAG_NORM_TH]
        th_d = prm[P_MAG_DIP_TH]
        k_ref = c[C_K_REF]
        ref_n = s[S_MAG_REF_NORM]
        # a homogeneous field keeps its bearing in the gyro-propagated frame E6; a magnet fixed to the body turns
        # it with the body, a magnet in the room changes it along the path, often with little change of norm or dip
        steady = _bearing_steady(s, prm, c, bearing)
        if abs(norm - ref_n) < th_n * ref_n and abs(dip - s[S_MAG_REF_DIP]) < th_d and steady:
            s[S_MAG_UNDIST_T] += dt_s
            if s[S_MAG_UNDIST_T] >= prm[P_MAG_MIN_UNDIST_T]:
                s[S_MAG_DIST] = 0.0
                s[S_MAG_REF_NORM] += k_ref * (norm - ref_n)
                s[S_MAG_REF_DIP] += k_ref * (dip - s[S_MAG_REF_DIP])
        else:
            s[S_MAG_UNDIST_T] = 0.0
            s[S_MAG_DIST] = 1.0
        # a new homogeneous field replaces the reference once it has stayed consistent while the body rotated
        cand_n = s[S_MAG_CAND_NORM]
        if abs(norm - cand_n) < th_n * cand_n and abs(dip - s[S_MAG_CAND_DIP]) < th_d and steady:
            g2 = s[S_REST_GYR] ** 2 + s[S_REST_GYR + 1] ** 2 + s[S_REST_GYR + 2] ** 2
            if g2 >= prm[P_MAG_NEW_MIN_GYR] ** 2:
                s[S_MAG_CAND_T] += dt_s
            s[S_MAG_CAND_NORM] += k_ref * (norm - cand_n)
            s[S_MAG_CAND_DIP] += k_ref * (dip - s[S_MAG_CAND_DIP])
            if s[S_MAG_DIST] != 0.0 and (
                s[S_MAG_CAND_T] >= prm[P_MAG_NEW_T]
                or (s[S_MAG_REF_NORM] == 0.0 and s[S_MAG_CAND_T] >= prm[P_MAG_NEW_FIRST_T])
            ):
                s[S_MAG_REF_NORM] = s[S_MAG_CAND_NORM]
                s[S_MAG_REF_DIP] = s[S_MAG_CAND_DIP]
                s[S_MAG_DIST] = 0.0
                s[S_MAG_UNDIST_T] = prm[P_MAG_MIN_UNDIST_T]
        else:
            s[S_MAG_CAND_T] = 0.0
            s[S_MAG_CAND_NORM] = norm
            s[S_MAG_CAND_DIP] = dip
    err = _wrap(bearing - s[S_DELTA])
    k = c[C_K_MAG]
    if prm[P_MAG_REJECT_ON] != 0.0:
        if s[S_MAG_DIST] != 0.0:
            if s[S_MAG_REJECT_T] <= prm[P_MAG_MAX_REJECT_T]:
                s[S_MAG_REJECT_T] += dt_s
                k = 0.0
            else:  # rejected for too long: accept the field again, but slowly
                k /= prm[P_MAG_REJECT_FACTOR]
        else:
            s[S_MAG_REJECT_T] = max(s[S_MAG_REJECT_T] - prm[P_MAG_REJECT_FACTOR] * dt_s, 0.0)
    kss = c[C_K_MAG]
    if prm[P_MAG_HEADING_KF_ON] != 0.0 and 0.0 < kss < 1.0:
        # heading as a scalar Kalman filter (measurement variance 1): the random walk q = kss²/(1 - kss) makes the
        # steady-state gain exactly kss, so nothing changes while the field is used; while it is rejected the
        # variance grows by q per sample, so after T seconds without correction the gain is about kss·(1 + T/tau):
        # the drift gathered meanwhile is taken out quickly once the field is clean again
        p = s[S_MAG_P]
        if math.isnan(p):
            p = kss
        p += kss * kss / (1.0 - kss)
        k = p / (p + 1.0) * (k / kss)  # rejection (0) and long rejection (1/factor) scale the gain
        s[S_MAG_P] = (1.0 - k) * p
    ki = s[S_K_MAG_INIT]
    if ki != 0.0:  # start: average the first headings (gain 1, 1/2, 1/3, ...) until the regular gain takes over
        k = max(k, ki)
        ki = ki / (ki + 1.0)
        s[S_K_MAG_INIT] = 0.0 if ki * prm[P_TAU_MAG] < dt_s else ki
    s[S_DELTA] = _wrap(s[S_DELTA] + k * err)


@njit(cache=True, error_model="numpy", inline="always")
def _bearing_steady(s: np.ndarray, prm: np.ndarray, c: np.ndarray, bearing: float) -> bool:
    """Track the field's bearing in E6 (fast and slow first-order averages, wrap-aware); False while the smoothed
    bearing is further than the threshold from its slow average, i.e. the field turns in a frame it should be fixed in.
    """
    th = prm[P_MAG_BEAR_TH]
    if th <= 0.0:  # test off: no averages to keep (the slots just hold the latest bearing)
        s[S_MAG_BEAR] = bearing
        s[S_MAG_BEAR + 1] = bearing
        return True
    if math.isnan(s[S_MAG_BEAR]):
        s[S_MAG_BEAR] = bearing
        s[S_MAG_BEAR + 1] = bearing
    fast = _wrap(s[S_MAG_BEAR] + c[C_K_BEAR_FAST] * _wrap(bearing - s[S_MAG_BEAR]))
    slow = _wrap(s[S_MAG_BEAR + 1] + c[C_K_BEAR_SLOW] * _wrap(fast - s[S_MAG_BEAR + 1]))
    s[S_MAG_BEAR] = fast
    s[S_MAG_BEAR + 1] = slow
    dev = abs(_wrap(fast - slow))
    # a magnetometer sampled a few ms apart from the gyro sees the bearing shifted by rate × lag in fast rotation
    g2 = s[S_REST_GYR] ** 2 + s[S_REST_GYR + 1] ** 2 + s[S_REST_GYR + 2] ** 2
    allowed: float = th + math.sqrt(g2) * prm[P_MAG_BEAR_LAG]
    return dev < allowed


@njit(cache=True, error_model="numpy", inline="always")
def _heading_half(s: np.ndarray) -> tuple[float, float]:
    """cos and sin of delta/2, kept in the state and turned by each sample's small step of delta (Taylor series,
    no trigonometric call); a large step (start, wrap at ±π, a set state) is recomputed exactly."""
    d = s[S_DELTA] - s[S_HEAD]
    ch, sh = s[S_HEAD + 1], s[S_HEAD + 2]
    if d == 0.0:
        return ch, sh
    if abs(d) < 0.02:
        y = 0.5 * d
        y2 = y * y
        cy = 1.0 - 0.5 * y2 * (1.0 - y2 / 12.0)  # error < y⁶/720 < 2e-15
        sy = y * (1.0 - y2 / 6.0 * (1.0 - y2 / 20.0))
        ch, sh = ch * cy - sh * sy, sh * cy + ch * sy
    else:
        ch, sh = math.cos(0.5 * s[S_DELTA]), math.sin(0.5 * s[S_DELTA])
    s[S_HEAD], s[S_HEAD + 1], s[S_HEAD + 2] = s[S_DELTA], ch, sh
    return ch, sh


@njit(cache=True, error_model="numpy", inline="always")
def _output(s: np.ndarray, wk: np.ndarray, use_mag: bool, out: np.ndarray, i: int) -> None:
    """out[i] = body -> ENU quaternion: heading delta about +z applied to the body -> E6 attitude."""
    if math.isnan(wk[W_Q6]):  # the sample did not reach the inclination step: compute it here
        qw, qx, qy, qz = _qmul(
            s[S_QI], s[S_QI + 1], s[S_QI + 2], s[S_QI + 3], s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3]
        )
    else:
        qw, qx, qy, qz = wk[W_Q6], wk[W_Q6 + 1], wk[W_Q6 + 2], wk[W_Q6 + 3]
    if use_mag:
        ch, sh = _heading_half(s)
        qw, qx, qy, qz = _qmul(ch, 0.0, 0.0, sh, qw, qx, qy, qz)
    out[i, 0] = qw
    out[i, 1] = qx
    out[i, 2] = qy
    out[i, 3] = qz


@njit(cache=True, error_model="numpy", inline="always")  # inlined into `_step_context` only: 15-30 % faster there
def _step_one(
    s: np.ndarray, prm: np.ndarray, c: np.ndarray, wk: np.ndarray,
    gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, use_mag: bool, dt_s: float, out: np.ndarray,
) -> None:
    for i in range(gyr.shape[0]):
        _step_sample(
            s, prm, c, wk, gyr[i, 0], gyr[i, 1], gyr[i, 2], acc[i, 0], acc[i, 1], acc[i, 2],
            mag[i, 0], mag[i, 1], mag[i, 2], use_mag, dt_s,
        )
        _output(s, wk, use_mag, out, i)


def new_context(settings: np.ndarray, state: np.ndarray) -> np.ndarray:
    """A context vector (N_CTX,) holding `state` and the settings vector; period unset, 6D, active."""
    x = np.zeros(N_CTX)
    x[X_STATE : X_STATE + N_STATE] = state
    x[X_PRM : X_PRM + N_PARAMS] = settings
    x[X_DT] = math.nan
    x[X_COEFFS_DT] = math.nan
    x[X_Q : X_Q + 4] = state[S_QG : S_QG + 4]
    x[X_ACTIVE] = 1.0
    return x


@njit(cache=True, error_model="numpy", inline="always")
def _context_step(
    x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, use_mag: bool, out: np.ndarray
) -> None:
    """Filter n samples with the context x (N_CTX,): coefficients follow x[X_DT], the last quaternion goes to x[X_Q]."""
    dt_s = x[X_DT]
    prm = x[X_PRM : X_PRM + N_PARAMS]
    c = x[X_COEFFS : X_COEFFS + N_COEFFS]
    if dt_s != x[X_COEFFS_DT]:
        coefficients(prm, dt_s, c)
        x[X_COEFFS_DT] = dt_s
    _step_one(x[X_STATE : X_STATE + N_STATE], prm, c, x[X_WORK : X_WORK + N_WORK], gyr, acc, mag, use_mag, dt_s, out)
    n = gyr.shape[0]
    if n > 0:
        for k in range(4):
            x[X_Q + k] = out[n - 1, k]


@njit(cache=True, error_model="numpy")
def _step_context(
    x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, use_mag: bool, out: np.ndarray
) -> None:
    """One device, n samples: context x (N_CTX,) with x[X_DT] > 0, inputs (n, 3), quaternions written to out (n, 4).

    Shapes are checked here (the kernel does not bounds-check its indexing)."""
    n = gyr.shape[0]
    if x.shape[0] != N_CTX or gyr.shape[1] != 3 or acc.shape != gyr.shape or mag.shape != gyr.shape:
        raise ValueError("context must be (N_CTX,) and gyr, acc, mag (n, 3) each")
    if out.shape[0] != n or out.shape[1] != 4:
        raise ValueError("out must be (n, 4)")
    _context_step(x, gyr, acc, mag, use_mag, out)


@njit(cache=True, error_model="numpy")
def _step_context_sample(
    x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, use_mag: bool, q: np.ndarray
) -> None:
    """One sample: inputs (3,) each, the body->ENU quaternion written to q (4,) and x[X_Q]."""
    if x.shape[0] != N_CTX or gyr.shape[0] != 3 or acc.shape[0] != 3 or mag.shape[0] != 3 or q.shape[0] != 4:
        raise ValueError("context must be (N_CTX,), gyr, acc, mag (3,) and q (4,)")
    _step_context(x, gyr.reshape((1, 3)), acc.reshape((1, 3)), mag.reshape((1, 3)), use_mag, q.reshape((1, 4)))


_C1 = "float64[::1]"
_C2 = "float64[:, ::1]"
_C3 = "float64[:, :, ::1]"


def _fixed(dispatcher: Any, signature: str) -> Any:
    """The dispatcher compiled (or loaded from numba's cache) for `signature`, with compilation for other argument
    types disabled: a call with anything but C-contiguous float64 arrays of the right ndim raises TypeError at once
    (the caller converts and retries) instead of compiling a new version. The per-call type check stays numba's C
    fast path over the arguments. Only for a dispatcher no kernel compiled later calls (see `_fix_all`)."""
    dispatcher.compile(signature)  # a no-op when loaded or compiled already (e.g. as another kernel's callee)
    dispatcher.disable_compile()
    return dispatcher


_ROWS_SIG = f"void({_C2}, {_C3}, {_C3}, {_C3}, boolean, {_C3})"
_fixed_all = False


def _fix_all() -> None:
    """Fix every public kernel at once, callers before callees: `step_contexts*` and `_step_context_sample`
    compile `_step_context` as their callee, which fails once its compilation is off; fixing them one at a time
    made the outcome depend on which was asked for first and on what numba's cache held."""
    global _fixed_all
    if _fixed_all:
        return
    kernels = ((step_contexts, _ROWS_SIG), (step_contexts_serial, _ROWS_SIG),
               (_step_context_sample, f"void({_C1}, {_C1}, {_C1}, {_C1}, boolean, {_C1})"),
               (_step_context, f"void({_C1}, {_C2}, {_C2}, {_C2}, boolean, {_C2})"))  # fmt: skip
    for dispatcher, signature in kernels:
        dispatcher.compile(signature)
    for dispatcher, signature in kernels:
        _fixed(dispatcher, signature)
    _fixed_all = True


def context_kernel() -> Any:
    """`_step_context(x, gyr, acc, mag, use_mag, out)` for one device's n-sample block (see `_fixed`)."""
    _fix_all()
    return _step_context


def context_sample_kernel() -> Any:
    """`_step_context_sample(x, gyr, acc, mag, use_mag, q)` for one sample (see `_fixed`)."""
    _fix_all()
    return _step_context_sample


def rows_kernels() -> tuple[Any, Any]:
    """(`step_contexts`, `step_contexts_serial`) for N devices' n-sample blocks (see `_fixed`)."""
    _fix_all()
    return step_contexts, step_contexts_serial


@njit(cache=True, error_model="numpy", inline="always")
def _context_rows(x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, mag_on: bool, out: np.ndarray,
                  d: int) -> None:
    """Row d of a stacked context (N, N_CTX): its own period and 6D/9D flag; an inactive row's output is NaN."""
    row = x[d]
    if row[X_ACTIVE] != 0.0:
        _step_context(row, gyr[d], acc[d], mag[d], mag_on and row[X_USE_MAG] != 0.0, out[d])
    else:
        out[d, :, :] = math.nan


@njit(cache=True, error_model="numpy")
def _check_rows(x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, out: np.ndarray) -> None:
    if x.shape[1] != N_CTX or gyr.shape[0] != x.shape[0] or gyr.shape[2] != 3:
        raise ValueError("contexts must be (N, N_CTX) and gyr (N, n, 3)")
    if acc.shape != gyr.shape or mag.shape != gyr.shape:
        raise ValueError("gyr, acc, mag must have one shape")
    if out.shape[0] != gyr.shape[0] or out.shape[1] != gyr.shape[1] or out.shape[2] != 4:
        raise ValueError("out must be (N, n, 4)")


@njit(cache=True, error_model="numpy", parallel=True)
def step_contexts(x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, mag_on: bool,
                  out: np.ndarray) -> None:
    """N devices, n samples each: contexts (N, N_CTX), inputs (N, n, 3), out (N, n, 4); `mag_on=False` runs every
    row 6D for this step. Rows are independent, so they are spread over the cores (numba prange); for a handful of
    devices the thread start-up costs more than it saves: use `step_contexts_serial` (same results)."""
    _check_rows(x, gyr, acc, mag, out)
    for d in prange(x.shape[0]):
        _context_rows(x, gyr, acc, mag, mag_on, out, d)


@njit(cache=True, error_model="numpy")
def step_contexts_serial(x: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, mag_on: bool,
                         out: np.ndarray) -> None:
    """`step_contexts` on one thread."""
    _check_rows(x, gyr, acc, mag, out)
    for d in range(x.shape[0]):
        _context_rows(x, gyr, acc, mag, mag_on, out, d)
