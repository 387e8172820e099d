"""Hook physics: pendulum period, energy, torsion frequency and consistency of the IMU truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from devices.hook_physics import (
    HookPhysicsSettings,
    HookScenario,
    pendulum_energy_per_mass,
    simulate,
    trolley_traverse,
)


def _crossing_times(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Times of upward zero crossings, linearly interpolated."""
    i = np.nonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))[0]
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


@pytest.mark.parametrize("rope_length_m", [2.0, 10.0, 25.0])
def test_small_swing_period_matches_2pi_sqrt_l_over_g(rope_length_m):
    settings = HookPhysicsSettings(rope_length_m=rope_length_m, internal_rate_hz=500.0)
    period_ref_s = 2.0 * math.pi * math.sqrt(rope_length_m / settings.gravity_m_s2)
    scenario = HookScenario(duration_s=3.2 * period_ref_s, initial_swing_rad=math.radians(2.0), output_rate_hz=100.0)
    truth = simulate(settings, scenario)
    crossings = _crossing_times(truth.t_s, truth.rope_dir[:, 0])
    assert len(crossings) >= 2
    period_s = float(np.mean(np.diff(crossings))) if len(crossings) > 2 else float(crossings[1] - crossings[0])
    assert period_s == pytest.approx(period_ref_s, rel=0.01)


def test_energy_is_conserved_without_damping():
    """RK4 at 1 kHz with re-projection: relative energy drift below 1e-8 over 40 s of a 30° swing."""
    settings = HookPhysicsSettings(rope_length_m=8.0)
    scenario = HookScenario(duration_s=40.0, initial_swing_rad=math.radians(30.0), initial_sideways_rate_rad_s=0.3)
    energy = pendulum_energy_per_mass(simulate(settings, scenario), settings)
    assert np.ptp(energy) / abs(energy[0]) < 1e-8


def test_damping_removes_energy():
    settings = HookPhysicsSettings(rope_length_m=5.0, swing_damping_1_s=0.05, internal_rate_hz=500.0)
    truth = simulate(settings, HookScenario(duration_s=20.0, initial_swing_rad=0.2))
    energy = pendulum_energy_per_mass(truth, settings)
    assert np.all(np.diff(energy) <= 1e-9)
    assert energy[-1] < energy[0] - 0.1


def test_torsion_oscillator_frequency():
    settings = HookPhysicsSettings(internal_rate_hz=500.0)
    k, j, c = settings.torsion_stiffness_n_m_rad, settings.torsion_inertia_kg_m2, settings.torsion_damping_n_m_s_rad
    wn = math.sqrt(k / j)
    zeta = c / (2.0 * math.sqrt(k * j))
    period_ref_s = 2.0 * math.pi / (wn * math.sqrt(1.0 - zeta**2))
    truth = simulate(settings, HookScenario(duration_s=3.5 * period_ref_s, initial_torsion_rad=0.5))
    crossings = _crossing_times(truth.t_s, truth.torsion_rad)
    assert float(np.mean(np.diff(crossings))) == pytest.approx(period_ref_s, rel=0.005)
    # Amplitude decays as exp(-ζ ω_n t): compare successive positive peaks.
    bounds = zip(crossings[:-1], crossings[1:], strict=True)
    peaks = [truth.torsion_rad[(truth.t_s > a) & (truth.t_s < b)].max() for a, b in bounds]
    assert peaks[1] / peaks[0] == pytest.approx(math.exp(-zeta * wn * period_ref_s), rel=0.01)


def test_specific_force_at_rest_is_g_up_in_body():
    settings = HookPhysicsSettings(rest_heading_rad=0.7)
    truth = simulate(settings, HookScenario(duration_s=2.0))
    np.testing.assert_allclose(truth.acc_m_s2, np.tile([0.0, 0.0, settings.gravity_m_s2], (200, 1)), atol=1e-9)
    np.testing.assert_allclose(truth.gyr_rad_s, 0.0, atol=1e-12)
    np.testing.assert_allclose(truth.quat[:, 0], math.cos(0.35), atol=1e-12)
    np.testing.assert_allclose(truth.quat[:, 3], math.sin(0.35), atol=1e-12)


