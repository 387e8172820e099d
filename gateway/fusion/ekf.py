"""Quaternion extended Kalman filter of the crane-hook paper (seed 001), on filterpy, with a numba batch twin.

Paper model: state Q (scalar-first, body -> earth ENU); prediction by the third-order Picard update (eq. 9-12)
    Q_k = [I (1 - Δθ²/8) + (1/2 - Δθ²/48) ΔΘ] Q_{k-1},
which is linear in Q, so its matrix is also the transition Jacobian; observation (eq. 13-15)
    h(Q) = [C_n^b g̃; C_n^b m̃],
the earth-frame gravity and magnetic-field directions rotated into the body frame (unit vectors here), with the
analytic Jacobian (eq. 16-17, `observation_jacobian`); white process and measurement noise (eq. 18). The process
noise is the gyro white noise mapped into quaternion space, G W Gᵀ with G = (Δt/2) Ξ(Q).

The reference field m̃ is learnt from the initial rest window, so the local inclination is whatever the sensor saw
(East component zero by construction of the 9D initial attitude). The quaternion is renormalised after each update.

Beyond the paper (all off with `EkfSettings(paper=True)`):
- three gyro-bias states (random walk): BROAD's raw gyros are biased by up to 0.5 °/s;
- accelerometer noise inflated as |a| departs from the rest norm g₀ (linear acceleration, tapping), capped so
  long fast motion still gets some tilt correction;
- magnetometer noise inflated as |m| departs from the rest norm and the dip angle (field vs predicted up) from the
  rest dip (nearby iron and magnets), and the magnetometer innovation restricted to heading: its component along
  the predicted up direction is removed, so a disturbed field cannot tilt the estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from gateway.fusion import quaternion as quat
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.quaternion import njit

N_STATE = 7  # quaternion w, x, y, z + gyro bias x, y, z (rad/s); the bias block stays zero when `paper=True`


@dataclass(frozen=True)
class EkfSettings:
    """EKF tuning, one set for every device and trial. Noise figures are standard deviations."""

    gyr_noise_rad_s: float = 0.01
    """Gyro white noise per sample (rad/s); covers model error too."""
    acc_noise: float = 0.05
    """Accelerometer direction noise (unit-vector components, dimensionless)."""
    mag_noise: float = 0.03
    """Magnetometer direction noise (unit-vector components, dimensionless)."""
    paper: bool = False
    """True: the paper's filter only (no bias states, no gating, full magnetometer innovation)."""
    bias_init_rad_s: float = 0.01
    """Prior standard deviation of each gyro-bias state (rad/s)."""
    bias_walk_rad_s_sqrt_s: float = 2e-4
    """Gyro-bias random walk (rad/s per √s)."""
    acc_gate: float = 0.03
    """Relative deviation ||a| - g₀|/g₀ at which the accelerometer noise has doubled (grows quadratically)."""
    mag_norm_gate: float = 0.05
    """Relative deviation ||m| - m₀|/m₀ at which the magnetometer noise has doubled."""
    mag_dip_gate_rad: float = 0.05
    """Dip-angle deviation (rad) at which the magnetometer noise has doubled."""
    mag_heading_only: bool = True
    """Remove the magnetometer innovation's component along gravity (heading-only magnetometer)."""
    rest_gyr_rad_s: float = 0.02
    """Rest when |ω - b| stays below this (rad/s) ..."""
    rest_acc: float = 0.02
    """... and ||a| - g₀|/g₀ below this ..."""
    rest_time_s: float = 0.5
    """... for this long (s). At rest the bias is learnt (zero-rate update); while moving it is held."""
    zero_rate_noise_rad_s: float = 0.005
    """Noise of the zero-rate pseudo-measurement ω = b at rest (rad/s)."""
    acc_gate_max: float = 2.0
    """Cap on the accelerometer noise multiplier (0: no cap), so long fast motion still sees some correction."""

    def as_array(self) -> FloatArray:
        """Pack for the numba kernels: the paper flag zeroes every extension."""
        p = self.paper
        return np.array(
            [
                self.gyr_noise_rad_s,
                self.acc_noise,
                self.mag_noise,
                0.0 if p else self.bias_walk_rad_s_sqrt_s,
                0.0 if p else self.acc_gate,
                0.0 if p else self.mag_norm_gate,
                0.0 if p else self.mag_dip_gate_rad,
                0.0 if p or not self.mag_heading_only else 1.0,
                0.0 if p else self.rest_gyr_rad_s,
                self.rest_acc,
                self.rest_time_s,
                self.zero_rate_noise_rad_s,
                self.acc_gate_max,
            ]
        )


