"""Where a hook's IMU sits off the rope axis and how it is tilted on the hook, from a recording of the hook hanging
still while it is twisted by hand (`python -m gateway.calibrate --hook-mount`; the hook settings `imu_offset_m` and
`imu_tilt_deg`).

Why: the hook filter takes the accelerometer's x/y as the force on the hook, minus the lever-arm terms
`ω' × r + ω × (ω × r)` of the IMU at `r` from the rope axis; an `r` it does not know reads the swing 2-4× worse
(docs/fusion.md, "The IMU's mount"), and the inside of a hook block is hard to measure with a ruler.

Model: on a hook hanging on its rope, the specific force is along the rope (body z) but for the forces that are not
tension (wind) and the lever-arm terms, so per sample, body x/y (m/s²):

    f_xy = b + R_z(-α) w + J(ω, ω') r_xy,   J = [[-(ω_y² + ω_z²), ω_x ω_y - ω'_z], [ω_x ω_y + ω'_z, -(ω_x² + ω_z²)]]

with `b` the accelerometer's x/y bias (body), `w` a steady horizontal force (a steady wind, earth frame) seen
through the twist `α` (from the magnetometer's horizontal field when there is one, else the z rate integrated with
its mean taken as bias: a twist that dies away leaves that mean off by its net turn), and `r_xy` the offset. Linear in
(b, w, r_xy): one least-squares fit. `ω'` is the gyro's central difference, smoothed over 50 ms. Samples where
the gyroscope or accelerometer clipped (a hook twisted fast; `clipped`) are left out of every fit (with a
magnetometer; without one the integrated twist is wrong after a clip and the fit is refused). The z offset (along
the rope) needs a swing, not a twist, and is not fitted. The uncertainty is taken from the spread of the fits of
`SEGMENTS` consecutive parts of the recording (the residual's gusts are correlated over seconds, so the formal
least-squares error would be too small), and the fit is refused when the twist does not excite it.

The same twist gives the IMU's tilt on the hook: a twist about the rope is read on the gyroscope's x/y in proportion
`s` to its z (`gyr_xy = s ω_z + bias`, one more least-squares fit), which an IMU tilted by the rotation
`(s_y, -s_x) atan|s| / |s|` about its x and y (or a board whose axes are not square) does; the hook filter takes
such x/y rate for a swing (a 2° tilt read the suite's Θ 1.5-2.2× worse, docs/fusion.md "The IMU's mount"). `tilt_xy_rad`
is the rotation that takes the IMU's axes onto the hook's (`imu_tilt_deg`).

And the magnetometer's offset in the hook's horizontal plane (`fit_hard_iron`): on a hook hanging plumb and turning
about the rope, the magnetometer's x/y (in the hook's axes) trace a circle about that offset (its hard iron, plus
the vertical field its soft iron leans onto x/y); the soft iron's in-plane part makes it an ellipse, fitted along the
twist the gyroscope integrates; `IronFit.calibration` is the device calibration (`gateway.calibrate.DeviceCalibration`)
that takes it out before fusion. An MPU-6050/HMC5883L-class board read the suite's torsion 2.2° RMS on fresh seeds;
with the twist's calibration, 0.6° (docs/fusion.md).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gateway.fusion.base import FloatArray
from gateway.fusion.quaternion import from_rotvec, to_matrix

MIN_RECORDING_S = 20.0  # shorter: too few twists to tell a centimetre
SEGMENTS = 4
SMOOTH_S = 0.05
MIN_TWIST_ACCEL_RAD_S2 = 0.2  # rms of ω'_z below this: not twisted enough for a centimetre
MAX_STD_M = 0.01  # a fit less certain than this is refused (the setting's prior is 1 cm)
# The accelerometer's x/y offset (`acc_bias_xy_m_s2`) is not given when its fit is less certain than this (the
# segments' spread, as the offset's; the filter's prior about a told offset is 0.02 m/s²). Twist sessions of the
# suite's hooks: at most 0.005 on tuning seeds 1-30 (calibrated and legacy boards), windy and short 1-12, and fresh
# 2126-2165; fresh seed 2184, whose stiff swivel twisted past its gyroscope's range and whose fit was off by 0.07
# m/s², 0.023.
MAX_BIAS_STD_M_S2 = 0.01
CLIP_RUN = 3  # an axis held at its largest |value| for this many samples in a row has clipped (full scale) ...
GYRO_MIN_FULL_SCALE_RAD_S = 4.3  # ... when that value is one a board's range can be (MPU-6050: ±250 °/s at least)
ACC_MIN_FULL_SCALE_M_S2 = 19.0  # ±2 g at least


MIN_IRON_SPAN_RAD = math.radians(90.0)  # the field must turn this far for the circle's centre ...
MIN_SHAPE_SPAN_RAD = math.radians(180.0)  # ... and this far for the ellipse the soft iron makes of it
MAX_SHAPE_STRETCH = 1.25  # an ellipse longer than this over its width is not a board's soft iron: the circle stands
MAX_IRON_SCATTER = 0.1  # samples further from the circle than this share of its radius (rms) do not trace one
GYRO_BIAS_SEARCH_RAD_S = 0.1  # `_gyro_ellipse`: the gyroscope's z bias is searched within ± this (5.7 °/s) ...
GYRO_SCALE_SEARCH = 0.04  # ... and its scale within 1 ± this
# A centre less certain than this (the segments' spread) is not given: the parts disagree by several µT, steel moved
# near the hook. The twist sessions of the suite's legacy boards: up to 0.66 (tuning 1-30), 0.88 (2106-2125), 0.33
# µT (2196-2215); against 5-14 µT of hard iron left in when it is not given.
MAX_IRON_STD_UT = 2.0


@dataclass(frozen=True)
class IronFit:
    """The magnetometer's x/y offset in the hook's axes (µT), the circle's radius (the horizontal field, µT), the rms
    of the samples' distance from it (µT), how far the field turned (rad), the offset's 1σ (µT, the segments'
    spread of the circle's centre, as the mount's) and the in-plane soft-iron correction `shape_xy` (2 × 2,
    symmetric: it turns the ellipse the samples trace back into a circle; the identity when no ellipse was fitted:
    no usable gyroscope and a turn under `MIN_SHAPE_SPAN_RAD`, or one stretched past `MAX_SHAPE_STRETCH`)."""

    offset_xy_uT: FloatArray
    radius_uT: float
    residual_uT: float
    span_rad: float
    std_uT: float
    shape_xy: FloatArray = dataclasses.field(default_factory=lambda: np.eye(2))

    def mag_correction(self, tilt_xy_rad: ArrayLike) -> tuple[FloatArray, FloatArray] | None:
        """The magnetometer's offset (3,) and soft-iron matrix (3, 3) in the IMU's own axes (a calibration is applied
        before the tilt turns the samples onto the hook's) that take this fit out before fusion, for
        `gateway.calibrate.hook_compass_calibration`; None when the fit is less certain than `MAX_IRON_STD_UT`."""
        if self.std_uT > MAX_IRON_STD_UT:
            return None
        turn = tilt_matrix(tilt_xy_rad)  # hook = turn @ IMU
        offset = turn.T @ np.array([self.offset_xy_uT[0], self.offset_xy_uT[1], 0.0])
        shape = np.eye(3)
        shape[:2, :2] = self.shape_xy
        return offset, turn.T @ shape @ turn  # in the hook's axes: x/y reshaped, z as it is


@dataclass(frozen=True)
class MountFit:
    """The IMU's x/y offset from the rope axis (m, body frame), its 1σ (m, from the segments' spread), its tilt on the
    hook (`fit_tilt`, rad), the accelerometer x/y bias and steady force fitted beside the offset (m/s²), the twist's
    excitation (rms of ω'_z, rad/s²), the residual rms (m/s²), the bias's 1σ (m/s², from the segments' spread) and
    how many samples were left out as clipped (`clipped`, with the smoothing's reach)."""

    offset_xy_m: FloatArray
    std_m: float
    tilt_xy_rad: FloatArray
    bias_xy_m_s2: FloatArray
    steady_force_m_s2: FloatArray
    twist_accel_rms_rad_s2: float
    residual_m_s2: float
    bias_std_m_s2: float
    clipped_samples: int = 0

    def setting(self, z_m: float = 0.0) -> list[float]:
        """`HookThresholds.imu_offset_m` from this fit: [x, y, z] m, rounded to the millimetre (z as measured)."""
        return [round(float(self.offset_xy_m[0]), 3), round(float(self.offset_xy_m[1]), 3), round(z_m, 3)]

    def tilt_setting(self) -> list[float]:
        """`HookThresholds.imu_tilt_deg` from this fit: [about x, about y] degrees, to 0.01°."""
        return [round(math.degrees(float(v)), 2) for v in self.tilt_xy_rad]

    def bias_setting(self) -> list[float] | None:
        """`HookThresholds.acc_bias_xy_m_s2` from this fit (made in the hook's axes: `hook_axes_fit`), m/s² to 1 mm/s²;
        None when it is less certain than `MAX_BIAS_STD_M_S2` (told wrong it leans the rope wrong: leave it out)."""
        if self.bias_std_m_s2 > MAX_BIAS_STD_M_S2:
            return None
        return [round(float(v), 3) for v in self.bias_xy_m_s2]


def clipped(v: FloatArray, min_full_scale: float, pad: int = 0) -> NDArray[np.bool_]:
    """The samples (N,) where any axis of `v` (N, 3) is at the sensor's full scale, and `pad` either side: an axis
    reads its largest |value|, at least `min_full_scale`, for `CLIP_RUN` samples in a row (a clipped reading is held
    at full scale; the range is the board's, not told). A hook twisted hard clips a ±500 °/s gyroscope (suite seed
    2184: 8.73 rad/s read, 10.4 true), and the fit's model is then wrong there."""
    mask = np.zeros(v.shape[0], dtype=bool)
    for axis in np.abs(v).T:
        top = axis.max()
        if top < min_full_scale:
            continue
        at = axis >= top
        runs = np.convolve(at.astype(np.int64), np.ones(CLIP_RUN, dtype=np.int64), mode="valid")
        if runs.size and runs.max() >= CLIP_RUN:
            mask |= at
    if pad > 0 and mask.any():
        mask = np.convolve(mask.astype(np.int64), np.ones(2 * pad + 1, dtype=np.int64), mode="same") > 0
    return mask


def _clipped_samples(gyr: FloatArray, acc: FloatArray, pad: int) -> NDArray[np.bool_]:
    return clipped(gyr, GYRO_MIN_FULL_SCALE_RAD_S, pad) | clipped(acc, ACC_MIN_FULL_SCALE_M_S2, pad)


def fit_tilt(gyr: FloatArray, keep: NDArray[np.bool_] | None = None) -> FloatArray:
    """The rotation (about x, y; rad, small) taking the IMU's axes onto the hook's, from the gyroscope's x/y read in
    proportion to its z on a twisting hook (see the module docstring), over the samples `keep` (default all)."""
    g = gyr if keep is None else gyr[keep]
    a = np.column_stack([g[:, 2], np.ones(g.shape[0])])
    s_x, s_y = (float(v) for v in np.linalg.lstsq(a, g[:, :2], rcond=None)[0][0])
    slope = math.hypot(s_x, s_y)  # the hook's z in the IMU's axes is (s_x, s_y, 1): tilted by atan(|s|)
    scale = 1.0 if slope == 0.0 else math.atan(slope) / slope
    return np.array([s_y * scale, -s_x * scale])


def tilt_matrix(tilt_xy_rad: ArrayLike) -> FloatArray:
    """The rotation matrix of the rotation vector (tx, ty, 0): body (hook) = M @ IMU."""
    tx, ty = (float(v) for v in np.asarray(tilt_xy_rad, dtype=np.float64))
    return to_matrix(from_rotvec([tx, ty, 0.0]))


def _twist(gyr: FloatArray, mag: FloatArray | None, dt_s: float) -> FloatArray:
    """The hook's twist about the rope (rad, up to a constant): the body's horizontal field turns by -α."""
    if mag is not None:
        return -np.unwrap(np.arctan2(mag[:, 1], mag[:, 0]))
    wz = gyr[:, 2]
    return np.cumsum(wz - wz.mean()) * dt_s


def _design(gyr: FloatArray, mag: FloatArray | None, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Per sample the 2 × 6 design rows (bias x/y, steady force x/y, r_x, r_y) and ω'_z."""
    n_smooth = max(1, int(round(SMOOTH_S / dt_s)))
    dw = np.gradient(gyr, dt_s, axis=0)
    if n_smooth > 1:
        kernel = np.ones(n_smooth) / n_smooth
        dw = np.stack([np.convolve(dw[:, i], kernel, mode="same") for i in range(3)], axis=1)
    wx, wy, wz = gyr.T
    alpha = _twist(gyr, mag, dt_s)
    c, s = np.cos(alpha), np.sin(alpha)
    n = gyr.shape[0]
    a = np.zeros((n, 2, 6))
    a[:, 0, 0] = a[:, 1, 1] = 1.0
    a[:, 0, 2], a[:, 0, 3], a[:, 1, 2], a[:, 1, 3] = c, s, -s, c  # R_z(-α) w
    a[:, 0, 4], a[:, 0, 5] = -(wy * wy + wz * wz), wx * wy - dw[:, 2]
    a[:, 1, 4], a[:, 1, 5] = wx * wy + dw[:, 2], -(wx * wx + wz * wz)
    return a, dw[:, 2]


def _solve(a: FloatArray, f_xy: FloatArray) -> tuple[FloatArray, float]:
    sol: FloatArray = np.linalg.lstsq(a.reshape(-1, 6), f_xy.reshape(-1), rcond=None)[0].astype(np.float64)
    res = f_xy.reshape(-1) - a.reshape(-1, 6) @ sol
    return sol, float(np.sqrt(np.mean(res * res)))


def fit_hook_mount(gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, dt_s: float, mag_uT: ArrayLike | None = None, *,
                   clip: NDArray[np.bool_] | None = None) -> MountFit:  # fmt: skip
    """The IMU's offset from the rope axis from a hook hanging still and twisted (see the module docstring).

    Raises ValueError with what to do when the recording cannot give it within `MAX_STD_M`: too short, not
    twisted enough, or too disturbed (a swinging hook, gusts, a hand pushing it sideways). `clip`: the samples to
    leave out as clipped (default: `clipped` of these samples; given when they were turned off the sensor's axes)."""
    gyr, acc = np.asarray(gyr_rad_s, dtype=np.float64), np.asarray(acc_m_s2, dtype=np.float64)
    if gyr.ndim != 2 or gyr.shape[1] != 3 or acc.shape != gyr.shape:
        raise ValueError(f"need gyr and acc of the same shape (N, 3), got {gyr.shape} and {acc.shape}")
    if not (dt_s > 0.0 and math.isfinite(dt_s)):
        raise ValueError(f"dt_s must be positive, got {dt_s}")
    if gyr.shape[0] < int(round(MIN_RECORDING_S / dt_s)):
        raise ValueError(f"{gyr.shape[0] * dt_s:.0f} s of samples; twist the hanging hook for {MIN_RECORDING_S:g} s "
                         "or more")
    mag = None if mag_uT is None else np.asarray(mag_uT, dtype=np.float64)
    if mag is not None and mag.shape != gyr.shape:
        raise ValueError(f"need mag of the shape of gyr {gyr.shape}, got {mag.shape}")
    if not (np.isfinite(gyr).all() and np.isfinite(acc).all() and (mag is None or np.isfinite(mag).all())):
        raise ValueError("the samples are not all finite")
    edge = max(1, int(round(SMOOTH_S / dt_s)))  # the smoothed difference is cut at the ends
    if clip is None:  # ω' is smoothed over `edge` samples either side
        clip = _clipped_samples(gyr, acc, edge + 1)
    if clip.any() and mag is None:  # the twist is the z rate integrated: wrong after a clip, not only there
        raise ValueError(f"the gyroscope or accelerometer clipped (at full scale in {int(clip.sum())} samples) and "
                         "there is no magnetometer to follow the twist: twist the hook more gently")  # fmt: skip
    a, dwz = _design(gyr, mag, dt_s)
    keep = ~clip[edge:-edge]
    a, f_xy, dwz = a[edge:-edge][keep], acc[edge:-edge, :2][keep], dwz[edge:-edge][keep]
    if a.shape[0] < int(round(MIN_RECORDING_S / dt_s)) - 2 * edge:
        raise ValueError(f"{a.shape[0] * dt_s:.0f} s of samples below full scale (the gyroscope or accelerometer "
                         f"clipped in {int(clip.sum())}): twist the hook more gently, for {MIN_RECORDING_S:g} s or "
                         "more")
    excitation = float(np.sqrt(np.mean(dwz * dwz)))
    if excitation < MIN_TWIST_ACCEL_RAD_S2:
        raise ValueError(f"the hook hardly twists (rms twist acceleration {excitation:.2f} rad/s², need "
                         f"{MIN_TWIST_ACCEL_RAD_S2:g}): turn it by hand 45-90° and let it twist back, a few times")
    sol, resid = _solve(a, f_xy)
    parts = np.array_split(np.arange(a.shape[0]), SEGMENTS)
    seg = np.array([_solve(a[p], f_xy[p])[0] for p in parts])
    std, bias_std = (float(np.sqrt(np.mean(np.var(seg[:, c], axis=0, ddof=1)) / SEGMENTS)) for c in (slice(4, 6),
                                                                                                    slice(0, 2)))
    fit = MountFit(sol[4:6].copy(), std, fit_tilt(gyr, ~clip), sol[0:2].copy(), sol[2:4].copy(), excitation, resid,
                   bias_std, int(clip.sum()))
    if std > MAX_STD_M:
        raise ValueError(f"the offset is uncertain by {100 * std:.1f} cm (fit {np.round(fit.offset_xy_m, 3).tolist()} "
                         "m): hold the crane still, twist the hook more and longer, in calmer air")  # fmt: skip
    return fit


def hook_axes_fit(gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, dt_s: float, mag_uT: ArrayLike | None,
                  tilt_xy_rad: ArrayLike) -> MountFit:  # fmt: skip
    """The fit again on the samples turned by the IMU's tilt `tilt_xy_rad` as the hook filter sees them (a tilt moves
    part of the tension onto x/y): its `bias_setting` is `HookThresholds.acc_bias_xy_m_s2`, the accelerometer's x/y
    offset in the hook's axes. ValueError as `fit_hook_mount`."""
    m = tilt_matrix(tilt_xy_rad).T  # rows @ M.T: each sample turned onto the hook's axes
    gyr, acc = np.asarray(gyr_rad_s, dtype=np.float64), np.asarray(acc_m_s2, dtype=np.float64)
    pad = max(1, int(round(SMOOTH_S / dt_s))) + 1
    clip = _clipped_samples(gyr, acc, pad) if gyr.ndim == 2 and gyr.shape[1] == 3 and acc.shape == gyr.shape else None
    return fit_hook_mount(gyr @ m, acc @ m, dt_s, None if mag_uT is None else np.asarray(mag_uT, dtype=np.float64) @ m,
                          clip=clip)  # the sensor's full scale is on its own axes


def _circle(xy: FloatArray) -> tuple[FloatArray, float, FloatArray]:
    """Centre (2,), radius and each point's distance from the circle: the algebraic (Kåsa) fit, then Gauss-Newton
    steps on the geometric distance (the algebraic fit leans towards the arc's inside on a partial circle)."""
    a = np.column_stack([2.0 * xy[:, 0], 2.0 * xy[:, 1], np.ones(xy.shape[0])])
    sol = np.linalg.lstsq(a, np.sum(xy * xy, axis=1), rcond=None)[0]
    centre, radius = sol[:2].astype(np.float64), math.sqrt(max(float(sol[2] + sol[:2] @ sol[:2]), 1e-12))
    for _ in range(5):
        d = xy - centre
        rho = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        jac = np.column_stack([-d / rho[:, None], -np.ones(xy.shape[0])])
        step = np.linalg.lstsq(jac, radius - rho, rcond=None)[0]
        centre, radius = centre + step[:2], radius + float(step[2])
    d = xy - centre
    return centre, radius, np.hypot(d[:, 0], d[:, 1]) - radius


def _ellipse(xy: FloatArray, centre: FloatArray, iterations: int = 20) -> tuple[FloatArray, FloatArray]:
    """Centre (2,) and matrix `A` (2, 2) of `xy ≈ centre + A (cos θ, sin θ)`, each sample's θ read back through `A`
    in turn (from the circle about `centre` at first): the ellipse a field turning in the plane traces through a
    soft iron, found by linear least squares at each step (it converges for the few % of a board's soft iron)."""
    d = xy - centre
    theta = np.arctan2(d[:, 1], d[:, 0])
    a = np.eye(2)
    for _ in range(iterations):
        basis = np.column_stack([np.ones(xy.shape[0]), np.cos(theta), np.sin(theta)])
        sol = np.linalg.lstsq(basis, xy, rcond=None)[0]
        centre, a = sol[0], sol[1:].T
        u = np.linalg.solve(a, (xy - centre).T)
        theta = np.arctan2(u[1], u[0])
    return centre.astype(np.float64), a.astype(np.float64)


def _along(xy: FloatArray, alpha: FloatArray) -> tuple[FloatArray, float]:
    """`[centre; Aᵀ]` (3, 2) of `xy ≈ centre + A (cos α, sin α)` by linear least squares, and the rms residual (µT)."""
    basis = np.column_stack([np.ones(xy.shape[0]), np.cos(alpha), np.sin(alpha)])
    sol = np.linalg.lstsq(basis, xy, rcond=None)[0]
    res = xy - basis @ sol
    return sol.astype(np.float64), float(np.sqrt(np.mean(res * res)))


def _gyro_ellipse(xy: FloatArray, wz: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray, float]:
    """Centre, `A` and rms residual (µT) of `xy ≈ centre + A (cos α, sin α)` with the twist α the gyroscope's z rate
    integrated, less a bias and times a scale found by search (`GYRO_BIAS_SEARCH_RAD_S`, then `GYRO_SCALE_SEARCH`
    about the best): linear in the centre and `A` for each (`_along`). With the twist known the ellipse is found on
    any part of its arc (a circle's or ellipse's fit on 125-170° of an MPU-6050/HMC5883L-class board's: 0.2-3.4 µT
    off; this, 0.03-0.72 µT on the suite's twist sessions)."""

    def twist(bias: float, scale: float) -> FloatArray:
        out: FloatArray = np.cumsum(wz - bias) * (dt_s * scale)
        return out

    best = min((_along(xy, twist(float(b), 1.0))[1], float(b), 1.0)
               for b in np.linspace(-GYRO_BIAS_SEARCH_RAD_S, GYRO_BIAS_SEARCH_RAD_S, 201))  # fmt: skip
    step = 2.0 * GYRO_BIAS_SEARCH_RAD_S / 200.0
    best = min([best, *((_along(xy, twist(float(b), float(k)))[1], float(b), float(k))
                        for k in np.linspace(1.0 - GYRO_SCALE_SEARCH, 1.0 + GYRO_SCALE_SEARCH, 33)
                        for b in np.linspace(best[1] - step, best[1] + step, 11))])  # fmt: skip
    sol, res = _along(xy, twist(best[1], best[2]))
    return sol[0], sol[1:].T, res


def fit_hard_iron(mag_uT: ArrayLike, tilt_xy_rad: ArrayLike = (0.0, 0.0), gyr_rad_s: ArrayLike | None = None,
                  dt_s: float | None = None) -> IronFit:  # fmt: skip
    """The magnetometer's x/y offset in the hook's axes from the twist session (the module docstring): the samples
    turned by the IMU's tilt `tilt_xy_rad` (`MountFit.tilt_xy_rad`), a circle fitted to their x/y; when the field
    turned `MIN_SHAPE_SPAN_RAD` or more, an ellipse (`_ellipse`) for the centre and the soft iron's in-plane shape.
    On a circle's part an MPU-6050/HMC5883L-class board's 3 % of soft iron moved the centre 1-3 µT (the suite's twist
    sessions); over 200° and more, the ellipse's centre was within 0.8 µT. Given the gyroscope (`gyr_rad_s`, `dt_s`,
    the same samples) and no sample of it clipped, the ellipse is fitted along the twist it integrates
    (`_gyro_ellipse`) whatever the turn.

    Raises ValueError with what to do when the field did not turn `MIN_IRON_SPAN_RAD` about the centre, the samples
    do not trace a circle (`MAX_IRON_SCATTER`) or are not finite."""
    mag = np.asarray(mag_uT, dtype=np.float64)
    if mag.ndim != 2 or mag.shape[1] != 3 or mag.shape[0] < 3 * SEGMENTS:
        raise ValueError(f"need magnetometer samples (N, 3), N ≥ {3 * SEGMENTS}, got {mag.shape}")
    if not np.isfinite(mag).all():
        raise ValueError("the magnetometer samples are not all finite")
    xy = (mag @ tilt_matrix(tilt_xy_rad).T)[:, :2]
    centre, radius, dist = _circle(xy)
    scatter = float(np.sqrt(np.mean(dist * dist)))
    if not (radius > 1.0 and scatter <= MAX_IRON_SCATTER * radius):
        raise ValueError(f"the magnetometer's x/y do not trace a circle as the hook turns ({scatter:.1f} µT rms about "
                         f"one of {radius:.1f} µT): steel moving near it, or a hook that did not turn")
    span = float(np.ptp(np.unwrap(np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0]))))
    if span < MIN_IRON_SPAN_RAD:
        raise ValueError(f"the hook turned {math.degrees(span):.0f}° in all; turn it "
                         f"{math.degrees(MIN_IRON_SPAN_RAD):.0f}° or more for the magnetometer's offset")
    seg = np.array([_circle(xy[p])[0] for p in np.array_split(np.arange(xy.shape[0]), SEGMENTS)])
    std = float(np.sqrt(np.mean(np.var(seg, axis=0, ddof=1)) / SEGMENTS))
    shape = np.eye(2)
    gyr = None if gyr_rad_s is None else np.asarray(gyr_rad_s, dtype=np.float64)
    by_gyro = (gyr is not None and dt_s is not None and gyr.shape == mag.shape and bool(np.isfinite(gyr).all())
               and not clipped(gyr, GYRO_MIN_FULL_SCALE_RAD_S).any())  # fmt: skip
    ellipse = None
    if by_gyro:
        assert gyr is not None and dt_s is not None
        e_centre, a, res = _gyro_ellipse(xy, (gyr @ tilt_matrix(tilt_xy_rad).T)[:, 2], dt_s)
        if res <= 2.0 * scatter:  # else the twist it integrates is not the field's (a bias beyond the search)
            ellipse = e_centre, a
    if ellipse is None and span >= MIN_SHAPE_SPAN_RAD:
        ellipse = _ellipse(xy, centre)
    if ellipse is not None:
        e_centre, a = ellipse
        u, sv, _ = np.linalg.svd(a)
        if np.isfinite(a).all() and sv[1] > 0.0 and sv[0] / sv[1] <= MAX_SHAPE_STRETCH:
            radius = float(np.sqrt(sv[0] * sv[1]))  # A = P R, P = U Σ Uᵀ: the correction r P⁻¹ keeps the area
            centre, shape = e_centre, radius * (u / sv) @ u.T
            d = (xy - centre) @ shape.T
            dist = np.hypot(d[:, 0], d[:, 1]) - radius
    return IronFit(centre, radius, float(np.sqrt(np.mean(dist * dist))), span, std, shape)


class TiltedHookFilter:
    """A hook filter fed in the hook's axes from an IMU tilted on the hook by `tilt_xy_rad` (`imu_tilt_deg`): every
    sample method turns its vectors by `tilt_matrix` and hands them on; everything else is the inner filter's (its
    state, settings and outputs, which are then of the hook's axes)."""

    def __init__(self, inner: Any, tilt_xy_rad: ArrayLike) -> None:
        self.__dict__["inner"] = inner
        self.__dict__["m_t"] = tilt_matrix(tilt_xy_rad).T  # rows @ M.T: each (3,) row turned by M

    def _turn(self, v: ArrayLike | None) -> FloatArray | None:
        return None if v is None else np.asarray(v, dtype=np.float64) @ self.m_t

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        self.inner.initialise(self._turn(acc_m_s2), self._turn(mag_uT))

    def start(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float,
              seed_bias: bool = True) -> None:  # fmt: skip
        self.inner.start(self._turn(gyr_rad_s), self._turn(acc_m_s2), self._turn(mag_uT), dt_s, seed_bias=seed_bias)

    def update(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
               ) -> FloatArray:  # fmt: skip
        out: FloatArray = self.inner.update(self._turn(gyr_rad_s), self._turn(acc_m_s2), self._turn(mag_uT), dt_s)
        return out

    def run_with_length(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float,
                        r_scale: float = 1.0, tip_enu: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
        out: tuple[FloatArray, FloatArray] = self.inner.run_with_length(
            self._turn(gyr_rad_s), self._turn(acc_m_s2), self._turn(mag_uT), dt_s, r_scale, tip_enu)
        return out  # the boom tip's acceleration is in ENU: the IMU's tilt does not turn it

    def run(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float,
            tip_enu: FloatArray | None = None) -> FloatArray:  # fmt: skip
        return self.run_with_length(gyr_rad_s, acc_m_s2, mag_uT, dt_s, tip_enu=tip_enu)[0]

    def run_bridged(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float,
                    coast: Any, tip_enu: FloatArray | None = None) -> FloatArray:  # fmt: skip
        out: FloatArray = self.inner.run_bridged(self._turn(gyr_rad_s), self._turn(acc_m_s2), self._turn(mag_uT),
                                                 dt_s, coast, tip_enu)  # fmt: skip
        return out

    def seed_gyro_bias(self, bias_rad_s: FloatArray, *args: Any, **kwargs: Any) -> None:
        self.inner.seed_gyro_bias(self._turn(bias_rad_s), *args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.inner, name, value)
