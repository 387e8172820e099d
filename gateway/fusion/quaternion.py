"""Quaternion maths, scalar first `w, x, y, z`, float64, body -> earth (ENU); see docs/design.md.

Every function takes arrays of shape `(..., 4)` (quaternions) or `(..., 3)` (vectors) and broadcasts over the
leading axes. `q` rotates a body vector into the earth frame: `v_earth = q ⊗ v_body ⊗ q*`.

Numba kernels for per-sample loops (`mul4`, `rotate4`, ...) work on single 1-D arrays and are listed at the end.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
F = TypeVar("F", bound=Callable[..., Any])

GRAVITY_M_S2 = 9.81
"""Nominal gravity used where a magnitude is needed (BROAD and the rigs sit near 9.81 m/s²)."""


def njit(func: F) -> F:
    """`numba.njit(cache=True)` with the function's own type kept, so mypy --strict still checks callers."""
    return cast(F, numba.njit(cache=True, fastmath=False)(func))


def _f64(a: ArrayLike) -> FloatArray:
    return np.asarray(a, dtype=np.float64)


# ---------------------------------------------------------------------------------------------------------------
# Basic algebra
# ---------------------------------------------------------------------------------------------------------------


def check_samples(*arrays: ArrayLike) -> None:
    """Raise ValueError unless every array has the same shape (N, 3): numba loops do not check bounds."""
    shapes = {np.shape(a) for a in arrays}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2 or next(iter(shapes))[1] != 3:
        raise ValueError(f"expected sample arrays of one shape (N, 3), got shapes {sorted(shapes)}")


def identity(shape: tuple[int, ...] = ()) -> FloatArray:
    """Identity quaternion(s) of the given leading shape."""
    q = np.zeros((*shape, 4))
    q[..., 0] = 1.0
    return q


def multiply(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product `p ⊗ q` (apply q first, then p, when both rotate vectors)."""
    p, q = _f64(p), _f64(q)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: ArrayLike) -> FloatArray:
    """Conjugate `q*` (the inverse of a unit quaternion)."""
    out = _f64(q).copy()
    out[..., 1:] *= -1.0
    return out


def normalise(q: ArrayLike) -> FloatArray:
    """Scale to unit norm (seed 000 eq. 22-24)."""
    q = _f64(q)
    out: FloatArray = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out


def canonical(q: ArrayLike) -> FloatArray:
    """The same rotation with `w >= 0` (q and -q are one rotation); useful before comparing."""
    q = _f64(q)
    out: FloatArray = np.where(q[..., :1] < 0.0, -q, q)
    return out


def angle_between(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Rotation angle in rad of `p ⊗ q*`, in [0, π]; insensitive to the sign of either quaternion."""
    w = np.abs(np.sum(_f64(p) * _f64(q), axis=-1))
    return _f64(2.0 * np.arccos(np.clip(w, 0.0, 1.0)))


def rotate(q: ArrayLike, v_body: ArrayLike) -> FloatArray:
    """Rotate body-frame vectors into the earth frame: `q ⊗ v ⊗ q*`."""
    q, v = _f64(q), _f64(v_body)
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rotate_inverse(q: ArrayLike, v_earth: ArrayLike) -> FloatArray:
    """Rotate earth-frame vectors into the body frame: `q* ⊗ v ⊗ q`."""
    return rotate(conjugate(q), v_earth)


# ---------------------------------------------------------------------------------------------------------------
# Conversions
# ---------------------------------------------------------------------------------------------------------------


def to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrix `R` (..., 3, 3) with `v_earth = R @ v_body`; its columns are the body axes in ENU."""
    q = normalise(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty((*q.shape[:-1], 3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def from_matrix(r: ArrayLike) -> FloatArray:
    """Quaternion (w >= 0) from rotation matrices (..., 3, 3), by Shepperd's method (stable for every angle)."""
    r = _f64(r)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    trace = m00 + m11 + m22
    # Four candidate solutions; pick per element the one with the largest pivot (seed 000 eq. 17-18 signs).
    cand = np.stack(
        [
            np.stack([1 + trace, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
                     axis=-1),
            np.stack([r[..., 2, 1] - r[..., 1, 2], 1 + 2 * m00 - trace, r[..., 0, 1] + r[..., 1, 0],
                      r[..., 0, 2] + r[..., 2, 0]], axis=-1),
            np.stack([r[..., 0, 2] - r[..., 2, 0], r[..., 0, 1] + r[..., 1, 0], 1 + 2 * m11 - trace,
                      r[..., 1, 2] + r[..., 2, 1]], axis=-1),
            np.stack([r[..., 1, 0] - r[..., 0, 1], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1],
                      1 + 2 * m22 - trace], axis=-1),
        ],
        axis=-2,
    )
    pivots = np.stack([1 + trace, 1 + 2 * m00 - trace, 1 + 2 * m11 - trace, 1 + 2 * m22 - trace], axis=-1)
    best = np.argmax(pivots, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    return canonical(normalise(q))


def from_rotvec(rotvec_rad: ArrayLike) -> FloatArray:
    """Quaternion of a rotation vector (axis × angle in rad); exact, stable near zero."""
    rv = _f64(rotvec_rad)
    angle = np.linalg.norm(rv, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(θ/2)/θ with its Taylor series below 1e-4 rad (error < 1e-17)
    small = angle < 1e-4
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), k * rv], axis=-1)


