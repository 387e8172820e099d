"""Pendulum-aware hook filter: per-sample path == batch path, rest behaviour, swing accuracy vs VQF, measured forces
(tag lines), rope length from the pendulum frequency and through hoisting.

Data: devices.hook_physics truth through devices.common.SensorModel (MPU-6050 + HMC5883L error model), seeded.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from devices.common import EARTH_FIELD_ENU_UT, G_M_S2, ImuErrorModel, SensorModel
from devices.hook_physics import HookPhysicsSettings, HookScenario, SlewMove, TrolleyMove, simulate
from gateway.fusion import hook
from gateway.fusion.hook_filter import (
    BIAS_ROUND,
    FIELD_START,
    FOURTH_ROUND,
    HOIST_ROUND,
    IRON_PRIOR_ROUND,
    JUMP_ROPE_ROUND,
    MAG_NOISE_ROUND,
    N_STATE,
    PREVIOUS_DEFAULT,
    PRIOR_ROUND,
    REST_PRIOR_ROUND,
    REST_ROUND,
    ROPE_ROUND,
    SLEW_ROUND,
    START_ROUND,
    TILT_GAIN_ROUND,
    TIP_ROUND,
    TRACKING,
    TRIAL_JUMP,
    WARMUP_ROUND,
    WINDY_START,
    HookFilter,
    HookFilterSettings,
    attitude_and_rate,
)

RATE_HZ = 100.0
DT_S = 1.0 / RATE_HZ
REST_S = 2.0


def swing_data(seed: int, duration_s: float, kick_m_s2: float, rope_length_m: float = 10.0):
    """Hook hanging still for REST_S, then a 2 s trolley jerk (+a, then -a) sets it swinging freely (about 5° per
    m/s² at l = 10 m), with random twist; returns truth and noisy (gyr, acc, mag)."""
    settings = HookPhysicsSettings(
        rope_length_m=rope_length_m, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT, internal_rate_hz=500.0
    )
    ax, ay = kick_m_s2 * math.cos(0.7), kick_m_s2 * math.sin(0.7)
    kick = (TrolleyMove(REST_S, 1.0, (ax, ay)), TrolleyMove(REST_S + 1.0, 1.0, (-ax, -ay)))
    scenario = HookScenario(
        duration_s=duration_s, output_rate_hz=RATE_HZ, trolley_moves=kick, wind_torque_std_n_m=2.0, seed=seed
    )
    truth = simulate(settings, scenario)
    sensor = SensorModel(ImuErrorModel(), 1, np.random.default_rng(seed))
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    return truth, gyr, acc, mag


def started_filter(gyr, acc, mag, rope_length_m=10.0, use_mag=False):
    """Started on a 0.5 s rest window as the gateway starts it, but without seeding the gyro bias from it."""
    f = HookFilter(HookFilterSettings(rope_length_m=rope_length_m, rope_length_known=True), use_mag=use_mag)
    rest = slice(0, int(0.5 * RATE_HZ))
    f.start(gyr[rest], acc[rest], mag[rest] if use_mag else None, DT_S, seed_bias=False)
    return f


@pytest.mark.parametrize("use_mag", [False, True])
def test_per_sample_update_and_batch_run_agree(use_mag):
    """`update()` sample by sample and `run()` over uneven batches give the same estimates (the gyro difference
    that feeds the lever-arm terms carries across calls)."""
    truth, gyr, acc, mag = swing_data(seed=3, duration_s=4.0, kick_m_s2=1.5)
    one, two = started_filter(gyr, acc, mag, use_mag=use_mag), started_filter(gyr, acc, mag, use_mag=use_mag)
    m = mag if use_mag else None
    q_single = np.array([one.update(gyr[i], acc[i], None if m is None else m[i], DT_S) for i in range(len(gyr))])
    cuts = [0, 7, 150, 151, len(gyr)]
    q_batch = np.concatenate([two.run(gyr[a:b], acc[a:b], None if m is None else m[a:b], DT_S)
                              for a, b in zip(cuts[:-1], cuts[1:], strict=True)])  # fmt: skip
    np.testing.assert_allclose(q_single, q_batch, atol=1e-9)
    np.testing.assert_allclose(one.P, two.P, atol=1e-9)


def test_hanging_still_reads_plumb_and_learns_the_gyro_bias():
    """Hanging still for 10 s: Θ stays below 0.5° (the filter starts not knowing the ~1 °/s gyro bias) and the
    x/y bias is learned to 0.02 °/s."""
    truth, gyr, acc, mag = swing_data(seed=5, duration_s=10.0, kick_m_s2=0.0)
    f = started_filter(gyr, acc, mag)
    q = f.run(gyr, acc, None, DT_S)
    assert float(np.degrees(np.max(hook.swing_angle(q)))) < 0.5
    true_bias = np.mean(gyr - truth.gyr_rad_s, axis=0)
    np.testing.assert_allclose(f.gyro_bias_rad_s[:2], true_bias[:2], atol=math.radians(0.02))
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)


def rmse_deg(err_rad):
    return float(np.degrees(np.sqrt(np.mean(np.square(err_rad)))))


@pytest.mark.parametrize("seed", [11, 12])
def test_free_swing_angle_accuracy_beats_vqf(seed):
    """Free swing of about 8° after a violent 1.6 m/s² trolley kick (legacy sensor model, 20 mg accel bias), scored
    from 12 s after it: swing-angle RMSE ≤ 0.2° and below VQF on the same data through the same hook.swing_angle.
    Measured 0.10° and 0.15° (VQF about 0.75°; 0.05° and 0.11° with `PREVIOUS_DEFAULT`: the tip tracking keeps the
    tip state looser for a while after a kick 3× the suite's largest move): the jump test sees the kick start and
    stop and puts it in the boom-tip state. Without it (the filter before) 0.61° and 0.53°: the kick, an unmeasured
    boom-tip acceleration, threw the rope-length, boom-tip and bias states off for tens of seconds.
    """
    vqf = pytest.importorskip("vqf")
    truth, gyr, acc, mag = swing_data(seed=seed, duration_s=30.0, kick_m_s2=1.6)
    assert math.radians(6.0) < truth.swing_rad.max() < math.radians(12.0)
    q = started_filter(gyr, acc, mag).run(gyr, acc, None, DT_S)
    q_vqf = vqf.offlineVQF(np.ascontiguousarray(gyr), np.ascontiguousarray(acc), None, DT_S)["quat6D"]
    scored = truth.t_s > REST_S + 14.0
    err = (hook.swing_angle(q) - truth.swing_rad)[scored]
    err_vqf = (hook.swing_angle(q_vqf) - truth.swing_rad)[scored]
    assert rmse_deg(err) <= 0.2
    assert rmse_deg(err_vqf) > rmse_deg(err)


def test_a_wrong_configured_rope_length_is_corrected_by_the_swing_frequency():
    """A 6 m rope swinging 5° when the filter starts (calibrated MPU-6050): told 12 m as a configured (tight) prior,
    the filter still finds the length from the pendulum frequency, within 7 % from 20 s on (measured 4.5 %), Θ RMSE
    ≤ 0.2° from 30 s (measured 0.18°; from 20 s 0.39°: the jump test at 13.8 and the tip tracking let the tip state
    take the length error for longer; the filter before the third round 0.10° / 0.13°, and on draws 22 and 23 both
    are above 0.25° from 30 s); told nothing (wide 10 m prior) within 3 % and ≤ 0.1° from 20 s (measured 1 %,
    0.04°)."""
    physics = HookPhysicsSettings(rope_length_m=6.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  internal_rate_hz=500.0)  # fmt: skip
    scenario = HookScenario(duration_s=40.0, initial_swing_rad=math.radians(5.0), initial_swing_bearing_rad=0.7,
                            wind_torque_std_n_m=2.0, seed=21)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(21)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    scored = truth.t_s > 20.0
    for settings_, rel_tol, rmse_tol, from_s in (
            (HookFilterSettings(rope_length_m=12.0, rope_length_known=True), 0.07, 0.2, 30.0),
            (HookFilterSettings(), 0.03, 0.1, 20.0)):  # fmt: skip
        f = HookFilter(settings_, use_mag=False)
        f.start(gyr[:50], acc[:50], None, DT_S)
        q, length = f.run_with_length(gyr, acc, None, DT_S)
        assert np.all(np.abs(length[scored] / 6.0 - 1.0) < rel_tol), (settings_.rope_length_m, length[scored].min())
        assert rmse_deg((hook.swing_angle(q) - truth.swing_rad)[truth.t_s > from_s]) <= rmse_tol


def test_rope_length_follows_hoisting():
    """Lowering 6 m -> 14 m at 0.5 m/s while swinging: the estimate follows within 10 % during the move and within
    8 % from 10 s after it (the tension channel sees the hoist's acceleration, the frequency the length; measured
    2.4 % and 2.2 %, Θ 0.03°; before the hoist round, `ROPE_ROUND`, 7.8 % and 6.6 %, Θ 0.12°: the length crept 5 %
    long in the free swing after it; 8.5 % and 4.1 % before the jump test and the stiffer swing-rate model, which left
    Θ at 0.23°), Θ RMSE ≤ 0.3° there."""
    from devices.hook_physics import Hoist

    physics = HookPhysicsSettings(rope_length_m=6.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  internal_rate_hz=500.0)  # fmt: skip
    scenario = HookScenario(duration_s=60.0, initial_swing_rad=math.radians(4.0), wind_torque_std_n_m=2.0,
                            hoists=(Hoist(10.0, 17.0, 0.5),), seed=7)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel(), 1, np.random.default_rng(7)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    f = HookFilter(HookFilterSettings(rope_length_m=6.0, rope_length_known=True), use_mag=False)
    f.start(gyr[:50], acc[:50], None, DT_S)
    q, length = f.run_with_length(gyr, acc, None, DT_S)
    true_l = truth.extra["rope_length_m"]
    assert true_l[-1] == pytest.approx(14.0, abs=0.01)
    rel = np.abs(length - true_l) / true_l
    during = (truth.t_s > 10.0) & (truth.t_s < 27.0)
    assert rel[during].max() < 0.10
    assert rel[truth.t_s > 37.0].max() < 0.08
    assert rmse_deg((hook.swing_angle(q) - truth.swing_rad)[truth.t_s > 37.0]) <= 0.3


def test_the_rope_length_of_a_still_hook_does_not_drift_through_hoisting():
    """A 10 m rope hanging still (no swing, no wind force, the hook twisting in torque gusts; calibrated MPU-6050)
    hoisted 4.8 m up at 0.4 m/s from 10 s and lowered back from 50 s: nothing tells the length but the hoist's
    acceleration in the tension channel. Before the hoist the estimate stays within 2 % (measured 0.25 %; the filter
    that corrected the length from the swing rate at any amplitude, `rope_observe_swing_rad=0`, 5 %), within 15 % of
    the truth throughout (measured 6.5 %; before the hoist round, `ROPE_ROUND`, 87 %: the tension offset took part of
    each ramp; before the rope round 8.1x), and within 5 % over the last 20 s (measured 1.7 %; `ROPE_ROUND` 22 %;
    before the rope round: 80 m for 10 m)."""
    from devices.hook_physics import Hoist

    physics = HookPhysicsSettings(rope_length_m=10.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT)
    scenario = HookScenario(duration_s=100.0, hoists=(Hoist(10.0, 15.0, -0.4, 3.0), Hoist(50.0, 15.0, 0.4, 3.0)),
                            wind_torque_std_n_m=2.0, seed=3)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(3)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    assert np.degrees(truth.swing_rad.max()) < 0.01
    f = HookFilter(HookFilterSettings(rope_length_m=10.0, rope_length_known=True), use_mag=False)
    f.start(gyr[:50], acc[:50], None, DT_S)
    _, length = f.run_with_length(gyr, acc, None, DT_S)
    rel = length / truth.extra["rope_length_m"] - 1.0
    assert np.abs(rel[truth.t_s < 10.0]).max() < 0.02
    assert np.abs(rel).max() < 0.15
    assert np.abs(rel[truth.t_s > 80.0]).max() < 0.05


def test_a_hoisted_hook_that_hardly_swings_has_its_length_followed():
    """A 9 m rope on a 2 t hook swinging 0.5° (calibrated MPU-6050), hoisted at 0.8 m/s to 3.4 m from 10 s (3 s ramps)
    and lowered at 0.5 m/s to 9.4 m from 45 s, the swing growing to 1° as the rope shortens: what follows the length
    is the hoist's ramps in the tension channel, the swing being too small to time. During, between and after the
    hoists the estimate stays within 12 % of the truth (measured 7.6 %), its RMS within 4 % (1.8 %). Before the hoist
    round (`ROPE_ROUND`) 51 % and 16 %: the hoist acceleration's model (0.05 m/s² over 1 s) called a 0.27 m/s² ramp a
    5σ event, the tension offset took part of each ramp and the rope speed followed the offset's correlation with it
    the wrong way (the length rose at the start of a hoist up); the ramp test opens the hoist acceleration and keeps the
    offset out of it (a ramp's first samples run again), and the rope speed runs on between the ramps. Θ RMSE within
    0.15° (measured 0.090°; `ROPE_ROUND` 0.108°)."""
    from devices.hook_physics import Hoist

    physics = HookPhysicsSettings(rope_length_m=9.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  hook_mass_kg=2000.0)  # fmt: skip
    scenario = HookScenario(duration_s=80.0, initial_swing_rad=math.radians(0.5), initial_swing_bearing_rad=0.4,
                            hoists=(Hoist(10.0, 10.0, -0.8, 3.0), Hoist(45.0, 15.0, 0.5, 3.0)), wind_torque_std_n_m=2.0,
                            seed=11)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(11)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    true_l = truth.extra["rope_length_m"]
    assert true_l.min() == pytest.approx(3.4, abs=0.01) and true_l[-1] == pytest.approx(9.4, abs=0.01)
    assert np.degrees(truth.swing_rad.max()) < 1.2
    f = HookFilter(HookFilterSettings(rope_length_m=9.0, rope_length_known=True), use_mag=False)
    f.start(gyr[:50], acc[:50], None, DT_S)
    q, length = f.run_with_length(gyr, acc, None, DT_S)
    rel = length / true_l - 1.0
    assert np.abs(rel).max() < 0.12
    assert np.sqrt(np.mean(rel**2)) < 0.04
    assert rmse_deg((hook.swing_angle(q) - truth.swing_rad)[truth.t_s > 0.5]) <= 0.15


@settings(max_examples=15, deadline=None)
@given(
    arrays(np.float64, (200, 3), elements=st.floats(-0.5, 0.5)),
    arrays(np.float64, (200, 3), elements=st.floats(-3.0, 3.0)),
)
def test_any_input_gives_unit_quaternions_and_a_rope_below_horizontal(gyr_noise, acc_noise):
    """Arbitrary (even non-physical) rates and forces never break the state: unit q, Θ < 90°."""
    acc = np.array([0.0, 0.0, G_M_S2]) + acc_noise
    f = HookFilter(use_mag=False)
    f.initialise(np.array([0.0, 0.0, G_M_S2]), None)
    q = f.run(gyr_noise, acc, None, DT_S)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    assert np.all(hook.swing_angle(q) < math.pi / 2)


def test_seeded_bias_is_used():
    truth, gyr, acc, mag = swing_data(seed=5, duration_s=1.0, kick_m_s2=0.0)
    f = started_filter(gyr, acc, mag)
    f.seed_gyro_bias(gyr[:50].mean(axis=0))
    np.testing.assert_allclose(f.gyro_bias_rad_s, gyr[:50].mean(axis=0))
    q = f.run(gyr, acc, None, DT_S)
    assert float(np.degrees(np.max(hook.swing_angle(q)))) < 0.5


def test_a_tag_line_pull_is_measured_not_guessed():
    """A 300 N pull on a 500 kg hook for 3 s (0.6 m/s², 3.5° of equilibrium shift) and let go: with the
    accelerometer's x/y as the force input, Θ stays within 0.3° of the truth through the pull and after it (measured
    0.19°, 0.20° before the thirteenth round; 0.17° before the hoist round, `ROPE_ROUND`); without it, on the boom-tip
    settings before the third round and the thirteenth (`SLEW_ROUND`: its rope length held while the jump test's
    statistic is high keeps the unmeasured pull out of the length, 0.24°) and the rope settings before the hoist
    round, the error is at least 3× larger (0.77°). (Without it on today's defaults 0.24°: the jump test and the tip
    tracking read the pull as a boom-tip move, and the length, gated at a 0.2° swing, does not take the unmeasured
    pull for a longer rope; 0.40° with the 0.1° gate before the hoist round.)"""
    from devices.hook_physics import Pull

    physics = HookPhysicsSettings(gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT, internal_rate_hz=500.0,
                                  hook_mass_kg=500.0)  # fmt: skip
    scenario = HookScenario(duration_s=30.0, pulls=(Pull(5.0, 3.0, (300.0 * math.cos(0.4), 300.0 * math.sin(0.4))),),
                            wind_torque_std_n_m=2.0, seed=31)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(31)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    assert truth.swing_rad.max() > math.radians(3.0)
    errors = []
    for over in ({}, PREVIOUS_DEFAULT | ROPE_ROUND | HOIST_ROUND | SLEW_ROUND | {"use_force_input": False}):
        f = HookFilter(HookFilterSettings(**over), use_mag=False)
        f.start(gyr[:50], acc[:50], None, DT_S)
        q = f.run(gyr, acc, None, DT_S)
        errors.append(np.abs(np.degrees(hook.swing_angle(q) - truth.swing_rad))[truth.t_s > 1.0])
    assert errors[0].max() < 0.3, errors[0].max()
    assert errors[1].max() > 3.0 * errors[0].max()


def test_a_suite_crane_twisting_at_start_keeps_its_heading_from_the_magnetometer():
    """bench.hook_suite's tuning seed 5 (17.7 m rope, already swinging and twisting when the gateway starts,
    calibrated 9D board), first 40 s: with the magnetometer weighted at 30 µT (set for uncalibrated hard iron) the
    torsion ran away (78.8° RMSE; 92° over the suite's 180 s); at 3 µT 9.9°, most of it while the heading
    converges in the first 15 s (4.8° over 180 s: the calibrated board's hard iron and misalignment)."""
    from dataclasses import replace

    from bench.hook_suite import hook_estimate, make_case

    case = make_case(5, 180.0)  # the suite's timeline (wind is drawn after it), cut to its first 40 s
    truth = simulate(case.physics, replace(case.scenario, duration_s=40.0))
    sensor = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(10_005))
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    q, _ = hook_estimate(gyr, acc, mag, case.physics.rope_length_m)
    err = np.angle(np.exp(1j * (hook.torsion(q, 0.0) - truth.torsion_rad)))[truth.t_s >= 0.5]
    assert rmse_deg(err) < 20.0, rmse_deg(err)  # measured 9.9° (mostly its first 15 s); 78.8° at 30 µT


def test_a_slow_swing_at_start_is_not_taken_for_rest():
    """A 7° swing on a 20 m rope when the gateway starts: over the 0.5 s warm-up its gyro looks almost quiet, so it
    was taken for rest (the swing rate seeded as gyro bias, the rope at plumb) and the first second read 4.4° off
    (bench.hook_suite seed 108; 1.3° here). The warm-up's rate slope gives the swing by the pendulum law."""
    settings = HookPhysicsSettings(rope_length_m=20.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT)
    scenario = HookScenario(duration_s=5.0, output_rate_hz=RATE_HZ, initial_swing_rad=math.radians(7.0),
                            initial_swing_bearing_rad=0.8, seed=2)  # fmt: skip
    truth = simulate(settings, scenario)
    sensor = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(2))
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    f = HookFilter(HookFilterSettings(rope_length_m=20.0, rope_length_known=True), use_mag=True)
    n = int(0.5 * RATE_HZ)
    f.start(gyr[:n], acc[:n], mag[:n], DT_S)
    q = f.run(gyr, acc, mag, DT_S)
    err = np.degrees(np.abs(hook.swing_angle(q) - truth.swing_rad))[n:]
    assert float(err.max()) < 0.8, float(err.max())  # measured 0.40°; 1.29° taken for rest