# --- pure maths (numba-compiled, callable from Python) -------------------------------------------------------------


@njit
def picard3_matrix(dtheta_rad: FloatArray) -> FloatArray:
    """Third-order Picard transition I (1 - Δθ²/8) + (1/2 - Δθ²/48) ΔΘ for body angle increments (eq. 9-12)."""
    x, y, z = dtheta_rad[0], dtheta_rad[1], dtheta_rad[2]
    th2 = x * x + y * y + z * z
    a = 1.0 - th2 / 8.0
    b = 0.5 - th2 / 48.0
    return np.array(
        [
            [a, -b * x, -b * y, -b * z],
            [b * x, a, b * z, -b * y],
            [b * y, -b * z, a, b * x],
            [b * z, b * y, -b * x, a],
        ]
    )


@njit
def xi_matrix(q: FloatArray) -> FloatArray:
    """Ξ(q), shape (4, 3): q ⊗ [0, ω] = Ξ(q) ω, the map from a body rate to a quaternion rate (times 2)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])


@njit
def rotate_to_body(q: FloatArray, v_earth: FloatArray) -> FloatArray:
    """C_n^b v = R(q)ᵀ v for a body -> earth quaternion (eq. 15, one block); q need not be normalised."""
    w = q[0]
    u = q[1:4]
    uv = u[0] * v_earth[0] + u[1] * v_earth[1] + u[2] * v_earth[2]
    cross = np.array(
        [
            u[1] * v_earth[2] - u[2] * v_earth[1],
            u[2] * v_earth[0] - u[0] * v_earth[2],
            u[0] * v_earth[1] - u[1] * v_earth[0],
        ]
    )
    out: FloatArray = (w * w - (u[0] * u[0] + u[1] * u[1] + u[2] * u[2])) * v_earth + 2.0 * uv * u - 2.0 * w * cross
    return out


@njit
def observation_jacobian(q: FloatArray, v_earth: FloatArray) -> FloatArray:
    """∂(C_n^b v)/∂q, shape (3, 4), analytic (eq. 16-17): [2wv - 2 u×v | 2(u·v)I + 2uvᵀ - 2vuᵀ + 2w[v]×]."""
    w = q[0]
    u = q[1:4]
    v = v_earth
    uv = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    jac = np.empty((3, 4))
    jac[0, 0] = 2.0 * (w * v[0] - (u[1] * v[2] - u[2] * v[1]))
    jac[1, 0] = 2.0 * (w * v[1] - (u[2] * v[0] - u[0] * v[2]))
    jac[2, 0] = 2.0 * (w * v[2] - (u[0] * v[1] - u[1] * v[0]))
    for i in range(3):
        for j in range(3):
            jac[i, 1 + j] = 2.0 * (u[i] * v[j] - v[i] * u[j])
        jac[i, 1 + i] += 2.0 * uv
    # + 2w [v]x
    jac[0, 2] += -2.0 * w * v[2]
    jac[0, 3] += 2.0 * w * v[1]
    jac[1, 1] += 2.0 * w * v[2]
    jac[1, 3] += -2.0 * w * v[0]
    jac[2, 1] += -2.0 * w * v[1]
    jac[2, 2] += 2.0 * w * v[0]
    return jac


@njit
def transition(x: FloatArray, gyr_rad_s: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """State prediction and its Jacobian: Picard-3 with the bias-corrected rate; bias constant (random walk)."""
    q = x[:4]
    bias = x[4:]
    phi = picard3_matrix((gyr_rad_s - bias) * dt_s)
    x_new = np.empty(N_STATE)
    x_new[:4] = phi @ q
    x_new[4:] = bias
    jac = np.eye(N_STATE)
    jac[:4, :4] = phi
    jac[:4, 4:] = -0.5 * dt_s * xi_matrix(q)
    return x_new, jac


@njit
def process_noise(q: FloatArray, dt_s: float, params: FloatArray) -> FloatArray:
    """Q = G W Gᵀ with G = (Δt/2) Ξ(q) and W = σ_g² I (eq. 18), plus the bias random walk."""
    g = 0.5 * dt_s * xi_matrix(q)
    qmat = np.zeros((N_STATE, N_STATE))
    qmat[:4, :4] = params[0] ** 2 * (g @ g.T)
    walk = params[3] ** 2 * dt_s
    for i in range(4, N_STATE):
        qmat[i, i] = walk
    return qmat


@njit
def rest_timer(
    rest_s: float, x: FloatArray, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, dt_s: float, ref: FloatArray,
    params: FloatArray,
) -> float:
    """Seconds the sensor has looked still (|ω - b| and ||a| - g₀| small); 0 while moving or if disabled."""
    if params[8] <= 0.0:
        return 0.0
    w = gyr_rad_s - x[4:]
    acc_norm = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    still = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2) < params[8] and abs(acc_norm - ref[0]) < params[9] * ref[0]
    return rest_s + dt_s if still else 0.0


@njit
def hold_bias(p: FloatArray) -> FloatArray:
    """While moving, drop the attitude-bias cross-covariance so no measurement moves the bias (a consider state)."""
    out = p.copy()
    out[:4, 4:] = 0.0
    out[4:, :4] = 0.0
    return out


@njit
def measurement(
    x: FloatArray,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    at_rest: bool,
    ref: FloatArray,
    params: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Measurement z, prediction h(x), Jacobian H and noise R for one sample (eq. 13-18, plus the extensions).

    Rows: accelerometer direction (3), magnetometer direction (3, if `use_mag`), zero-rate ω = b (3, if `at_rest`).
    `ref` = [g₀ (m/s²), m₀ (µT), dip₀ (rad), m̃_E, m̃_N, m̃_U]. With heading-only magnetometer, the mag rows of the
    residual and Jacobian are projected onto the plane normal to the predicted up direction.
    """
    q = x[:4]
    nz = 3 + (3 if use_mag else 0) + (3 if at_rest else 0)
    z = np.empty(nz)
    hx = np.empty(nz)
    hjac = np.zeros((nz, N_STATE))
    rmat = np.zeros((nz, nz))
    acc_norm = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    up = np.array([0.0, 0.0, 1.0])
    hx[:3] = rotate_to_body(q, up)
    # a zero specific force (free fall, a device sending zeros) has no direction: no innovation (it was NaN)
    a_hat = acc_m_s2 / acc_norm if acc_norm > 0.0 else hx[:3].copy()
    z[:3] = a_hat
    hjac[:3, :4] = observation_jacobian(q, up)
    sig_a = params[1]
    if params[4] > 0.0:
        infl = 1.0 + (abs(acc_norm - ref[0]) / ref[0] / params[4]) ** 2
        sig_a *= min(infl, params[12]) if params[12] > 0.0 else infl
    for i in range(3):
        rmat[i, i] = sig_a * sig_a
    k = 3
    if use_mag:
        mag_norm = np.sqrt(mag_uT[0] ** 2 + mag_uT[1] ** 2 + mag_uT[2] ** 2)
        m_ref = ref[3:6]
        hx[3:6] = rotate_to_body(q, m_ref)
        m_hat = mag_uT / mag_norm if mag_norm > 0.0 else hx[3:6].copy()  # no field (zeros): no innovation
        z[3:6] = m_hat
        hjac[3:6, :4] = observation_jacobian(q, m_ref)
        sig_m = params[2]
        if params[5] > 0.0:
            sig_m *= 1.0 + (abs(mag_norm - ref[1]) / ref[1] / params[5]) ** 2
        # the predicted up direction, not the measured one: linear acceleration must not reject the magnetometer
        up_b = hx[:3] / np.sqrt(np.sum(hx[:3] ** 2))
        if params[6] > 0.0:
            dot = up_b[0] * m_hat[0] + up_b[1] * m_hat[1] + up_b[2] * m_hat[2]
            dip = np.arcsin(min(1.0, max(-1.0, dot)))
            sig_m *= 1.0 + ((dip - ref[2]) / params[6]) ** 2
        for i in range(3, 6):
            rmat[i, i] = sig_m * sig_m
        if params[7] > 0.0:
            # heading only: z_m and h_m lose their component along the predicted up direction. R stays σ²I: in a
            # basis along/normal to up its along-up part meets a zero residual and a zero Jacobian row, so it adds
            # no information, exactly as the projected (singular) noise would. (The projection is taken as fixed
            # at the predicted attitude: its own dependence on q is left out of the Jacobian.)
            proj = np.eye(3) - np.outer(up_b, up_b)
            z[3:6] = proj @ z[3:6]
            hx[3:6] = proj @ hx[3:6]
            hjac[3:6, :4] = proj @ np.ascontiguousarray(hjac[3:6, :4])
        k = 6
    if at_rest:
        sig_r2 = params[11] ** 2
        for i in range(3):
            z[k + i] = gyr_rad_s[i]
            hx[k + i] = x[4 + i]
            hjac[k + i, 4 + i] = 1.0
            rmat[k + i, k + i] = sig_r2
    return z, hx, hjac, rmat


