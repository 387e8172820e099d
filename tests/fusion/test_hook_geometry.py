"""Hook geometry (seed 001 eq. 1-7) against constructed attitudes, scipy Euler angles and the hook physics truth.

Tolerances: 1e-9 rad for closed-form trigonometry; 1e-7 rad near the arcsine/arccos edges.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from devices.hook_physics import HookPhysicsSettings, HookScenario, simulate
from gateway.fusion import hook

ATOL = 1e-9


@st.composite
def unit_quats(draw: st.DrawFn) -> np.ndarray:
    v = draw(arrays(np.float64, 4, elements=st.floats(-1.0, 1.0)).filter(lambda a: np.linalg.norm(a) > 0.1))
    return v / np.linalg.norm(v)


angles = st.floats(-math.pi, math.pi)


def z_rotation(angle_rad: float) -> np.ndarray:
    return np.array([math.cos(angle_rad / 2), 0.0, 0.0, math.sin(angle_rad / 2)])


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    r = Rotation.from_quat(p[[1, 2, 3, 0]]) * Rotation.from_quat(q[[1, 2, 3, 0]])
    return r.as_quat()[[3, 0, 1, 2]]


def angle_diff(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi)


@given(unit_quats(), angles)
def test_swing_angle_is_invariant_to_twist_about_the_rope(q, twist):
    twisted = qmul(q, z_rotation(twist))
    assert hook.swing_angle(twisted) == pytest.approx(hook.swing_angle(q), abs=ATOL)
    if hook.swing_angle(q) < 3.0:  # the swing-twist split is singular with the hook upside down (Θ = π)
        assert angle_diff(hook.torsion(twisted, hook.twist_heading(q)), twist) < 1e-7


@given(unit_quats())
@pytest.mark.filterwarnings("ignore:Gimbal lock")
def test_swing_angle_range_and_the_papers_cosine_product(q):
    theta = float(hook.swing_angle(q))
    assert 0.0 <= theta <= math.pi
    # cos Θ = n_z = cos(roll) cos(pitch) of the Z-Y-X Euler angles (the paper's M, eq. 3 and 6).
    yaw, pitch, roll = Rotation.from_quat(q[[1, 2, 3, 0]]).as_euler("ZYX")
    # Euler pitch comes from an arcsin: near ±90° (gimbal lock) it carries ~sqrt(eps) error, so cos(pitch) does
    # (hypothesis found 6e-8 there); the direct check below keeps the tight tolerance.
    assert math.cos(theta) == pytest.approx(math.cos(roll) * math.cos(pitch), abs=max(ATOL, 3e-7))
    assert math.cos(theta) == pytest.approx(Rotation.from_quat(q[[1, 2, 3, 0]]).apply([0, 0, 1])[2], abs=ATOL)


@given(unit_quats(), angles)
def test_swing_components_compose_to_the_swing_angle(q, rest_heading):
    theta_x, theta_y = hook.swing_components(q, rest_heading)
    assert math.cos(theta_x) * math.cos(theta_y) == pytest.approx(math.cos(hook.swing_angle(q)), abs=ATOL)


@given(st.floats(0.01, math.pi - 0.01), angles, angles)
def test_constructed_attitude_round_trips(theta, bearing, heading):
    q = hook.hook_attitude(theta, bearing, heading)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
    assert hook.swing_angle(q) == pytest.approx(theta, abs=ATOL)
    assert angle_diff(hook.displacement_bearing(q), bearing) < 1e-9
    assert angle_diff(hook.twist_heading(q), heading) < 1e-9
    assert angle_diff(hook.displacement_bearing(qmul(q, z_rotation(0.7))), bearing) < 1e-9


def test_known_geometry_reference_values():
    # Hook displaced 30° towards North (+y), hook heading East: rope leans South, θx = 0, θy = 30°.
    q = hook.hook_attitude(math.radians(30), math.pi / 2, 0.0)
    np.testing.assert_allclose(hook.rope_direction(q), [0.0, -0.5, math.sqrt(3) / 2], atol=ATOL)
    theta_x, theta_y = hook.swing_components(q)
    assert theta_x == pytest.approx(0.0, abs=ATOL) and theta_y == pytest.approx(math.radians(30), abs=ATOL)
    assert hook.swing_direction_paper(q) == pytest.approx(math.pi / 2, abs=1e-7)
    # Same displacement seen from a rest heading of 90° (rest X = North): θx = 30°, θy = 0, Φ = 0.
    theta_x, theta_y = hook.swing_components(q, math.pi / 2)
    assert theta_x == pytest.approx(math.radians(30), abs=ATOL) and theta_y == pytest.approx(0.0, abs=ATOL)
    assert hook.swing_direction_paper(q, math.pi / 2) == pytest.approx(0.0, abs=ATOL)
    # 20° towards bearing 45°, heading 45°: displacement (s, s, c) with s = sin20°/√2, c = cos20°.
    q = hook.hook_attitude(math.radians(20), math.pi / 4, math.pi / 4)
    theta_x, theta_y = hook.swing_components(q)
    s, c = math.sin(math.radians(20)) / math.sqrt(2), math.cos(math.radians(20))
    assert theta_x == pytest.approx(math.atan2(s, c), abs=ATOL)
    assert theta_y == pytest.approx(math.asin(s), abs=ATOL)
    assert hook.swing_direction_paper(q) == pytest.approx(math.pi / 4, abs=1e-7)
    assert hook.torsion(q, math.pi / 4) == pytest.approx(0.0, abs=ATOL)


@given(st.floats(0.05, 1.2), st.floats(-1.5, 1.5), angles)
def test_eq7_direction_alternates_between_phi_and_180_minus_phi(theta, rel_bearing, rest_heading):
    """On the +X side of the rest frame Φ is the relative bearing; on the -X side eq. 7 reads π - bearing."""
    front = hook.hook_attitude(theta, rest_heading + rel_bearing, 0.3)
    back = hook.hook_attitude(theta, rest_heading + rel_bearing + math.pi, 0.3)  # half a period later
    phi_front = float(hook.swing_direction_paper(front, rest_heading))
    phi_back = float(hook.swing_direction_paper(back, rest_heading))
    assert phi_front == pytest.approx(rel_bearing, abs=1e-7)
    assert angle_diff(math.pi - phi_back, rel_bearing + math.pi) < 1e-7
    # The folded plane direction is the same on both sides.
    plane_front = hook.swing_plane_direction(front, rest_heading)
    plane_back = hook.swing_plane_direction(back, rest_heading)
    assert 0.0 <= plane_front < math.pi
    assert angle_diff(2 * plane_front, 2 * plane_back) < 2e-9  # equal modulo π


def test_batched_shapes():
    q = hook.hook_attitude(np.full((2, 3), 0.2), np.zeros((2, 3)), np.zeros((2, 3)))
    assert q.shape == (2, 3, 4)
    assert hook.swing_angle(q).shape == (2, 3) and hook.rope_direction(q).shape == (2, 3, 3)
    assert hook.swing_components(q, np.zeros(3))[0].shape == (2, 3)


def test_agrees_with_the_physics_truth():
    """hook.py on the simulated attitude reproduces the simulator's own Θ, bearing and torsion (independent code)."""
    settings = HookPhysicsSettings(rope_length_m=5.0, rest_heading_rad=0.4, internal_rate_hz=500.0)
    scenario = HookScenario(
        duration_s=8.0, initial_swing_rad=0.3, initial_swing_bearing_rad=2.0, initial_sideways_rate_rad_s=0.2,
        initial_torsion_rad=0.5,
    )  # fmt: skip
    truth = simulate(settings, scenario)
    np.testing.assert_allclose(hook.swing_angle(truth.quat), truth.swing_rad, atol=ATOL)
    moving = truth.swing_rad > 1e-3
    assert np.all(angle_diff(hook.displacement_bearing(truth.quat), truth.swing_bearing_rad)[moving] < 1e-9)
    np.testing.assert_allclose(hook.torsion(truth.quat, settings.rest_heading_rad), truth.torsion_rad, atol=ATOL)