@pytest.mark.parametrize("seed", [3, 6])
def test_a_hook_swinging_at_start_levels_its_magnetometer_reference(seed):
    """A 5° swing on a 16 m rope, twisting at 0.1 rad/s, when the gateway starts (calibrated 9D board, gyro biases
    of 2-3 °/s): the warm-up's body-frame mean field carries the tilted vertical field (4 µT), so the start heading
    and the reference were off, and the z gyro bias and hard iron took the difference. Turned to ENU by the start
    swing and twist, the reference is the earth field's, and the start swing is read with that heading. Max Θ error
    over the first 10 s, measured 0.58° / 0.41° (seeds 3 / 6); the body-frame mean (`FOURTH_ROUND`) 3.59° / 1.30°
    (both with the x/y bias left at 0, the default; with the bias from the field's turn, `FIELD_START`, 0.57° /
    0.41°; with a calibrated board's 0.5-µT hard-iron prior, before 2026-12-06's twenty-eighth session, 0.65° / 0.48°,
    1.44° / 1.28° and 0.57° / 0.37°)."""
    physics = HookPhysicsSettings(rope_length_m=16.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT)
    scenario = HookScenario(duration_s=10.0, output_rate_hz=RATE_HZ, initial_swing_rad=math.radians(5.0),
                            initial_swing_bearing_rad=1.2, initial_torsion_rad=0.5, initial_torsion_rate_rad_s=0.1,
                            seed=seed)  # fmt: skip
    truth = simulate(physics, scenario)
    sensor = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(seed))
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    n = int(0.5 * RATE_HZ)
    worst, refs, start = [], [], []
    for over in ({}, FOURTH_ROUND, FIELD_START):
        f = HookFilter(HookFilterSettings(rope_length_m=16.0, rope_length_known=True, **over), use_mag=True)
        f.start(gyr[:n], acc[:n], mag[:n], DT_S)
        assert f.mag_ref_uT is not None
        refs.append(float(np.linalg.norm(f.mag_ref_uT - np.asarray(EARTH_FIELD_ENU_UT))))
        start.append(float(np.degrees(np.hypot(*(f.x[:2] - truth.rope_dir[0, :2])))))
        q = f.run(gyr, acc, mag, DT_S)
        worst.append(float(np.degrees(np.abs(hook.swing_angle(q) - truth.swing_rad))[n:].max()))
    assert worst[0] < 0.8 < worst[1], worst
    assert worst[2] < worst[0] + 0.02, worst  # the field's bias: no worse (level on seed 6 with the 3-µT prior)
    assert refs[0] < 1.0 < refs[1], refs  # µT from the earth field: measured 0.40 / 0.13, body-frame mean 3.9 / 3.6
    # the start swing read with the levelled heading, closer than with the body-frame mean's (its std is 1.55°, so
    # only within 1°): 0.67° / 0.93°, body-frame mean 0.72° / 1.62° (0.57° / 0.60° and 0.84° / 1.23° before the start
    # swing followed the twist over the warm-up and was carried back to second order)
    assert start[0] < min(1.0, start[1]), start