@njit
def ekf_step(
    x: FloatArray,
    p: FloatArray,
    rest_s: float,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    dt_s: float,
    ref: FloatArray,
    params: FloatArray,
) -> tuple[FloatArray, FloatArray, float]:
    """One predict + update, in the same operation order as filterpy's ExtendedKalmanFilter (Joseph form)."""
    rest_s = rest_timer(rest_s, x, gyr_rad_s, acc_m_s2, dt_s, ref, params)
    at_rest = rest_s >= params[10] and params[8] > 0.0
    x_pred, f_jac = transition(x, gyr_rad_s, dt_s)
    p_pred = f_jac @ p @ f_jac.T + process_noise(x[:4], dt_s, params)
    if not at_rest:
        p_pred = hold_bias(p_pred)
    z, hx, h_jac, rmat = measurement(x_pred, gyr_rad_s, acc_m_s2, mag_uT, use_mag, at_rest, ref, params)
    pht = p_pred @ h_jac.T
    s_inv = np.linalg.inv(h_jac @ pht + rmat)
    k = pht @ s_inv
    x_new = x_pred + k @ (z - hx)
    i_kh = np.eye(N_STATE) - k @ h_jac
    p_new = i_kh @ p_pred @ i_kh.T + k @ rmat @ k.T
    x_new[:4] /= np.sqrt(np.sum(x_new[:4] ** 2))
    return x_new, p_new, rest_s


