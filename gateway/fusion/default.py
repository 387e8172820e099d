"""The project's default attitude filter: VQF-class fusion with gyro-bias estimation, rest detection and rejection of
external acceleration and magnetic disturbances, tuned once with physical time constants (no per-device tuning).

Method after D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation with bias estimation and magnetic
disturbance rejection", Information Fusion 91:187-204, 2023 (doi:10.1016/j.inffus.2022.10.014); our own structure and
defaults. The numeric core is in `_default_kernels` (numba); this module holds settings, state and the class.
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass, fields

import numpy as np

from gateway.fusion import _default_kernels as K
from gateway.fusion.base import AttitudeFilter, FloatArray

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class DefaultSettings:
    """Defaults that need no per-device tuning; every time is in seconds, so any rate from 50 Hz to 1 kHz works.

    Low-pass time constants define the cutoff fc = 1 / (2π tau) of a second-order Butterworth filter.
    """

    tau_acc_s: float = 2.5  # specific force low-pass in the almost-inertial frame: rejects external acceleration
    tau_mag_s: float = 20.0  # heading correction time constant (steady state; faster after a rejection)
    # low-pass of gyro/acc for rest detection: VQF's 0.5 s. VQF's time constants mean fc = √2/(2π tau) (its tau_acc
    # 3 s is 3/√2 = 2.12 s here); taken over unconverted, 0.5 s smoothed the rest gyro more than VQF does and let
    # the start of motion leak into the rest-bias estimate for longer (docs/fusion.md, "rest detection")
    rest_tau_s: float = 0.5 / math.sqrt(2.0)
    rest_gyr_th_deg_s: float = 2.0  # a sample deviating more from the low-pass is motion
    rest_acc_th_m_s2: float = 0.5
    rest_min_s: float = 1.5  # rest is declared after this long below both thresholds
    bias_clip_deg_s: float = 5.0  # largest bias the filter will believe (MPU-6050 class: ~1 °/s std after start-up)
    bias_sigma_init_deg_s: float = 0.5  # prior bias uncertainty; also the cap of the random walk
    bias_walk_deg_s: float = 0.1  # bias random walk: the standard deviation it gains per `bias_forget_s`
    bias_forget_s: float = 100.0
    bias_sigma_motion_deg_s: float = 0.1  # steady-state bias uncertainty reached in motion
    bias_vertical_factor: float = 1e-4  # motion says little about the bias about the vertical: weight it down
    bias_sigma_rest_deg_s: float = 0.03  # steady-state bias uncertainty reached at rest
    scale_sigma_init_pct: float = 1.5  # prior uncertainty of each gyro axis' scale factor (MEMS: ~0.5-3 %)
    scale_walk_pct: float = 0.1  # scale random walk: the standard deviation it gains per `bias_forget_s`
    scale_clip_pct: float = 5.0  # largest scale correction the filter will believe
    mag_current_tau_s: float = 0.05  # low-pass of the measured field norm and dip
    mag_ref_tau_s: float = 20.0  # slow adaptation of the accepted field norm and dip
    mag_norm_th: float = 0.1  # relative norm deviation that marks a disturbance
    mag_dip_th_deg: float = 10.0  # dip deviation that marks a disturbance
    mag_new_s: float = 20.0  # a new steady field is accepted after this long while rotating
    mag_new_first_s: float = 5.0  # same, before any field was accepted
    mag_new_min_gyr_deg_s: float = 20.0  # "rotating": a constant field seen under rotation is a real field
    mag_min_undisturbed_s: float = 0.5  # the field must look undisturbed this long before it is used again
    mag_max_reject_s: float = 60.0  # after this much rejection, use the field at a reduced gain
    mag_reject_factor: float = 2.0  # gain divisor after long rejection; also how fast the rejection budget refills
    # Optional bearing test (off by default: on the BROAD trials it costs more than it gains, see docs/fusion.md).
    # A homogeneous field keeps its bearing in the gyro-propagated frame; a magnet on the body turns it with the body,
    # one in the room changes it along the path (a small magnet a few cm away swings the bearing by ~10° and the norm
    # and dip by only a few %). The bearing is averaged over `mag_bearing_tau_s`; further than the threshold from that
    # average marks a disturbance. The threshold grows by |rate| × `mag_bearing_lag_s`: magnetometer and gyro are
    # not sampled at the same instant, which shifts the bearing in fast rotation (0.02 s: 9° at 450 °/s).
    mag_bearing_tau_s: float = 2.0
    mag_bearing_th_deg: float = 0.0  # e.g. 4; 0 disables the bearing test
    mag_bearing_lag_s: float = 0.02
    mag_heading_kf: bool = True  # gain grows with the time the field was rejected: the drift gathered meanwhile
    # is taken out quickly once the field is clean (same steady-state gain as a fixed `tau_mag_s`)
    acc_spike_m_s2: float = 60.0  # |specific force - g| above ~6 g is a shock (tap, knock), skipped; 0 disables
    motion_bias: bool = True
    rest_bias: bool = True
    mag_rejection: bool = True
    scale_estimation: bool = True  # estimate per-axis gyro scale errors from the inclination corrections in motion

    def to_array(self) -> FloatArray:
        """The settings in SI units (rad, rad/s) as the kernels' flat parameter vector."""
        p = np.zeros(K.N_PARAMS)
        p[K.P_TAU_ACC] = self.tau_acc_s
        p[K.P_TAU_MAG] = self.tau_mag_s
        p[K.P_REST_TAU] = self.rest_tau_s
        p[K.P_REST_GYR_TH] = self.rest_gyr_th_deg_s * _DEG
        p[K.P_REST_ACC_TH] = self.rest_acc_th_m_s2
        p[K.P_REST_MIN] = self.rest_min_s
        p[K.P_BIAS_CLIP] = self.bias_clip_deg_s * _DEG
        p[K.P_BIAS_SIGMA_INIT] = self.bias_sigma_init_deg_s * _DEG
        p[K.P_BIAS_FORGET] = self.bias_forget_s
        p[K.P_BIAS_WALK] = self.bias_walk_deg_s * _DEG
        p[K.P_BIAS_SIGMA_MOTION] = self.bias_sigma_motion_deg_s * _DEG
        p[K.P_BIAS_VERT_FACTOR] = self.bias_vertical_factor
        p[K.P_BIAS_SIGMA_REST] = self.bias_sigma_rest_deg_s * _DEG
        p[K.P_MAG_CUR_TAU] = self.mag_current_tau_s
        p[K.P_MAG_REF_TAU] = self.mag_ref_tau_s
        p[K.P_MAG_NORM_TH] = self.mag_norm_th
        p[K.P_MAG_DIP_TH] = self.mag_dip_th_deg * _DEG
        p[K.P_MAG_NEW_T] = self.mag_new_s
        p[K.P_MAG_NEW_FIRST_T] = self.mag_new_first_s
        p[K.P_MAG_NEW_MIN_GYR] = self.mag_new_min_gyr_deg_s * _DEG
        p[K.P_MAG_MIN_UNDIST_T] = self.mag_min_undisturbed_s
        p[K.P_MAG_MAX_REJECT_T] = self.mag_max_reject_s
        p[K.P_MAG_REJECT_FACTOR] = self.mag_reject_factor
        p[K.P_MOTION_BIAS_ON] = float(self.motion_bias)
        p[K.P_REST_BIAS_ON] = float(self.rest_bias)
        p[K.P_MAG_REJECT_ON] = float(self.mag_rejection)
        p[K.P_SCALE_ON] = float(self.scale_estimation)
        p[K.P_SCALE_SIGMA_INIT] = self.scale_sigma_init_pct / 100.0
        p[K.P_SCALE_WALK] = self.scale_walk_pct / 100.0
        p[K.P_SCALE_CLIP] = self.scale_clip_pct / 100.0
        p[K.P_MAG_BEAR_TAU] = self.mag_bearing_tau_s
        p[K.P_MAG_BEAR_TH] = self.mag_bearing_th_deg * _DEG
        p[K.P_ACC_SPIKE_TH] = self.acc_spike_m_s2
        p[K.P_MAG_BEAR_LAG] = self.mag_bearing_lag_s
        p[K.P_MAG_HEADING_KF_ON] = float(self.mag_heading_kf)
        return p

    def __post_init__(self) -> None:
        values = astuple(self)
        names = [f.name for f in fields(self)]
        for name, value in zip(names, values, strict=True):
            if not isinstance(value, bool) and not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
        if self.bias_forget_s <= 0 or self.bias_sigma_init_deg_s <= 0:
            raise ValueError("bias_forget_s and bias_sigma_init_deg_s must be positive")