def slew_data(seed: int):
    """An 8 m rope hanging still, then a 30 s slew of 88° at 40 m radius (0.35 m/s² tangential for 8 s at each
    end, 0.2 m/s² centripetal at the cruise rate: the rope leans 1.1° out for 14 s), then 20 s of free swing."""
    physics = HookPhysicsSettings(rope_length_m=8.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  internal_rate_hz=500.0)  # fmt: skip
    slew = SlewMove(5.0, 30.0, 0.07 * 22.0, radius_m=40.0, mast_bearing_rad=0.3, ramp_s=8.0)
    truth = simulate(physics, HookScenario(duration_s=55.0, slews=(slew,), wind_torque_std_n_m=2.0, seed=seed))
    gyr, acc, mag = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(seed)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    return truth, gyr, acc, mag


# This filter's boom-tip settings before the jump test: a tight tip state decaying in 5 s and a large white part.
OLD_TIP = PREVIOUS_DEFAULT | {"move_mean_gate": 0.0, "tip_accel_tau_s": 5.0, "tip_accel_psd": 1e-3}


# The boom-tip tracking of issue 11's second round (on the defaults before the third), and it with one part off.
NO_TRACK = TRACKING | {"move_track_s": 0.0}
NO_TURN = TRACKING | {"tip_turn_psd": 0.0}