def test_the_worked_example_of_protocol_section_3_5():
    """docs/protocol.md 3.5's worked example and the `swing` example payload: the quaternion gives the published
    Θ, displacement bearing, Φ (eq. 7), torsion and θx/θy to the printed digits, and the other half period flips Φ."""
    from gateway.protocol_doc import examples

    swing = examples()["swing"][1]
    q = np.array([0.94292, 0.03305, -0.02827, 0.33016])
    psi = swing.rest_heading_rad
    assert float(hook.swing_angle(q)) == pytest.approx(swing.swing_angle_rad, abs=1e-4)
    assert float(hook.displacement_bearing(q)) == pytest.approx(swing.swing_direction_rad, abs=1e-4)
    assert float(hook.swing_direction_paper(q, psi)) == pytest.approx(swing.swing_phi_rad, abs=1e-4)
    assert float(hook.torsion(q, psi)) == pytest.approx(swing.torsion_rad, abs=1e-4)
    tx, ty = hook.swing_components(q, psi)
    assert (math.degrees(float(tx)), math.degrees(float(ty))) == pytest.approx((3.89, 3.12), abs=0.005)
    other = hook.hook_attitude(swing.swing_angle_rad, swing.swing_direction_rad + math.pi, psi + swing.torsion_rad)
    phi = float(hook.swing_direction_paper(other, psi))
    assert phi == pytest.approx(-swing.swing_phi_rad, abs=1e-9)
    assert math.remainder(psi + math.pi - phi - float(hook.displacement_bearing(other)), 2 * math.pi) == pytest.approx(
        0.0, abs=1e-9)