def to_rotvec(q: ArrayLike) -> FloatArray:
    """Rotation vector (axis × angle in rad, angle in [0, π]) of a unit quaternion."""
    q = canonical(normalise(q))
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s < 1e-12
    k = np.where(small, 2.0, angle / np.where(small, 1.0, s))
    return k * q[..., 1:]


def from_axis_angle(axis: ArrayLike, angle_rad: ArrayLike) -> FloatArray:
    """Quaternion of a rotation by `angle_rad` about `axis` (any non-zero length)."""
    axis = _f64(axis)
    unit = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    return from_rotvec(unit * _f64(angle_rad)[..., None])


# ---------------------------------------------------------------------------------------------------------------
# Gyro integration: q_k = q_{k-1} ⊗ Δq, with the body rate ω in rad/s over dt_s
# ---------------------------------------------------------------------------------------------------------------


def exp_gyro_step(gyr_rad_s: ArrayLike, dt_s: float) -> FloatArray:
    """Exact increment `Δq = exp(ω dt / 2)` for a body rate held constant over `dt_s`."""
    return from_rotvec(_f64(gyr_rad_s) * dt_s)


def integrate_exact(q: ArrayLike, gyr_rad_s: ArrayLike, dt_s: float) -> FloatArray:
    """`q ⊗ exp(ω dt / 2)`: the exact update for a constant body rate."""
    return multiply(q, exp_gyro_step(gyr_rad_s, dt_s))


def _omega_product(q: FloatArray, gyr_rad_s: FloatArray) -> FloatArray:
    """`q ⊗ (0, ω)`, the quaternion derivative times 2 (seed 000 eq. 7-8)."""
    zeros = np.zeros((*np.asarray(gyr_rad_s).shape[:-1], 1))
    return multiply(q, np.concatenate([zeros, gyr_rad_s], axis=-1))


def first_order_update(q: ArrayLike, gyr_rad_s: ArrayLike, dt_s: float, *, renormalise: bool = True) -> FloatArray:
    """First-order Runge-Kutta step `q + dt/2 · q ⊗ (0, ω)` (seed 000 eq. 19-21), then normalise (eq. 22-24)."""
    q, w = _f64(q), _f64(gyr_rad_s)
    out = q + 0.5 * dt_s * _omega_product(q, w)
    return normalise(out) if renormalise else out


def picard3_update(q: ArrayLike, gyr_rad_s: ArrayLike, dt_s: float, *, renormalise: bool = True) -> FloatArray:
    """Third-order Picard step (seed 001 eq. 9-12): `[I(1 - Δθ²/8) + (1/2 - Δθ²/48) ΔΘ] q`, Δθ = |ω| dt."""
    q, w = _f64(q), _f64(gyr_rad_s)
    dtheta = w * dt_s
    d2 = np.sum(dtheta * dtheta, axis=-1, keepdims=True)
    out = q * (1.0 - d2 / 8.0) + (0.5 - d2 / 48.0) * _omega_product(q, dtheta)
    return normalise(out) if renormalise else out


# ---------------------------------------------------------------------------------------------------------------
# Euler angles (docs/design.md)
# ---------------------------------------------------------------------------------------------------------------