def test_a_slewing_move_is_followed_not_averaged_away():
    """Through a slewing move and 20 s after it, the filter before the third round (`PREVIOUS_DEFAULT`): Θ RMSE ≤ 0.5°
    and max ≤ 1.7° (measured 0.43° / 1.48°, most of it while the tangential acceleration turns into the centripetal
    one, too slowly to trip the jump test); the jump test sees the boom tip's acceleration start, settle and stop and
    opens the tip state each time. With the second round's tracking (`TRACKING`: for 10 s after a jump the tip state
    keeps tracking while its estimate is not near 0, and takes noise across its own direction, so the tangential
    part can turn into the centripetal one) 0.31° / 0.82°; without its tracking part 0.49° / 1.23°, without its
    noise across 0.39° / 0.92°. With the boom-tip settings before the jump test (tight, never opened: the
    squared-innovation test stayed below its gate) 0.80° / 2.36°. The default filter (the tracking, a slow gyro
    bias, jump gate 13.8) ≤ 0.35° / 1.0° (measured 0.31° / 0.86°). These on the rope settings before the hoist round
    (`ROPE_ROUND`, measured again: `TRACKING` 0.31° / 0.82°, without its tracking 0.49° / 1.23°, without its noise
    across 0.39° / 0.91°, `PREVIOUS_DEFAULT` 0.43° / 1.49°, the old tip 0.80° / 2.36°; since the tenth round with
    `HOIST_ROUND` too, the same figures; since the bias-jump test with `BIAS_ROUND` too, which alone takes the
    variant without the noise across to 0.33°). The hoist round's default 0.36° / 0.89° (0.31° / 0.83° with
    `ROPE_ROUND`): it holds the hoist acceleration at 0.015 m/s² between ramps (0.05 before), so the tension
    channel's errors through a slew (it lacks the boom tip's acceleration along the rope) go into the swing instead
    (0.30° / 0.74° with the hoist test off). The tenth round's default (tighter tip state, slower tracking) 0.33° /
    0.81° (0.29° / 0.73° with the tracking at 1e-3; `HOIST_ROUND` 0.36° / 0.89°), the eleventh's the same. Today's
    default (the thirteenth round's tracking held while the tip estimate is long, and the length held while the jump
    test's statistic is high) ≤ 0.3° / 0.7° (measured 0.27° / 0.63°); the older filters above are compared without
    it (`SLEW_ROUND`)."""
    truth, gyr, acc, mag = slew_data(seed=41)
    assert truth.swing_rad.max() > math.radians(2.0)
    errors = []
    for over in (TRACKING, NO_TRACK, NO_TURN, PREVIOUS_DEFAULT, OLD_TIP, {}):
        over = over | ROPE_ROUND | HOIST_ROUND | SLEW_ROUND | BIAS_ROUND if over else over
        f = HookFilter(HookFilterSettings(rope_length_m=8.0, rope_length_known=True, **over), use_mag=False)
        f.start(gyr[:50], acc[:50], None, DT_S)
        q = f.run(gyr, acc, None, DT_S)
        errors.append(np.abs(np.degrees(hook.swing_angle(q) - truth.swing_rad))[truth.t_s > 0.5])
    rmse = [float(np.sqrt(np.mean(e**2))) for e in errors]
    worst = [float(e.max()) for e in errors]
    assert rmse[0] <= 0.35 and worst[0] <= 1.0, (rmse[0], worst[0])
    assert rmse[1] > 1.3 * rmse[0] and rmse[2] > 1.15 * rmse[0], rmse
    assert rmse[3] <= 0.5 and worst[3] <= 1.7, (rmse[3], worst[3])
    assert rmse[3] > 1.3 * rmse[0] and worst[3] > 1.5 * worst[0], (rmse, worst)
    assert rmse[4] > 1.5 * rmse[3] and worst[4] > 1.4 * worst[3], (rmse, worst)
    assert rmse[5] <= 0.3 and worst[5] <= 0.7, (rmse[5], worst[5])


def first_detection_s(bias: float, seed: int, duration_s: float) -> tuple[float, float]:
    """Seconds until the jump test and the slow test first fire on whitened swing-rate innovations (unit white noise
    plus `bias` on one axis, as a boom-tip acceleration the model lacks leaves); `inf` if never."""
    from gateway.fusion.hook_filter import N_MONITOR, _mean_test

    s = HookFilterSettings()
    monitor = np.zeros(N_MONITOR)
    first = [math.inf, math.inf]
    noise = np.random.default_rng(seed).standard_normal((int(duration_s * RATE_HZ), 2))
    for i, w in enumerate(noise + np.array([bias, 0.0])):
        for k, (tau, gate, at) in enumerate(((s.move_mean_tau_s, TRACKING["move_mean_gate"], 2),
                                             (s.slow_mean_tau_s, TRACKING["slow_mean_gate"], 6))):  # fmt: skip
            if _mean_test(w[0], w[1], tau, gate, DT_S, monitor, at) and first[k] == math.inf:
                first[k] = i * DT_S
    return first[0], first[1]


def test_a_small_steady_innovation_bias_is_seen_by_the_slow_test_first():
    """A steady bias of 0.15 σ on the whitened swing-rate innovation (a boom-tip acceleration turning too slowly to
    trip the jump test): the optional slow test (`TRACKING`: 3 s mean, gate 20) fires after a median of under 12 s
    over 20 noise draws (measured 7.8 s), `TRACKING`'s 0.5 s jump test (gate 20) after more than 15 s (measured
    25 s). Without a bias neither fires in 60 s on at least 18 of 20 draws (false alarms)."""
    biased = np.array([first_detection_s(0.15, seed, 40.0) for seed in range(20)])
    fast, slow = np.median(np.minimum(biased, 40.0), axis=0)
    assert slow < 12.0 and fast > 15.0, (fast, slow)
    quiet = [first_detection_s(0.0, seed, 60.0) for seed in range(20)]
    assert sum(math.isinf(a) and math.isinf(b) for a, b in quiet) >= 18, quiet