def test_pure_torsion_gives_centripetal_and_tangential_terms_at_the_lever_arm():
    d = 0.3
    settings = HookPhysicsSettings(lever_arm_m=(d, 0.0, 0.0), internal_rate_hz=500.0)
    truth = simulate(settings, HookScenario(duration_s=5.0, initial_torsion_rad=0.8))
    rate = truth.extra["torsion_rate_rad_s"]
    k, j, c = settings.torsion_stiffness_n_m_rad, settings.torsion_inertia_kg_m2, settings.torsion_damping_n_m_s_rad
    accel = -(k * truth.torsion_rad + c * rate) / j
    np.testing.assert_allclose(truth.acc_m_s2[:, 0], -d * rate**2, atol=1e-8)
    np.testing.assert_allclose(truth.acc_m_s2[:, 1], d * accel, atol=1e-8)
    np.testing.assert_allclose(truth.acc_m_s2[:, 2], settings.gravity_m_s2, atol=1e-9)
    np.testing.assert_allclose(truth.gyr_rad_s[:, 2], rate, atol=1e-9)


def test_swinging_specific_force_is_tension_along_the_rope_not_gravity():
    settings = HookPhysicsSettings(lever_arm_m=(0.0, 0.0, 0.0), internal_rate_hz=500.0)
    truth = simulate(settings, HookScenario(duration_s=10.0, initial_swing_rad=0.3, initial_torsion_rad=0.4))
    np.testing.assert_allclose(truth.acc_m_s2[:, :2], 0.0, atol=1e-9)
    np.testing.assert_allclose(truth.acc_m_s2[:, 2], truth.tension_per_mass_m_s2, atol=1e-9)
    # T/m = g cosΘ + l |n'|² for a fixed boom tip.
    expected = settings.gravity_m_s2 * np.cos(truth.swing_rad) + settings.rope_length_m * np.sum(
        truth.rope_rate_1_s**2, axis=1
    )
    np.testing.assert_allclose(truth.tension_per_mass_m_s2, expected, rtol=1e-12)


def test_gyro_integrates_to_the_true_attitude():
    """Exact gyro consistency: integrating the body rate reproduces the attitude to 1e-6 rad after 10 s."""
    from scipy.spatial.transform import Rotation

    settings = HookPhysicsSettings(rope_length_m=4.0)
    scenario = HookScenario(
        duration_s=10.0, output_rate_hz=1000.0, initial_swing_rad=0.4, initial_sideways_rate_rad_s=0.4,
        initial_torsion_rad=0.6,
    )  # fmt: skip
    truth = simulate(settings, scenario)
    rot = Rotation.from_quat(truth.quat[0, [1, 2, 3, 0]])
    dt = 1e-3
    for i in range(len(truth.t_s) - 1):
        w0, w1 = truth.gyr_rad_s[i], truth.gyr_rad_s[i + 1]
        w_dot = truth.extra["gyr_dot_rad_s2"]
        # Second-order rate over the step plus the commutator term (Bortz): error O(dt^4) per step.
        rotvec = 0.5 * (w0 + w1) * dt + (w_dot[i] - w_dot[i + 1]) * dt * dt / 12.0 + np.cross(w0, w1) * dt * dt / 12.0
        rot = rot * Rotation.from_rotvec(rotvec)
    ref = Rotation.from_quat(truth.quat[-1, [1, 2, 3, 0]])
    assert (rot.inv() * ref).magnitude() < 1e-6


def test_trolley_move_makes_the_hook_swing_and_the_boom_tip_travel():
    settings = HookPhysicsSettings(rope_length_m=6.0, internal_rate_hz=500.0)
    moves = trolley_traverse(1.0, 3.0, bearing_rad=math.pi / 2)
    truth = simulate(settings, HookScenario(duration_s=12.0, trolley_moves=moves))
    assert truth.suspension_pos_m[-1, 1] == pytest.approx(3.0, abs=0.01)
    assert abs(truth.suspension_pos_m[-1, 0]) < 1e-9
    assert truth.swing_rad.max() > math.radians(1.0)
    # While accelerating north the hook lags behind, i.e. is displaced south (bearing -90°).
    accelerating = (truth.t_s > 1.5) & (truth.t_s < 2.0)
    np.testing.assert_allclose(truth.swing_bearing_rad[accelerating], -math.pi / 2, atol=1e-6)


def test_held_hook_reads_gravity_then_swings_after_release():
    settings = HookPhysicsSettings(lever_arm_m=(0.0, 0.0, 0.0), internal_rate_hz=500.0)
    theta0 = math.radians(10.0)
    truth = simulate(settings, HookScenario(duration_s=3.0, initial_swing_rad=theta0, hold_s=1.0))
    held = truth.t_s < 1.0
    g = settings.gravity_m_s2
    # Held at 10° towards East: earth up in body = (sin, 0, cos) rotated; |f| = g and f_z = g cos Θ.
    np.testing.assert_allclose(np.linalg.norm(truth.acc_m_s2[held], axis=1), g, atol=1e-9)
    np.testing.assert_allclose(truth.acc_m_s2[held, 2], g * math.cos(theta0), atol=1e-9)
    np.testing.assert_allclose(truth.gyr_rad_s[held], 0.0, atol=1e-12)
    np.testing.assert_allclose(truth.swing_rad[held], theta0, atol=1e-12)
    assert truth.swing_rad[-1] < theta0 - math.radians(1.0)
    # After release the accelerometer reads tension along the rope again.
    np.testing.assert_allclose(truth.acc_m_s2[~held, :2], 0.0, atol=1e-9)