def to_euler(q: ArrayLike) -> FloatArray:
    """Roll, pitch, yaw in rad, shape (..., 3), from `R = Rz(yaw) · Ry(-pitch) · Rx(roll)` (Z-Y-X sequence).

    pitch: elevation of body x above the horizon, in [-π/2, π/2] (positive = rod tip up);
    yaw: heading of body x, counter-clockwise from East, in (-π, π];
    roll: rotation about body x, right-handed, in (-π, π] (positive = body y tips up).
    At pitch = ±π/2 roll and yaw are not separable; roll then carries the whole turn and yaw is whatever
    `atan2` returns.
    """
    r = to_matrix(q)
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = np.arcsin(np.clip(r[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.stack([roll, pitch, wrap_angle(yaw)], axis=-1)


def from_euler(roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """Inverse of `to_euler`: `q = qz(yaw) ⊗ qy(-pitch) ⊗ qx(roll)`."""
    roll, pitch, yaw = np.broadcast_arrays(_f64(roll_rad), _f64(pitch_rad), _f64(yaw_rad))
    z = np.zeros_like(roll)
    qx = np.stack([np.cos(roll / 2), np.sin(roll / 2), z, z], axis=-1)
    qy = np.stack([np.cos(-pitch / 2), z, np.sin(-pitch / 2), z], axis=-1)
    qz = np.stack([np.cos(yaw / 2), z, z, np.sin(yaw / 2)], axis=-1)
    return multiply(qz, multiply(qy, qx))


def wrap_angle(angle_rad: ArrayLike) -> FloatArray:
    """Wrap to (-π, π]."""
    a = _f64(angle_rad)
    out = np.mod(a + np.pi, 2 * np.pi) - np.pi
    return np.where(out == -np.pi, np.pi, out)


def unwrap_yaw(yaw_rad: ArrayLike) -> FloatArray:
    """Continuous yaw along the last axis: removes the ±2π jumps at ±π (seed 000 notes the jump)."""
    return np.unwrap(_f64(yaw_rad), axis=-1)


class YawUnwrapper:
    """Streaming form of `unwrap_yaw`: feed wrapped yaw one sample at a time, get a continuous angle back."""

    def __init__(self) -> None:
        self._last_wrapped: float | None = None
        self._turns = 0

    def update(self, yaw_rad: float) -> float:
        """Return the continuous yaw in rad for this wrapped sample (steps below π between samples assumed)."""
        if self._last_wrapped is not None:
            step = yaw_rad - self._last_wrapped
            if step > np.pi:
                self._turns -= 1
            elif step < -np.pi:
                self._turns += 1
        self._last_wrapped = yaw_rad
        return yaw_rad + 2.0 * np.pi * self._turns

    def reset(self) -> None:
        self._last_wrapped = None
        self._turns = 0


# ---------------------------------------------------------------------------------------------------------------
# Initial attitude at rest (seed 000 eq. 17-18; seed 004 tilt-compensated heading)
# ---------------------------------------------------------------------------------------------------------------


def from_acc(acc_m_s2: ArrayLike) -> FloatArray:
    """Attitude with yaw = 0 whose predicted specific force matches `acc_m_s2` at rest (roll and pitch only)."""
    a = _f64(acc_m_s2)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    roll = np.arctan2(a[..., 1], a[..., 2])
    pitch = np.arcsin(np.clip(a[..., 0], -1.0, 1.0))
    return from_euler(roll, pitch, np.zeros_like(roll))


def from_acc_mag(acc_m_s2: ArrayLike, mag_uT: ArrayLike) -> FloatArray:
    """Attitude at rest from specific force and magnetic field in the body frame, ENU.

    Up = acc/|acc|; East = normalise(mag × Up) (the horizontal field points North); North = Up × East.
    The rows of the body->earth matrix are East, North, Up expressed in body coordinates.
    """
    a, m = _f64(acc_m_s2), _f64(mag_uT)
    up = a / np.linalg.norm(a, axis=-1, keepdims=True)
    east = np.cross(m, up)
    east = east / np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(up, east)
    return from_matrix(np.stack([east, north, up], axis=-2))


def heading_from_mag(q_tilt: ArrayLike, mag_uT: ArrayLike) -> FloatArray:
    """Yaw in rad (CCW from East) that makes attitude `q_tilt` (roll, pitch kept) agree with the magnetometer.

    Tilt compensation (seed 004): rotate the field into the earth frame with roll and pitch only, then take the
    heading of its horizontal part: the field's earth direction should be North (yaw of body x = yaw_tilt + Δ).
    """
    m_earth = rotate(q_tilt, mag_uT)
    field_bearing = np.arctan2(m_earth[..., 1], m_earth[..., 0])  # CCW from East; π/2 when pointing North
    yaw_tilt = to_euler(q_tilt)[..., 2]
    return wrap_angle(yaw_tilt + np.pi / 2 - field_bearing)


# ---------------------------------------------------------------------------------------------------------------
# Numba kernels on single quaternions (shape (4,)) and vectors (shape (3,)), for per-sample filter loops
# ---------------------------------------------------------------------------------------------------------------


@njit
def mul4(p: FloatArray, q: FloatArray) -> FloatArray:
    """`p ⊗ q` for single quaternions (numba)."""
    out = np.empty(4)
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]
    return out


@njit
def normalise4(q: FloatArray) -> FloatArray:
    """Unit-norm copy of a single quaternion (numba)."""
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    out: FloatArray = q / n
    return out


@njit
def rotate4(q: FloatArray, v: FloatArray) -> FloatArray:
    """Body -> earth rotation of one vector by one quaternion (numba)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    tx = 2.0 * (y * v[2] - z * v[1])
    ty = 2.0 * (z * v[0] - x * v[2])
    tz = 2.0 * (x * v[1] - y * v[0])
    out = np.empty(3)
    out[0] = v[0] + w * tx + (y * tz - z * ty)
    out[1] = v[1] + w * ty + (z * tx - x * tz)
    out[2] = v[2] + w * tz + (x * ty - y * tx)
    return out


@njit
def rotate_inverse4(q: FloatArray, v: FloatArray) -> FloatArray:
    """Earth -> body rotation of one vector by one quaternion (numba)."""
    qc = np.empty(4)
    qc[0] = q[0]
    qc[1] = -q[1]
    qc[2] = -q[2]
    qc[3] = -q[3]
    return rotate4(qc, v)


@njit
def gyro_step4(q: FloatArray, gyr_rad_s: FloatArray, dt_s: float) -> FloatArray:
    """`normalise(q ⊗ exp(ω dt / 2))` for one sample (numba)."""
    wx, wy, wz = gyr_rad_s[0] * dt_s, gyr_rad_s[1] * dt_s, gyr_rad_s[2] * dt_s
    angle = np.sqrt(wx * wx + wy * wy + wz * wz)
    dq = np.empty(4)
    dq[0] = np.cos(0.5 * angle)
    k = 0.5 - angle * angle / 48.0 if angle < 1e-4 else np.sin(0.5 * angle) / angle
    dq[1] = k * wx
    dq[2] = k * wy
    dq[3] = k * wz
    return normalise4(mul4(q, dq))


@njit
def tilt_error4(q: FloatArray, acc_m_s2: FloatArray) -> FloatArray:
    """Body-frame error `â × v̂` between measured and predicted gravity direction (seed 004; zero if acc is 0).

    v̂ = q* ⊗ [0, 0, 1] ⊗ q is the predicted "up" in the body; rotating about the result brings v̂ onto â.
    """
    out = np.zeros(3)
    n = np.sqrt(acc_m_s2[0] ** 2 + acc_m_s2[1] ** 2 + acc_m_s2[2] ** 2)
    if n == 0.0:
        return out
    ax, ay, az = acc_m_s2[0] / n, acc_m_s2[1] / n, acc_m_s2[2] / n
    w, x, y, z = q[0], q[1], q[2], q[3]
    vx = 2.0 * (x * z - w * y)
    vy = 2.0 * (y * z + w * x)
    vz = 1.0 - 2.0 * (x * x + y * y)
    out[0] = ay * vz - az * vy
    out[1] = az * vx - ax * vz
    out[2] = ax * vy - ay * vx
    return out


@njit
def heading_error4(q: FloatArray, mag_uT: FloatArray) -> float:
    """Yaw error in rad of `q` from the tilt-compensated field (seed 004): the bearing of the field's horizontal
    part in the estimated earth frame minus North (π/2), wrapped; positive when the estimate is rotated CCW too far.
    Returns 0 when the field has no usable horizontal part."""
    m = rotate4(q, mag_uT)
    h = np.sqrt(m[0] * m[0] + m[1] * m[1])
    if h < 1e-9:
        return 0.0
    e = np.arctan2(m[1], m[0]) - 0.5 * np.pi
    if e > np.pi:
        e -= 2.0 * np.pi
    elif e <= -np.pi:
        e += 2.0 * np.pi
    return float(e)