def test_hard_iron_is_learnt_as_the_hook_twists():
    """A calibrated 9D board with 1.5 µT of hard iron left on x (4° of heading on a 20 µT horizontal field) on a hook
    twisting ±60°: from 20 s on the torsion RMSE is below 1° (measured 0.54°); without the hard-iron states it is
    the hard iron's heading error (measured 4.3°)."""
    physics = HookPhysicsSettings(gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT, internal_rate_hz=500.0)
    scenario = HookScenario(duration_s=50.0, initial_torsion_rad=math.radians(60.0), wind_torque_std_n_m=2.0, seed=43)
    truth = simulate(physics, scenario)
    sensor = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(43))
    sensor.mag_hard_iron_uT = np.array([[1.5, 0.0, 0.0]])
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    rmse = []
    for std in (0.5, 0.0):
        f = HookFilter(HookFilterSettings(mag_hard_iron_std_uT=std), use_mag=True)
        f.start(gyr[:50], acc[:50], mag[:50], DT_S)
        q = f.run(gyr, acc, mag, DT_S)
        err = np.angle(np.exp(1j * (hook.torsion(q, 0.0) - truth.torsion_rad)))[truth.t_s > 20.0]
        rmse.append(rmse_deg(err))
    assert rmse[0] < 1.0, rmse
    assert rmse[1] > 2.0 * rmse[0], rmse


def test_a_board_nobody_calibrated_has_its_hard_iron_learnt_with_the_wider_prior():
    """Suite crane 26 on the MPU-6050/HMC5883L-class board (5 µT of hard iron per axis), 120 s told: with the
    default prior the hard iron is learnt as the hook twists (torsion RMSE measured 1.32°; 2.49° with the 3-µT prior
    and 3-µT compass noise of 2026-12-06's twenty-eighth session, `MAG_NOISE_ROUND`); held near 0 by a calibrated
    board's 0.5 µT with that noise (`IRON_PRIOR_ROUND`) it stays a heading error (9.98°). Crane 23 on a raw board
    (15 µT), its first 30 s: the 0.5-µT prior let the compass mislead the swing (Θ RMSE 1.32°, max 3.0°; 2.06° /
    5.9° when written; 0.85° with the compass's gain on the swing at 0.3, so the filter before is taken with its full
    gain, `TILT_GAIN_ROUND`, and 1.00° with a jump opening the told length by 3 %, so with `JUMP_ROPE_ROUND` too);
    the default 0.18° (3 µT then: 0.19°)."""
    from bench.hook_suite import hook_estimate, score, simulate_seed

    for seed, imu, duration_s in ((26, "legacy", 120.0), (23, "uncalibrated", 30.0)):
        case, truth, gyr, acc, mag = simulate_seed(seed, duration_s, imu, True)
        keep = truth.t_s > 0.5
        before_over = {**MAG_NOISE_ROUND, **IRON_PRIOR_ROUND, **TILT_GAIN_ROUND, **JUMP_ROPE_ROUND}
        figures = [score(hook_estimate(gyr, acc, mag, case.physics.rope_length_m, overrides=over)[0], truth, keep,
                         True) for over in ({}, before_over)]  # fmt: skip
        if imu == "legacy":
            now, before = (f["torsion_rmse"] for f in figures)
            assert now < 3.0 and before > 2.5 * now, (now, before)
        else:
            now, before = (f["swing_rmse"] for f in figures)
            assert now < 0.3 and before > 1.0, (now, before)


def test_the_windy_suite_family_is_light_short_and_windy_from_the_start():
    """`bench.hook_suite.make_case(seed, family="windy")`: 0.5-1.5 t on 2-6 m in a 30-60 N steady wind (the character
    of held-out seed 309), the same kinds of events as the default family's seed; an unknown family is refused."""
    from bench.hook_suite import make_case

    for seed in range(1, 21):
        windy, crane = make_case(seed, 120.0, "windy"), make_case(seed, 120.0)
        steady_n = math.hypot(*windy.scenario.wind_mean_m_s2) * windy.physics.hook_mass_kg
        assert 2.0 <= windy.physics.rope_length_m <= 6.0 and 500.0 <= windy.physics.hook_mass_kg <= 1500.0
        assert 30.0 <= steady_n <= 60.0, steady_n
        assert windy.events[0][0] == crane.events[0][0]
    with pytest.raises(ValueError, match="family"):
        make_case(1, 60.0, "gusty")


def steady_slew_data(seed: int):
    """An 8 m rope swinging 3° from the start, no twist (a body-fixed gyro bias cannot be told from the swing by
    turning), and a long slew from 40 s: 25 s ramps at 40 m, so its acceleration turns and grows for tens of seconds;
    calibrated MPU-6050, 6D. Returns truth, gyr, acc."""
    physics = HookPhysicsSettings(rope_length_m=8.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  internal_rate_hz=500.0)  # fmt: skip
    slew = SlewMove(40.0, 60.0, 0.05 * 35.0, radius_m=40.0, mast_bearing_rad=0.3, ramp_s=25.0)
    scenario = HookScenario(duration_s=110.0, slews=(slew,), initial_swing_rad=math.radians(3.0),
                            initial_swing_bearing_rad=1.0, seed=seed)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(seed)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    return truth, gyr, acc


def swing_rmse_from(truth, gyr, acc, rope_length_m: float, over: dict[str, float], from_s: float) -> float:
    f = HookFilter(HookFilterSettings(rope_length_m=rope_length_m, rope_length_known=True, **over), use_mag=False)
    f.start(gyr[:50], acc[:50], None, DT_S)
    q = f.run(gyr, acc, None, DT_S)
    return rmse_deg((hook.swing_angle(q) - truth.swing_rad)[truth.t_s > from_s])


def test_a_gyro_bias_that_drifts_like_the_sensor_keeps_a_slow_slew_out_of_it():
    """The default filter (third round) lets the gyro bias random-walk at the MPU-6050's 4e-10 (rad/s)²/s:
    through a slew whose acceleration changes over tens of seconds on a hook that does not twist, Θ RMSE from 20 s
    ≤ 0.23° on two draws (measured 0.203°, 0.200°); with the bias drifting 25x faster (1e-8, the default before) the
    bias took part of the slowly changing tip acceleration: more than 1.15x that on average (measured 0.248°,
    0.255°)."""
    steady, loose = [], []
    for seed in (41, 42):
        truth, gyr, acc = steady_slew_data(seed)
        steady.append(swing_rmse_from(truth, gyr, acc, 8.0, {}, 20.0))
        loose.append(swing_rmse_from(truth, gyr, acc, 8.0, {"gyro_bias_psd": 1e-8}, 20.0))
    assert max(steady) <= 0.23, steady
    assert np.mean(loose) > 1.15 * np.mean(steady), (steady, loose)