@njit
def ekf_run(
    x0: FloatArray,
    p0: FloatArray,
    rest0_s: float,
    gyr_rad_s: FloatArray,
    acc_m_s2: FloatArray,
    mag_uT: FloatArray,
    use_mag: bool,
    dt_s: float,
    ref: FloatArray,
    params: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """Batch filter: returns quaternions (N, 4), the final state, covariance and rest timer."""
    n = gyr_rad_s.shape[0]
    out = np.empty((n, 4))
    x = x0.copy()
    p = p0.copy()
    rest_s = rest0_s
    for i in range(n):
        x, p, rest_s = ekf_step(x, p, rest_s, gyr_rad_s[i], acc_m_s2[i], mag_uT[i], use_mag, dt_s, ref, params)
        out[i] = x[:4]
    return out, x, p, rest_s


# --- filterpy-backed filter ------------------------------------------------------------------------------------------


class _PicardEkf(ExtendedKalmanFilter):  # type: ignore[misc]
    """filterpy EKF whose state prediction is the Picard-3 step (filterpy's documented `predict_x` override)."""

    def __init__(self) -> None:
        super().__init__(dim_x=N_STATE, dim_z=6)
        self.x = np.zeros(N_STATE)
        self.gyr_rad_s = np.zeros(3)
        self.dt_s = 0.0

    def predict_x(self, u: object = 0) -> None:
        self.x, _ = transition(self.x, self.gyr_rad_s, self.dt_s)


class QuaternionEkf(AttitudeFilter):
    """Quaternion EKF of seed 001 (see module docstring); `update()` runs filterpy, `run()` the numba twin."""

    name = "ekf"

    def __init__(self, settings: EkfSettings | None = None, *, use_mag: bool = True) -> None:
        super().__init__(use_mag=use_mag)
        self.settings = settings or EkfSettings()
        self._params = self.settings.as_array()
        self._kf = _PicardEkf()
        self._ref = np.array([9.81, 50.0, 0.0, 0.0, 1.0, 0.0])
        self._rest_s = 0.0
        self._kf.x[0] = 1.0
        self._reset_covariance()

    def _reset_covariance(self) -> None:
        p = np.zeros((N_STATE, N_STATE))
        p[:4, :4] = 1e-4 * np.eye(4)
        if not self.settings.paper:
            p[4:, 4:] = self.settings.bias_init_rad_s**2 * np.eye(3)
        self._kf.P = p

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        """Attitude from the rest means; learn g₀, m₀, the dip angle and the earth-frame field direction m̃."""
        q0 = quat.from_acc(acc_m_s2) if mag_uT is None or not self.use_mag else quat.from_acc_mag(acc_m_s2, mag_uT)
        self._kf.x = np.concatenate([q0, np.zeros(3)])
        self._reset_covariance()
        self._rest_s = 0.0
        g0 = float(np.linalg.norm(acc_m_s2))
        if mag_uT is not None and self.use_mag:
            m0 = float(np.linalg.norm(mag_uT))
            m_hat = mag_uT / m0
            dip0 = float(np.arcsin(np.clip(np.dot(acc_m_s2 / g0, m_hat), -1.0, 1.0)))
            m_ref = quat.rotate(q0, m_hat)  # earth-frame field direction: East component 0, dip learnt
            self._ref = np.array([g0, m0, dip0, *m_ref])
        else:
            self._ref = np.array([g0, 50.0, 0.0, 0.0, 1.0, 0.0])

    @property
    def quaternion(self) -> FloatArray:
        q: FloatArray = self._kf.x[:4].copy()
        return q

    @property
    def gyro_bias_rad_s(self) -> FloatArray:
        """Current gyro-bias estimate (zero when `paper=True`)."""
        b: FloatArray = self._kf.x[4:].copy()
        return b

    def update(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Predict with the Picard-3 step, then correct with the accelerometer (and magnetometer) directions."""
        kf = self._kf
        use_mag = self.use_mag and mag_uT is not None
        gyr = np.asarray(gyr_rad_s, dtype=np.float64)
        acc = np.asarray(acc_m_s2, dtype=np.float64)
        mag = np.asarray(mag_uT, dtype=np.float64) if use_mag else np.zeros(3)
        self._rest_s = rest_timer(self._rest_s, kf.x, gyr, acc, dt_s, self._ref, self._params)
        at_rest = self._rest_s >= self._params[10] and self._params[8] > 0.0
        kf.gyr_rad_s = gyr
        kf.dt_s = dt_s
        kf.F = transition(kf.x, gyr, dt_s)[1]
        kf.Q = process_noise(kf.x[:4], dt_s, self._params)
        kf.predict()
        if not at_rest:
            kf.P = hold_bias(kf.P)
        z, hx, h_jac, rmat = measurement(kf.x, gyr, acc, mag, use_mag, at_rest, self._ref, self._params)
        kf.update(z, HJacobian=lambda _x: h_jac, Hx=lambda _x: hx, R=rmat)
        kf.x[:4] /= np.linalg.norm(kf.x[:4])
        return self.quaternion

    def run(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Same filter over whole (N, 3) arrays with the numba kernel; leaves the state at the last sample."""
        use_mag = self.use_mag and mag_uT is not None
        mag = np.ascontiguousarray(mag_uT, dtype=np.float64) if use_mag else np.zeros_like(acc_m_s2)
        out, x, p, self._rest_s = ekf_run(
            self._kf.x,
            self._kf.P,
            self._rest_s,
            np.ascontiguousarray(gyr_rad_s, dtype=np.float64),
            np.ascontiguousarray(acc_m_s2, dtype=np.float64),
            mag,
            use_mag,
            float(dt_s),
            self._ref,
            self._params,
        )
        self._kf.x = x
        self._kf.P = p
        return out