def test_steady_pull_tilts_the_hook_to_force_over_weight_and_the_imu_reads_it_across_the_rope():
    """A 200 N pull on 1000 kg held for 40 s (ramped over 5 s, damped swing): the rope settles at atan(F / (m g))
    from the vertical, displaced along the pull, and the accelerometer's x/y read the pull per unit mass."""
    from devices.hook_physics import Pull

    settings = HookPhysicsSettings(rope_length_m=5.0, hook_mass_kg=1000.0, swing_damping_1_s=0.5,
                                   lever_arm_m=(0.0, 0.0, 0.0), internal_rate_hz=500.0)  # fmt: skip
    truth = simulate(settings, HookScenario(duration_s=40.0, pulls=(Pull(0.0, 60.0, (0.0, 200.0), ramp_s=5.0),)))
    end = truth.t_s > 35.0
    expected = math.atan2(200.0, 1000.0 * settings.gravity_m_s2)
    np.testing.assert_allclose(truth.swing_rad[end], expected, atol=1e-4)
    np.testing.assert_allclose(truth.swing_bearing_rad[end], math.pi / 2, atol=1e-3)
    np.testing.assert_allclose(np.hypot(truth.acc_m_s2[end, 0], truth.acc_m_s2[end, 1]),
                               0.2 * math.cos(expected), atol=2e-3)  # fmt: skip


def test_hoisting_follows_the_profile_and_lowering_damps_the_swing():
    """Lowering 5 -> 15 m at 0.5 m/s: the rope length follows the trapezoid exactly, tension at rest = g - l'', and
    the swing amplitude falls as the adiabatic invariant of a lengthening pendulum predicts (θ ∝ l^-3/4, 10 %)."""
    from devices.hook_physics import Hoist, rope_length

    settings = HookPhysicsSettings(rope_length_m=5.0, lever_arm_m=(0.0, 0.0, 0.0), internal_rate_hz=500.0)
    hoist = Hoist(5.0, 22.0, 0.5, ramp_s=2.0)  # trapezoid area (22 - 2) s × 0.5 m/s = 10 m
    l_ref, _, l_acc = rope_length(5.0, (hoist,), np.array([4.0, 27.0, 40.0]))
    assert l_ref[0] == pytest.approx(5.0) and l_ref[1] == pytest.approx(15.0) and l_acc[2] == 0.0
    still = simulate(settings, HookScenario(duration_s=8.0, hoists=(hoist,)))
    ramp = (still.t_s > 5.2) & (still.t_s < 6.8)
    np.testing.assert_allclose(still.tension_per_mass_m_s2[ramp], settings.gravity_m_s2 - 0.25, atol=1e-9)
    swing = simulate(settings, HookScenario(duration_s=60.0, initial_swing_rad=math.radians(4.0), hoists=(hoist,)))
    np.testing.assert_allclose(swing.extra["rope_length_m"][-1], 15.0, atol=1e-9)
    before = swing.swing_rad[swing.t_s < 5.0].max()
    after = swing.swing_rad[swing.t_s > 40.0].max()
    assert after / before == pytest.approx((15.0 / 5.0) ** -0.75, rel=0.1)


def test_slewing_turns_the_boom_tip_by_the_angle_and_ends_at_rest():
    """A 60° slew at 30 m: the tip travels the chord between the two ends of the arc and stops."""
    from devices.hook_physics import SlewMove

    settings = HookPhysicsSettings(rope_length_m=5.0, internal_rate_hz=500.0)
    move = SlewMove(1.0, 20.0, math.radians(60.0), 30.0, 0.0, ramp_s=5.0)
    truth = simulate(settings, HookScenario(duration_s=25.0, slews=(move,)))
    end = truth.suspension_pos_m[-1, :2]
    np.testing.assert_allclose(end, [30.0 * (math.cos(math.radians(60.0)) - 1.0), 30.0 * math.sin(math.radians(60.0))],
                               atol=0.02)  # fmt: skip
    np.testing.assert_allclose(truth.suspension_vel_m_s[-1, :2], 0.0, atol=1e-3)