def test_the_jump_test_at_p_0001_sees_a_small_trolley_step_on_a_short_rope():
    """A 0.14 m/s² trolley acceleration for 8 s on a 5 m rope swinging 3° (0.8° of equilibrium tilt; the step the
    jump test missed on tuning seed 8's slew): with the jump gate at χ² p = 0.001 (13.8, the default) Θ
    RMSE from the move on, mean over four draws, is more than 1.2x lower than with the gate at 20 (measured 0.43° vs
    0.61° when written: the lower gate caught the step on two of the four draws, the other two were missed by both).
    On the filter before issue 11's eleventh round (`TIP_ROUND`, `SLEW_ROUND`), again: 0.119° vs 0.159°. With its
    re-run from the jump test's onset (the default) both gates read 0.117°: the step the gate at 20 sees late is run
    again from where the statistic first rose."""
    physics = HookPhysicsSettings(rope_length_m=5.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  internal_rate_hz=500.0)  # fmt: skip
    step = TrolleyMove(20.0, 8.0, (0.14 * math.cos(1.0), 0.14 * math.sin(1.0)))
    low, high = [], []
    for seed in (41, 42, 43, 44):
        scenario = HookScenario(duration_s=40.0, trolley_moves=(step,), initial_swing_rad=math.radians(3.0),
                                initial_swing_bearing_rad=1.0, wind_torque_std_n_m=2.0, seed=seed)  # fmt: skip
        truth = simulate(physics, scenario)
        gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(seed)).measure(
            truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
        low.append(swing_rmse_from(truth, gyr, acc, 5.0, TIP_ROUND | SLEW_ROUND, 19.5))
        high.append(swing_rmse_from(truth, gyr, acc, 5.0, TIP_ROUND | SLEW_ROUND | {"move_mean_gate": 20.0}, 19.5))
    assert np.mean(high) > 1.2 * np.mean(low), (low, high)
    assert np.mean(low) <= 0.5, low


def trolley_step_data(seed: int, rope_m: float, acc_m_s2: float, start_s: float, duration_s: float, run_s: float):
    """A `rope_m` rope swinging 2° (bearing 1 rad), a boom-tip acceleration of `acc_m_s2` along the same bearing
    from `start_s` for `duration_s`, `run_s` in all: truth, gyroscope and accelerometer samples (calibrated IMU)."""
    physics = HookPhysicsSettings(rope_length_m=rope_m, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT,
                                  internal_rate_hz=500.0)  # fmt: skip
    step = TrolleyMove(start_s, duration_s, (acc_m_s2 * math.cos(1.0), acc_m_s2 * math.sin(1.0)))
    scenario = HookScenario(duration_s=run_s, trolley_moves=(step,), initial_swing_rad=math.radians(2.0),
                            initial_swing_bearing_rad=1.0, wind_torque_std_n_m=2.0, seed=seed)  # fmt: skip
    truth = simulate(physics, scenario)
    gyr, acc, _ = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(seed)).measure(
        truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)  # fmt: skip
    return truth, gyr, acc


def small_step_data(seed: int):
    """An 8 m rope swinging 2°, then a 0.1 m/s² boom-tip step for 15 s from t = 20 s (0.6° of equilibrium tilt; the
    size of tuning seed 6's slew onset, which the jump test at 13.8 never saw)."""
    return trolley_step_data(seed, 8.0, 0.1, 20.0, 15.0, 40.0)


def small_step_rmses(*overrides: dict) -> list[list[float]]:
    """Θ RMSE from the small step on (`small_step_data`), per settings override, over the four draws 41-44."""
    out: list[list[float]] = [[] for _ in overrides]
    for seed in (41, 42, 43, 44):
        truth, gyr, acc = small_step_data(seed)
        for rmses, over in zip(out, overrides, strict=True):
            rmses.append(swing_rmse_from(truth, gyr, acc, 8.0, over, 19.5))
    return out


def test_a_trial_jump_sees_a_tip_step_below_the_jump_gate():
    """`TRIAL_JUMP`: below the jump gate the filter tries the jump (goes back 1 s, opens the tip state) and keeps it
    when the re-run's swing-rate innovations are likelier. On a 0.1 m/s² step on an 8 m rope, Θ RMSE from the step
    on, mean over four draws, is more than 2x lower than without trials (measured 0.18° vs 0.52°; 0.11-0.23° vs
    0.45-0.55° per draw). Measured on the boom-tip state of its round (`HOIST_ROUND`): with today's tighter tip
    state the jump test sees this step itself (`test_a_tight_tip_state_lets_the_jump_test_see_a_sub_gate_step`);
    both without the bias-jump test (`BIAS_ROUND`), which takes the round's own filter to 0.18° on this step."""
    on, off = small_step_rmses(HOIST_ROUND | BIAS_ROUND | TRIAL_JUMP, HOIST_ROUND | BIAS_ROUND)
    assert np.mean(off) > 2.0 * np.mean(on), (on, off)


def test_a_tight_tip_state_lets_the_jump_test_see_a_sub_gate_step():
    """Issue 11's tenth round: the boom-tip state's stationary std 0.03 m/s² (0.06 before, `HOIST_ROUND`). The looser
    state random-walked far enough to absorb a 0.1 m/s² step on an 8 m rope slowly, so the swing-rate innovation's
    mean stayed below the jump gate and the step's a/g was taken for tilt; with the tight one the innovation shows
    it. Θ RMSE from the step on, mean over four draws: ≤ 0.3° and less than half of `HOIST_ROUND`'s (measured
    0.19° vs 0.48°; 0.16-0.23° vs 0.43-0.54° per draw; since the eleventh round's onset re-run 0.15°)."""
    new, old = small_step_rmses({}, HOIST_ROUND)
    assert np.mean(new) <= 0.3, new
    assert np.mean(old) > 2.0 * np.mean(new), (new, old)


def test_a_late_jump_is_run_again_from_the_jump_tests_onset():
    """Issue 11's eleventh round (`jump_onset_gate`): a jump the test found seconds after its statistic first rose
    above χ² 4 is also run again from there (at most 4 s back) and that re-run kept when the swing rate is likelier
    along it. On a 0.1 m/s² step on an 8 m rope swinging 2°, Θ RMSE from the step on, mean over four draws: ≤ 0.18° and
    more than 1.2x lower than without it (`TIP_ROUND`; measured 0.146° vs 0.191°, 0.10-0.21° vs 0.16-0.23° per draw).
    The case of windy tuning seed 8, whose slew onset peaked the statistic at 7.7 and tripped it 3.2 s later."""
    new, old = small_step_rmses({}, TIP_ROUND)
    assert np.mean(new) <= 0.18, new
    assert np.mean(old) > 1.2 * np.mean(new), (new, old)


def test_an_onset_re_run_the_likelihood_rejects_changes_nothing():
    """With `jump_onset_lr` out of reach the onset's re-run is never kept: the estimates are `TIP_ROUND`'s to the
    last bit (the longer rollback ring changes nothing else)."""
    truth, gyr, acc = small_step_data(42)
    runs = []
    for over in (TIP_ROUND, {"jump_onset_lr": -1e9}):
        f = HookFilter(HookFilterSettings(rope_length_m=8.0, rope_length_known=True, **over), use_mag=False)
        f.start(gyr[:50], acc[:50], None, DT_S)
        runs.append(f.run(gyr, acc, None, DT_S))
    assert np.array_equal(runs[0], runs[1])


def test_a_trial_the_likelihood_rejects_changes_nothing():
    """With the likelihood ratio a trial must reach set out of reach, every trial is undone: the estimates are the
    ones without trials to the last bit (the kept state, covariance and gate statistics are restored)."""
    truth, gyr, acc = small_step_data(41)
    runs = []
    for over in ({}, TRIAL_JUMP | {"jump_trial_lr": 1e9}):
        f = HookFilter(HookFilterSettings(rope_length_m=8.0, rope_length_known=True, **over), use_mag=False)
        f.start(gyr[:50], acc[:50], None, DT_S)
        runs.append(f.run(gyr, acc, None, DT_S))
    assert np.array_equal(runs[0], runs[1])


