"""Minimal quaternion helpers for the simulators (scalar-first wxyz, body -> ENU), vectorised over leading axes.

Kept separate from `gateway.fusion.quaternion` on purpose: the simulators stand in for firmware and must not
share code with the estimator they are used to test. Convention identical to docs/design.md:
`q = qz(yaw) ⊗ qy(-pitch) ⊗ qx(roll)`, pitch positive when body x points above the horizon.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def multiply(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product p ⊗ q, shapes (..., 4)."""
    a, b = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    w1, x1, y1, z1 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    w2, x2, y2, z2 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out: FloatArray = np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )
    return out


def conjugate(q: ArrayLike) -> FloatArray:
    """Conjugate q* (the inverse of a unit quaternion), shapes (..., 4)."""
    out: FloatArray = np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])
    return out


def to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrix body -> earth, shape (..., 3, 3)."""
    a = np.asarray(q, dtype=np.float64)
    w, x, y, z = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def rotate_inverse(q: ArrayLike, v_earth: ArrayLike) -> FloatArray:
    """Earth-frame vector(s) expressed in the body frame: R(q)ᵀ v."""
    r = to_matrix(q)
    out: FloatArray = np.einsum("...ji,...j->...i", r, np.asarray(v_earth, dtype=np.float64))
    return out


def from_euler(roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """`q = qz(yaw) ⊗ qy(-pitch) ⊗ qx(roll)` (design.md Z-Y-X, pitch positive nose up), shape (..., 4)."""
    r, p, y = np.broadcast_arrays(
        np.asarray(roll_rad, dtype=np.float64), np.asarray(pitch_rad, dtype=np.float64),
        np.asarray(yaw_rad, dtype=np.float64),
    )
    z = np.zeros_like(r)
    qx = np.stack([np.cos(r / 2), np.sin(r / 2), z, z], axis=-1)
    qy = np.stack([np.cos(-p / 2), z, np.sin(-p / 2), z], axis=-1)
    qz = np.stack([np.cos(y / 2), z, z, np.sin(y / 2)], axis=-1)
    q = multiply(qz, multiply(qy, qx))
    out: FloatArray = np.where(q[..., :1] < 0, -q, q)
    return out


def to_euler(q: ArrayLike) -> FloatArray:
    """Inverse of `from_euler`: roll, pitch, yaw in rad, shape (..., 3)."""
    r = to_matrix(q)
    pitch = np.arcsin(np.clip(r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def body_rates_from_euler(
    euler_rad: ArrayLike, euler_rate_rad_s: ArrayLike
) -> FloatArray:
    """Body angular rate (rad/s) from Euler angles and their rates for `from_euler`'s convention.

    With θ' = -pitch in the aerospace Z-Y-X kinematics p = φ̇ - ψ̇ sin θ', q = θ̇' cos φ + ψ̇ cos θ' sin φ,
    r = -θ̇' sin φ + ψ̇ cos θ' cos φ.
    """
    e, d = np.asarray(euler_rate_rad_s, dtype=np.float64), np.asarray(euler_rad, dtype=np.float64)
    roll, pitch = d[..., 0], d[..., 1]
    droll, dpitch, dyaw = e[..., 0], e[..., 1], e[..., 2]
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    wx = droll + dyaw * sp
    wy = -dpitch * cr + dyaw * cp * sr
    wz = dpitch * sr + dyaw * cp * cr
    return np.stack([wx, wy, wz], axis=-1)