def attitude_from_rest(acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> FloatArray:
    """Body->ENU quaternion from a mean specific force at rest (inclination) and, if given, field (heading).

    The accelerometer direction is turned onto +z by the shortest rotation; the field's horizontal part then sets
    the heading so that it points North (+y). Without a field the heading is zero.
    """
    a = np.asarray(acc_m_s2, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if n == 0.0:
        raise ValueError("accelerometer reading is zero; cannot find the vertical")
    ax, ay, az = a / n
    # rotation by acos(az) about the horizontal axis (ay, -ax, 0), in the form that keeps precision: the
    # half-vector form near level, sin/cos of the half angle (cos from sin θ = h) near upside down
    if az >= 0.0:
        q = np.array([1.0 + az, ay, -ax, 0.0])
    else:
        h = math.hypot(ax, ay)
        s = math.sqrt(0.5 * (1.0 - az))
        ux, uy = (ay / h, -ax / h) if h > 0.0 else (1.0, 0.0)
        q = np.array([0.5 * h / s, s * ux, s * uy, 0.0])
    q /= np.linalg.norm(q)
    if mag_uT is None:
        return q
    w, x, y, z = q
    mx, my, mz = np.asarray(mag_uT, dtype=np.float64)
    hx = (1.0 - 2.0 * (y * y + z * z)) * mx + 2.0 * (x * y - w * z) * my + 2.0 * (x * z + w * y) * mz
    hy = 2.0 * (x * y + w * z) * mx + (1.0 - 2.0 * (x * x + z * z)) * my + 2.0 * (y * z - w * x) * mz
    half = 0.5 * math.atan2(hx, hy)
    c, s = math.cos(half), math.sin(half)
    return np.array([c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w])


def initial_state(params: FloatArray, acc_m_s2: FloatArray | None, mag_uT: FloatArray | None) -> FloatArray:
    """Kernel state vector for a device starting at rest with mean readings `acc_m_s2` (and `mag_uT` in 9D).

    Without readings the attitude starts at identity and converges (inclination within ~tau_acc, heading by the
    initial averaging gain). With a field, its norm and dip become the accepted reference (the field that sets the
    initial heading is trusted as undisturbed).
    """
    s = K.new_state(params)
    if acc_m_s2 is None:
        return s
    q = attitude_from_rest(acc_m_s2, mag_uT)
    s[K.S_QG : K.S_QG + 4] = q
    if mag_uT is not None:
        m = np.asarray(mag_uT, dtype=np.float64)
        s[K.S_K_MAG_INIT] = 0.0  # heading is already known
        norm = float(np.linalg.norm(m))
        w, x, y, z = q
        hz = 2.0 * (x * z - w * y) * m[0] + 2.0 * (y * z + w * x) * m[1] + (1.0 - 2.0 * (x * x + y * y)) * m[2]
        dip = -math.asin(max(-1.0, min(1.0, hz / norm))) if norm > 0 else 0.0
        s[K.S_MAG_CAND_NORM] = norm
        s[K.S_MAG_CAND_DIP] = dip
        # the rest field already sets the heading, so it is also the accepted reference for disturbance detection
        s[K.S_MAG_REF_NORM] = norm
        s[K.S_MAG_REF_DIP] = dip
        s[K.S_MAG_DIST] = 0.0
        s[K.S_MAG_REJECT_T] = 0.0
    return s


def _as_rows(
    ndim: int, gyr: FloatArray, acc: FloatArray, mag: FloatArray, use_mag: bool, message: str
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The inputs as C-contiguous float64 arrays of `ndim` dimensions (mag is gyr in 6D); the kernel checks shapes."""
    g = np.ascontiguousarray(gyr, dtype=np.float64)
    a = np.ascontiguousarray(acc, dtype=np.float64)
    m = np.ascontiguousarray(mag, dtype=np.float64) if use_mag else g
    if g.ndim != ndim or a.ndim != ndim or m.ndim != ndim:
        raise ValueError(message)
    return g, a, m


class DefaultFilter(AttitudeFilter):
    """The project's default filter (VQF-class): see the module docstring and `DefaultSettings`.

    Everything the kernel reads or writes (state, settings, coefficients, scratch) is one float64 context vector, so a
    packet costs one numba call over six arguments; `state` is the view of its state part, the same layout
    `gateway.fusion.batch` stacks for N devices.
    """

    name = "default"

    def __init__(self, settings: DefaultSettings | None = None, *, use_mag: bool = True) -> None:
        super().__init__(use_mag=use_mag)
        self.settings = settings or DefaultSettings()
        self._params = self.settings.to_array()
        self._ctx = K.new_context(self._params, K.new_state(self._params))
        self._dt_s = math.nan  # the period in the context (validated when it changes)
        self._step = K.context_kernel()
        self._step_sample = K.context_sample_kernel()
        self._fast_block = self._fast_sample = True  # inputs so far were C-contiguous float64 (no conversion)

    @property
    def params(self) -> FloatArray:
        """The kernels' parameter vector (read-only copy)."""
        return self._params.copy()

    @property
    def state(self) -> FloatArray:
        """The kernel state vector (N_STATE,): a view, writes go to the filter."""
        return self._ctx[K.X_STATE : K.X_STATE + K.N_STATE]

    @state.setter
    def state(self, value: FloatArray) -> None:
        self._ctx[K.X_STATE : K.X_STATE + K.N_STATE] = value

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        """Start from a rest reading: attitude from acc (+ mag); that field becomes the accepted reference."""
        use_mag = self.use_mag and mag_uT is not None
        self.state = initial_state(self._params, acc_m_s2, mag_uT if use_mag else None)
        self._ctx[K.X_Q : K.X_Q + 4] = self._ctx[K.X_STATE + K.S_QG : K.X_STATE + K.S_QG + 4]

    def _set_period(self, dt_s: float) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        self._ctx[K.X_DT] = dt_s  # the kernel derives its coefficients when this differs from theirs
        self._dt_s = dt_s

    def update(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """One sample; returns the body->ENU quaternion (4,). A zero acc or mag sample means "no reading"."""
        if dt_s != self._dt_s:
            self._set_period(dt_s)
        use_mag = self.use_mag and mag_uT is not None
        mag = mag_uT if use_mag and mag_uT is not None else gyr_rad_s
        q = np.empty(4)
        if self._fast_sample:
            try:
                self._step_sample(self._ctx, gyr_rad_s, acc_m_s2, mag, use_mag, q)
                return q
            except TypeError:
                self._fast_sample = False  # see `update_block`
        gyr, acc, mag = _as_rows(1, gyr_rad_s, acc_m_s2, mag, use_mag, "gyr, acc and mag must be 3-vectors")
        self._step_sample(self._ctx, gyr, acc, mag, use_mag, q)
        return q

    def update_block(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """n samples of one packet, inputs (n, 3) sampled every `dt_s`; returns quaternions (n, 4).

        Rows with a non-finite gyro are skipped (the attitude is held); zero or non-finite acc / mag rows are treated
        as missing readings. C-contiguous float64 arrays go straight to the kernel, whose dispatcher checks the types;
        once a call needs converting (lists, float32, strided views), every later call converts first.
        """
        if dt_s != self._dt_s:
            self._set_period(dt_s)
        use_mag = self.use_mag and mag_uT is not None
        mag = mag_uT if use_mag and mag_uT is not None else gyr_rad_s
        if self._fast_block:
            try:
                out = np.empty((len(gyr_rad_s), 4))
                self._step(self._ctx, gyr_rad_s, acc_m_s2, mag, use_mag, out)
                return out
            except TypeError:
                # this caller's arrays need converting: convert from now on instead of paying numba's failed type
                # match (~80 µs) on every call
                self._fast_block = False
        gyr, acc, mag = _as_rows(2, gyr_rad_s, acc_m_s2, mag, use_mag, "gyr, acc and mag must be (n, 3) arrays")
        out = np.empty((gyr.shape[0], 4))
        self._step(self._ctx, gyr, acc, mag, use_mag, out)
        return out

    def run(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Whole arrays (N, 3) in one kernel call; returns (N, 4)."""
        return self.update_block(gyr_rad_s, acc_m_s2, mag_uT, dt_s)

    @property
    def quaternion(self) -> FloatArray:
        """Current body->ENU estimate (4,), scalar first."""
        return self._ctx[K.X_Q : K.X_Q + 4].copy()

    @property
    def bias_rad_s(self) -> FloatArray:
        """Current gyroscope bias estimate (3,) in rad/s."""
        return np.array(self.state[K.S_BIAS : K.S_BIAS + 3])

    @property
    def rest_detected(self) -> bool:
        """True while the device is judged at rest."""
        return bool(self.state[K.S_REST] != 0.0)

    @property
    def mag_disturbed(self) -> bool:
        """True while the magnetic field is judged disturbed (heading correction paused or slowed)."""
        return bool(self.state[K.S_MAG_DIST] != 0.0)