def trolley_stop_data(seed: int):
    """A 3 m rope swinging 2°, a 0.25 m/s² trolley acceleration from 15 s for 6 s, then the tip at rest."""
    return trolley_step_data(seed, 3.0, 0.25, 15.0, 6.0, 35.0)


def test_a_stops_re_run_from_a_zero_tip_estimate_helps_after_a_trolley_stop():
    """`jump_stop_std_m_s2` (issue 11's ninth round, off by default): when the jump's re-run at a move's stop puts the
    tip estimate past zero (shorter than half the lagging one it started from), the samples are run again from a zero
    tip estimate. After a 0.25 m/s² trolley acceleration stops on a 3 m rope, Θ RMSE from 0.5 s after the stop, mean
    over four draws, is more than 5 % lower with it at 0.2 m/s² (measured 0.152° vs 0.165°: 0.170 vs 0.201° and
    0.180 vs 0.200° on two draws, the same on the other two), on the filter of its round (`ROPE_ROUND`, the rope
    settings before the hoist round, `PRIOR_ROUND`, the rope prior before the prior round, and `START_ROUND`, the start
    swing before the start-swing round: with it the re-run is not needed on these draws, 0.133° either way; with the
    hoist round's defaults 0.182° vs 0.187°, 2.7 % lower), and a jump opening the told length by 10 %
    (`JUMP_ROPE_ROUND`: at 3 % the stop's jump no longer shortens the rope here, 0.145° with or without the re-run)."""
    on, off = [], []
    for seed in (41, 42, 43, 44):
        truth, gyr, acc = trolley_stop_data(seed)
        its_round = ROPE_ROUND | HOIST_ROUND | PRIOR_ROUND | START_ROUND | JUMP_ROPE_ROUND
        on.append(swing_rmse_from(truth, gyr, acc, 3.0, its_round | {"jump_stop_std_m_s2": 0.2}, 21.0))
        off.append(swing_rmse_from(truth, gyr, acc, 3.0, its_round, 21.0))
    assert np.mean(off) > 1.05 * np.mean(on), (on, off)


def test_a_stops_re_run_the_likelihood_rejects_changes_nothing():
    """With `jump_stop_lr` out of reach the stop's re-run is never kept: the estimates are the default's to the last
    bit (the first re-run's state, covariance and monitor stay as they were)."""
    truth, gyr, acc = trolley_stop_data(41)
    runs = []
    for over in ({}, {"jump_stop_std_m_s2": 0.2, "jump_stop_lr": -1e9}):
        f = HookFilter(HookFilterSettings(rope_length_m=3.0, rope_length_known=True, **over), use_mag=False)
        f.start(gyr[:50], acc[:50], None, DT_S)
        runs.append(f.run(gyr, acc, None, DT_S))
    assert np.array_equal(runs[0], runs[1])


def test_the_error_budget_oracles_reach_the_truth():
    """`bench.hook_budget`: with error-free sensors and every truth given (rope, boom tip, lever arm, initial state,
    sensor-error states), a 30 s suite crane's Θ RMSE is below 0.02° (measured 0.002° on seeds 1-12); the filter alone
    is above 0.03° on it (so the oracles, not the crane, make it small)."""
    from bench.hook_budget import oracle_run
    from bench.hook_suite import score_phases, simulate_seed

    case, truth, gyr, acc, mag = simulate_seed(8, 30.0, "ideal", True)
    rmse = {o: score_phases(oracle_run(o, case, truth, gyr, acc, mag, {})[0], truth, case, True)["all"]["swing_rmse"]
            for o in ("all", "base")}  # fmt: skip
    assert rmse["all"] < 0.02 and rmse["base"] > 0.03, rmse


def test_the_start_swing_of_a_twisting_hook_is_read_with_the_heading_it_turns_through():
    """A hook swinging 5° on a 4 m rope while it twists at 0.6 rad/s (34°/s, fresh suite seed 1720) when the gateway
    starts: over the 0.5 s warm-up it turns 17°, so the gyroscope's x/y must be turned by the heading at each sample,
    not the start heading, to give the swing's rate (the start swing read 0.3-0.5° short there). Noise-free rates
    from the filter's own model: the start swing within 3 % of the truth (measured 1.3 %; 54 % with the start
    heading held)."""
    length_m, rate_rad_s, alpha0 = 4.0, 0.6, 0.4
    omega = math.sqrt(G_M_S2 / length_m)
    n = int(0.5 * RATE_HZ)
    t = np.arange(n) * DT_S
    amp, minor = math.sin(math.radians(5.0)), 0.3  # an elliptic swing, its major axis along East
    gyr = np.empty((n, 3))
    for k in range(n):
        x = np.zeros(N_STATE)
        x[0], x[1] = amp * math.cos(omega * t[k] + 0.7), minor * amp * math.sin(omega * t[k] + 0.7)
        x[2], x[3] = -amp * omega * math.sin(omega * t[k] + 0.7), minor * amp * omega * math.cos(omega * t[k] + 0.7)
        x[4], x[5] = alpha0 + rate_rad_s * t[k], rate_rad_s
        gyr[k] = attitude_and_rate(x)[1]
    p_true = np.array([amp * math.cos(0.7), minor * amp * math.sin(0.7)])
    errors = []
    for over in ({}, START_ROUND):
        f = HookFilter(HookFilterSettings(rope_length_m=length_m, rope_length_known=True, **over), use_mag=False)
        f.x[4] = alpha0
        swing = f.swing_from_window(gyr, DT_S)
        assert swing is not None
        errors.append(float(np.linalg.norm(swing[0] - p_true) / np.linalg.norm(p_true)))
    assert errors[0] < 0.03 < 0.3 < errors[1], errors


def test_a_steady_wind_at_start_is_split_from_the_accelerometer_bias_by_their_priors():
    """A still hook in a steady wind (0.06 m/s² per unit mass: the rope leans 0.35°) that does not twist, on a board
    without accelerometer bias: by default (`start_wind_std_m_s2` 0) the warm-up's mean force is taken for bias and
    the lean is lost; `WINDY_START` (a 0.03 m/s² wind prior, the bias's 0.03) gives the force half of it, as the two
    priors say. Θ RMSE over 2-10 s (told the length): measured 0.44° by default, 0.27° with the prior split (the
    bias estimate half the default's)."""
    physics = HookPhysicsSettings(rope_length_m=6.0, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT)
    scenario = HookScenario(duration_s=10.0, output_rate_hz=RATE_HZ, wind_mean_m_s2=(0.06, 0.0),
                            wind_torque_std_n_m=0.0, seed=5)  # fmt: skip
    truth = simulate(physics, scenario)
    board = dataclasses.replace(ImuErrorModel.calibrated(), acc_bias_std_m_s2=0.0, misalignment_std_rad=0.0)
    gyr, acc, mag = SensorModel(board, 1, np.random.default_rng(5)).measure(truth.gyr_rad_s, truth.acc_m_s2,
                                                                            truth.mag_uT, DT_S)  # fmt: skip
    n = int(0.5 * RATE_HZ)
    errors, biases = [], []
    for over in ({}, WINDY_START):
        f = HookFilter(HookFilterSettings(rope_length_m=6.0, rope_length_known=True, **over), use_mag=True)
        f.start(gyr[:n], acc[:n], mag[:n], DT_S)
        biases.append(float(np.hypot(*f.x[10:12])))
        q = f.run(gyr, acc, mag, DT_S)
        later = truth.t_s >= 2.0
        errors.append(rmse_deg((hook.swing_angle(q) - truth.swing_rad)[later]))
    assert errors[1] < 0.7 * errors[0], errors
    assert biases[1] == pytest.approx(0.5 * biases[0], rel=1e-9), biases  # k = 0.03² / (0.03² + 0.03²)


