"""Crane-hook geometry from the hook attitude (seed 001 eq. 1-7): swing angle, swing direction, torsion.

Conventions (docs/design.md): `q` is wxyz, body -> ENU, shape (..., 4). The hook's body z axis lies along the
rope and points up to the boom tip, so the rope direction is `n = R e_z` (the third column of R). All angles
are in radians.

* **Swing angle Θ** ∈ [0, π]: the angle between the rope and the earth vertical, `cos Θ = n_z`. This equals
  `cos θx · cos θy` (eq. 6) and `cos(roll) · cos(pitch)` of the Z-Y-X Euler angles, the paper's `M`. It does
  not depend on any rotation about the rope (torsion), nor on heading.
* **Swing components θx, θy** (Fig. 1), in the *rest frame*: ENU turned by the rest heading ψ about the
  vertical, so its X axis is the hook's body x when hanging still. With the hook's horizontal displacement
  `d = -n_h` (from the point below the boom tip to the hook), `θx` is the angle between the rope's projection
  on the rest XZ plane and the vertical (positive when the hook is displaced towards +X) and `θy` the angle
  between the rope and that plane (positive towards +Y).
* **Displacement bearing** ∈ (-π, π]: the direction of the hook's horizontal displacement, counter-clockwise
  from East (the yaw convention). Unambiguous, but undefined when Θ = 0 (then 0 is returned).
* **Swing direction Φ (eq. 7)** ∈ [-π/2, π/2]: `sin Φ = sin θy / sin Θ`, the paper's bearing of the swing
  relative to ψ. Being an arcsine it cannot tell the two sides apart: the true displacement bearing is ψ + Φ on
  the +X side and ψ + 180° - Φ on the -X side, which is the alternation every half period the paper describes.
* **Swing plane direction** ∈ [0, π): the displacement bearing relative to ψ folded modulo 180°; constant
  through a planar swing (both half periods), so it is the quantity to display and alarm on.
* **Torsion φ** ∈ (-π, π]: twist about the rope. `q` is split as `q = q_swing ⊗ q_z(α)` with `q_swing` the
  shortest rotation taking the vertical onto the rope (eq. 2: the twisted attitude is the untwisted one turned
  about body z); `α = 2 atan2(q_z, q_w)` is the hook's heading about the rope, and `φ = α - ψ_ref`, positive
  counter-clockwise seen from above (the paper's "clockwise" twist is -φ). Θ and the displacement bearing do
  not change with φ.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def _wrap(angle_rad: FloatArray) -> FloatArray:
    """Wrap to (-π, π]."""
    out: FloatArray = np.pi - np.mod(np.pi - angle_rad, 2.0 * np.pi)
    return out


def rope_direction(q: ArrayLike) -> FloatArray:
    """Unit rope direction `n = R e_z` (..., 3) in ENU, from the hook up to the boom tip."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)], axis=-1)


def swing_angle(q: ArrayLike) -> FloatArray:
    """Swing angle Θ in [0, π] (eq. 6): `cos Θ = n_z`, computed as `2 atan2(|(x, y)|, |(w, z)|)` for accuracy at 0."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    out: FloatArray = 2.0 * np.arctan2(np.hypot(x, y), np.hypot(w, z))
    return out


def swing_components(q: ArrayLike, rest_heading_rad: ArrayLike = 0.0) -> tuple[FloatArray, FloatArray]:
    """`(θx, θy)` of Fig. 1 in the rest frame (see the module docstring); `cos θx · cos θy = cos Θ`."""
    n = rope_direction(q)
    psi = np.asarray(rest_heading_rad, dtype=np.float64)
    c, s = np.cos(psi), np.sin(psi)
    dx = -(c * n[..., 0] + s * n[..., 1])  # hook displacement in the rest frame
    dy = -(-s * n[..., 0] + c * n[..., 1])
    theta_x: FloatArray = np.arctan2(dx, n[..., 2])
    theta_y: FloatArray = np.arctan2(dy, np.hypot(dx, n[..., 2]))
    return theta_x, theta_y


def displacement_bearing(q: ArrayLike) -> FloatArray:
    """Bearing of the hook's horizontal displacement in (-π, π], CCW from East; 0 when hanging exactly plumb."""
    n = rope_direction(q)
    out: FloatArray = np.arctan2(-n[..., 1], -n[..., 0])
    return out


def swing_direction_paper(q: ArrayLike, rest_heading_rad: ArrayLike = 0.0) -> FloatArray:
    """Φ of eq. 7 in [-π/2, π/2]: `sin Φ = sin θy / sin Θ` relative to ψ (ambiguous between Φ and π - Φ)."""
    _, theta_y = swing_components(q, rest_heading_rad)
    sin_big = np.sin(swing_angle(q))
    ratio = np.divide(np.sin(theta_y), sin_big, out=np.zeros_like(sin_big), where=sin_big > 0.0)
    out: FloatArray = np.arcsin(np.clip(ratio, -1.0, 1.0))
    return out


def swing_plane_direction(q: ArrayLike, rest_heading_rad: ArrayLike = 0.0) -> FloatArray:
    """Direction of the swing plane relative to ψ in [0, π): the displacement bearing minus ψ, modulo π."""
    out: FloatArray = np.mod(displacement_bearing(q) - np.asarray(rest_heading_rad, dtype=np.float64), np.pi)
    return np.where(out >= np.pi, 0.0, out)  # mod can round a tiny negative up to π


def turn_horizontal(rows: ArrayLike, angle_rad: float) -> FloatArray:
    """Horizontal vectors (N, 2), x/y, turned counter-clockwise (seen from above) by `angle_rad`: the same vectors
    read in a frame turned by -`angle_rad` (a crane feed's East/North in the filter's own frame)."""
    v = np.asarray(rows, dtype=np.float64)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.column_stack((c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]))


def twist_heading(q: ArrayLike) -> FloatArray:
    """Hook heading about the rope α in (-π, π]: the twist part of the swing-twist split `q = q_swing ⊗ q_z(α)`."""
    q = np.asarray(q, dtype=np.float64)
    return _wrap(2.0 * np.arctan2(q[..., 3], q[..., 0]))


def torsion(q: ArrayLike, reference_rad: ArrayLike = 0.0) -> FloatArray:
    """Torsion φ = α - reference in (-π, π] (eq. 1-3): twist about the rope relative to, e.g., the rest heading."""
    return _wrap(twist_heading(q) - np.asarray(reference_rad, dtype=np.float64))


def hook_attitude(swing_rad: ArrayLike, bearing_rad: ArrayLike, heading_rad: ArrayLike) -> FloatArray:
    """Inverse of the split (for tests and sims): the hook displaced by Θ towards `bearing_rad`, heading α."""
    th = np.asarray(swing_rad, dtype=np.float64)
    b = np.asarray(bearing_rad, dtype=np.float64)
    a = np.asarray(heading_rad, dtype=np.float64)
    th, b, a = np.broadcast_arrays(th, b, a)
    # The rope tilts away from the displacement: swing axis e_z × n / |e_z × n| = (sin b, -cos b, 0).
    w0, s0 = np.cos(0.5 * th), np.sin(0.5 * th)
    x0, y0 = s0 * np.sin(b), -s0 * np.cos(b)
    cw, sa = np.cos(0.5 * a), np.sin(0.5 * a)
    return np.stack([w0 * cw, x0 * cw + y0 * sa, y0 * cw - x0 * sa, w0 * sa], axis=-1)  # q_swing ⊗ q_z(α)