@pytest.mark.parametrize(("rope_m", "swing_deg"), [(20.0, 4.0), (25.0, 0.0)])
def test_an_mpu6050_class_accelerometer_offset_at_start_is_taken_for_bias(rope_m, swing_deg):
    """A board whose x/y zero-g offset is 50 mg (0.49 m/s², the MPU-6050's raw tolerance; one MPU-6050/HMC5883L-class
    board in eight is above 40 mg): the start takes the warm-up's mean force for bias, as for a smaller one. Before
    (`WARMUP_ROUND`, 0.4 m/s²) it was taken for a force and left to the pendulum's dynamics, slow on a long rope.
    Θ RMSE over 0.5-30 s, told the length: measured 0.151° / 0.051° (swinging 4° / still) against 0.494° / 0.510°."""
    physics = HookPhysicsSettings(rope_length_m=rope_m, gravity_m_s2=G_M_S2, earth_field_uT=EARTH_FIELD_ENU_UT)
    scenario = HookScenario(duration_s=30.0, output_rate_hz=RATE_HZ, initial_swing_rad=math.radians(swing_deg),
                            initial_swing_bearing_rad=0.6, wind_torque_std_n_m=0.0, seed=3)  # fmt: skip
    truth = simulate(physics, scenario)
    sensor = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(3))
    sensor.acc_bias_m_s2[0, :2] = (0.45, -0.2)
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    n = int(0.5 * RATE_HZ)
    errors = []
    for over in ({}, WARMUP_ROUND):
        f = HookFilter(HookFilterSettings(rope_length_m=rope_m, rope_length_known=True, **over), use_mag=True)
        f.start(gyr[:n], acc[:n], mag[:n], DT_S)
        if not over:
            assert f.x[10:12] == pytest.approx((0.45, -0.2), abs=0.1)  # the offset, within the tension's pick-up
        q = f.run(gyr, acc, mag, DT_S)
        errors.append(rmse_deg((hook.swing_angle(q) - truth.swing_rad)[n:]))
    assert errors[0] < 0.25 < 0.4 < errors[1], errors


def test_a_warm_up_force_beyond_any_offset_is_not_taken_for_bias():
    """A mean x/y force of 1 m/s² over the warm-up (102 mg: the hook held aside, not an MPU-6050's offset) leaves the
    accelerometer bias at 0 with the wide prior (`max_warmup_acc_bias_m_s2`), for the dynamics to find."""
    n = int(0.5 * RATE_HZ)
    gyr = np.zeros((n, 3))
    acc = np.tile([1.0, 0.0, G_M_S2], (n, 1))
    mag = np.tile([0.0, 20.0, -44.0], (n, 1))
    f = HookFilter(HookFilterSettings(rope_length_m=10.0, rope_length_known=True), use_mag=True)
    f.start(gyr, acc, mag, DT_S)
    assert f.x[10:12] == pytest.approx((0.0, 0.0), abs=1e-12)
    assert np.sqrt(f.P[10, 10]) == pytest.approx(f.settings.max_warmup_acc_bias_m_s2)
    g = HookFilter(HookFilterSettings(rope_length_m=10.0, rope_length_known=True), use_mag=True)
    g.start(gyr, acc * [0.6, 1.0, 1.0], mag, DT_S)  # 0.6 m/s²: an offset
    assert g.x[10] == pytest.approx(0.6, abs=0.05)


def test_a_rest_start_whose_swing_reads_over_the_noise_is_not_held_at_plumb():
    """Fresh crane 3680 (29.5 m, swinging 7.0° at its turning point and twisting 0.24 rad/s) on its MPU-6050-class
    board: its 0.5-s window reads 4.9° of swing against a cross-axis σ of 2.9° (a long rope's rate barely changes in
    0.5 s), under the 3σ bar and not too large for rest, so the start is rest, at plumb. Held there by the rest prior
    (`REST_PRIOR_ROUND`) Θ reads 1.78° RMS over 0.5-5 s and 0.44° over 5-20 s (max 0.75°); with the prior widened
    to the reading's σ (`rest_prior_from_read`) 0.46° and 0.21° (max 0.29°), 10-sample packets. A still hook whose
    reading is under 3σ of noise (suite crane 4) keeps the tight rest prior."""
    from bench.hook_suite import simulate_seed

    case, truth, gyr, acc, mag = simulate_seed(3680, 120.0, "legacy", True)  # (the timeline is drawn over 120 s)
    n = 2000
    first, later = [], []
    for over in ({}, REST_PRIOR_ROUND):
        f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True, **over))
        f.start(gyr[:50], acc[:50], mag[:50], 0.01)
        q = np.concatenate([f.run_with_length(gyr[a:a + 10], acc[a:a + 10], mag[a:a + 10], 0.01)[0]
                            for a in range(0, n, 10)])  # fmt: skip
        err = np.degrees(np.abs(hook.swing_angle(q) - truth.swing_rad[:n]))
        first.append(float(np.sqrt(np.mean(err[50:500] ** 2))))
        later.append(float(np.sqrt(np.mean(err[500:] ** 2))))
    assert first[0] < 0.8 < 1.2 < first[1], first
    assert later[0] < 0.3 < 0.35 < later[1], later
    case, truth, gyr, acc, mag = simulate_seed(4, 120.0, "legacy", True)
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True))
    f.start(gyr[:50], acc[:50], mag[:50], 0.01)
    assert f.P[0, 0] == pytest.approx(f.settings.init_swing_std**2, rel=1e-12)


def test_a_swing_under_the_detection_bar_of_a_fast_twist_is_not_taken_for_rest():
    """Suite crane 2672 at 50 Hz (19.6 m, swinging 7.8° and twisting at 145 °/s² at start): the twist's cross-axis
    pick-up puts the start swing test's σ at 2.9°, and the swing reads 8.67° for a 3σ bar of 8.72°. With
    `REST_ROUND` (and `REST_PRIOR_ROUND`) the quiet window was rest: its swing's rate seeded as gyro bias and the
    start at plumb (Θ 5.1° off in the first 3 s). Over 3σ of noise plus 2σ of cross-axis pick-up it is not rest
    (measured max 1.29°; taken for rest but with the swing's prior widened to its reading, 1.16°). A still hook
    (suite crane 4, 25.7 m) is rest either way, its window's mean rate the gyro bias."""
    from bench.hook_suite import simulate_seed

    case, truth, gyr, acc, mag = simulate_seed(2672, 120.0, "calibrated", True, rate_hz=50.0)
    rope = case.physics.rope_length_m
    worst = []
    for over in ({}, {**REST_ROUND, **REST_PRIOR_ROUND}):
        f = HookFilter(HookFilterSettings(rope_length_m=rope, rope_length_known=True, **over), use_mag=True)
        f.start(gyr[:25], acc[:25], mag[:25], 0.02)
        q = f.run(gyr[:150], acc[:150], mag[:150], 0.02)
        worst.append(float(np.degrees(np.abs(hook.swing_angle(q) - truth.swing_rad[:150])[25:].max())))
    assert worst[0] < 1.5 < 4.0 < worst[1], worst
    case, truth, gyr, acc, mag = simulate_seed(4, 120.0, "calibrated", True)
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True), use_mag=True)
    f.start(gyr[:50], acc[:50], mag[:50], 0.01)
    assert f.x[6:8] == pytest.approx(gyr[:50, :2].mean(axis=0), abs=1e-12)  # rest: the x/y bias from the window
