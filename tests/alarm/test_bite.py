"""Bite, drop-back and line-guard behaviour on synthetic rod scenarios with stated expectations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from gateway.alarm.bite import BiteDetector, run_starts, trailing_mean
from gateway.config import RodThresholds
from tests.alarm.scenarios import REST_DEG, noisy, pulse, raised_cosine_step, run_rod, times, tip_acc_up

NOISE_DEG = 0.2  # fused-pitch noise, 1 sigma
ACC_NOISE = 0.3  # m/s^2, 1 sigma


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(7)


def test_run_starts_carries_across_blocks():
    t = np.arange(6) * 0.01
    cond = np.array([True, True, False, True, True, True])
    starts = run_starts(cond, t, carry_s=-0.5)
    np.testing.assert_allclose(starts, [-0.5, -0.5, np.nan, 0.03, 0.03, 0.03])


def test_trailing_mean_matches_convolution_across_blocks():
    x = np.random.default_rng(1).standard_normal(40)
    ref = np.convolve(np.concatenate(([0.0, 0.0], x)), np.ones(3) / 3, mode="valid")
    ref[:2] = [x[0], (2 * x[0] + x[1]) / 3]  # the first sample stands in for the missing ones at the very start
    whole, _ = trailing_mean(x, np.zeros(0), 3)
    for cut in (1, 2, 7):
        tail = np.zeros(0)
        got = []
        for i in range(0, 40, cut):
            m, tail = trailing_mean(x[i : i + cut], tail, 3)
            got.append(m)
        np.testing.assert_allclose(np.concatenate(got), ref, atol=1e-12)
        assert np.array_equal(np.concatenate(got), whole)  # bit-identical however the stream is cut


def test_one_bite_alarms_once_within_confirmation_of_crossing_theta1(rng):
    t = times(30.0)
    rel = -pulse(t, 10.0, 0.15, 5.0, 15.0)
    t_cross = t[np.argmax(rel <= -10.0)]  # noise-free crossing of theta1
    run = run_rod(t, noisy(t, rel, NOISE_DEG, rng))
    bites = run.of("bite")
    assert len(bites) == 1
    after_cross = bites[0].alarm.started_at - t_cross
    assert -0.02 <= after_cross <= 0.02 + 0.011, after_cross  # confirmation 20 ms at sensitivity 3, +1 sample
    assert run.raised_types() == {"bite"}
    assert len(run.of("bite", "cleared")) == 1  # re-armed after the rod came back and stayed quiet


def test_accel_cue_only_skips_the_confirmation_once_theta1_is_reached(rng):
    """A fast pull: the cue fires at the first sample >= theta1 below rest, pitch alone confirm_s (20 ms) later."""
    t = times(20.0)
    rel = -pulse(t, 10.0, 0.2, 3.0, 15.0)
    pitch = noisy(t, rel, NOISE_DEG, rng)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng)
    plain = run_rod(t, pitch).of("bite")
    cued = run_rod(t, pitch, acc).of("bite")
    assert len(plain) == len(cued) == 1
    assert cued[0].alarm.details["cue"] == "accel" and plain[0].alarm.details["cue"] == "pitch"
    first_at_theta1 = t[np.argmax(pitch - REST_DEG <= -10.0)]  # the baseline is REST_DEG within noise/10
    assert abs(cued[0].alarm.started_at - first_at_theta1) < 0.011
    assert cued[0].alarm.value <= -10.0 and plain[0].alarm.value <= -10.0  # both measured beyond theta1
    assert plain[0].alarm.started_at - cued[0].alarm.started_at == pytest.approx(0.02, abs=0.011)


@pytest.mark.parametrize("depth_deg", [6.0, 7.0, 9.5])
def test_accel_cue_never_alarms_a_pull_short_of_theta1(depth_deg, rng):
    """Issue 10: a scripted 7 deg pull with a sharp downward jolt alarmed by the cue. theta1 is a floor."""
    t = times(20.0)
    rel = -pulse(t, 10.0, 0.1, 1.0, depth_deg)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng)
    acc[(t >= 10.0) & (t < 10.1)] -= 40.0  # a 4 g downward tap during the pull, far above any cue bar
    run = run_rod(t, noisy(t, rel, 0.05, rng), acc)
    assert run.of("bite") == []


def test_fast_bite_with_accel_cue_alarms_within_100ms(rng):
    t = times(20.0)
    rel = -pulse(t, 10.0, 0.15, 3.0, 15.0)
    pitch = noisy(t, rel, NOISE_DEG, rng)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng)
    bites = run_rod(t, pitch, acc).of("bite")
    assert len(bites) == 1
    assert 0.0 <= bites[0].alarm.started_at - 10.0 <= 0.1


@pytest.mark.parametrize("axis", ["roll", "yaw"])
def test_roll_or_yaw_change_with_pitch_fixed_never_alarms(axis, rng):
    t = times(20.0)
    roll = raised_cosine_step(t, 5.0, 0.3, 15.0) if axis == "roll" else np.zeros_like(t)
    yaw = raised_cosine_step(t, 5.0, 1.0, 90.0) if axis == "yaw" else np.zeros_like(t)
    # Body x = rod axis; pitch up is a negative rotation about body y in scipy's intrinsic Z-Y-X.
    rot = Rotation.from_euler("ZYX", np.column_stack([yaw, -np.full_like(t, REST_DEG), roll]), degrees=True)
    tip_dir = rot.apply([1.0, 0.0, 0.0])
    pitch = np.degrees(np.arcsin(tip_dir[:, 2])) + NOISE_DEG * rng.standard_normal(t.size)
    acc = ACC_NOISE * rng.standard_normal(t.size)  # turning about the axis or the holder: the tip height is fixed
    run = run_rod(t, pitch, acc)
    assert run.changes == []
    det = BiteDetector()
    det.update(t, np.radians(pitch), np.radians(roll), np.radians(yaw), acc)
    assert det.state.bite_armed and det.state.drop_armed


def test_wind_vibration_never_alarms_at_default_sensitivity(rng):
    t = times(120.0)
    rel = 3.0 * np.sin(2 * np.pi * 2.0 * t + 0.3)
    pitch = noisy(t, rel, NOISE_DEG, rng)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng)
    run = run_rod(t, pitch, acc)
    assert run.changes == []
    assert abs(run.baselines[-1] - REST_DEG) < 0.3


def test_zero_mean_oscillation_beyond_cue_level_does_not_fire_cue(rng):
    # +/-8 deg at 2 Hz crosses the cue level (5 deg) every period, but below rest the tip accelerates upwards.
    t = times(60.0)
    gust = np.clip((t - 5.0) / 5.0, 0.0, 1.0)  # at rest for 5 s, then the wind builds up over 5 s
    rel = 8.0 * gust * np.sin(2 * np.pi * 2.0 * t)
    pitch = noisy(t, rel, NOISE_DEG, rng)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng)
    run = run_rod(t, pitch, acc)
    assert run.of("bite") == []


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_slow_drift_of_holder_does_not_alarm(sign, rng):
    t = times(240.0)
    pitch = noisy(t, sign * 5.0 / 60.0 * t, NOISE_DEG, rng)  # 5 deg/min for 4 min = 20 deg
    run = run_rod(t, pitch)
    assert run.changes == []
    assert abs(run.baselines[-1] - pitch[-100:].mean()) < 1.0  # the baseline followed the holder


def test_drop_back_is_reported_as_drop_back_not_bite(rng):
    t = times(20.0)
    pitch = noisy(t, pulse(t, 8.0, 0.3, 4.0, 8.0), NOISE_DEG, rng)
    run = run_rod(t, pitch)
    assert run.raised_types() == {"drop_back"}
    assert len(run.of("drop_back")) == 1
    assert 8.5 <= run.of("drop_back")[0].alarm.started_at <= 8.8  # 5 deg crossed by 8.3 s, then held 0.5 s


def test_two_bites_separated_by_quiet_time_give_two_alarms(rng):
    t = times(40.0)
    th = RodThresholds()
    second = 10.0 + 0.2 + 1.0 + 0.2 + th.rearm_quiet_s + 1.0  # back at rest for quiet time + 1 s
    rel = -pulse(t, 10.0, 0.2, 1.0, 14.0) - pulse(t, second, 0.2, 1.0, 14.0)
    run = run_rod(t, noisy(t, rel, NOISE_DEG, rng), th=th)
    starts = [c.alarm.started_at for c in run.of("bite")]
    assert len(starts) == 2
    assert starts[0] == pytest.approx(10.1, abs=0.1) and starts[1] == pytest.approx(second + 0.1, abs=0.1)
    assert run.of("bite")[0].alarm.id != run.of("bite")[1].alarm.id


def test_bites_closer_than_quiet_time_give_one_alarm(rng):
    t = times(30.0)
    rel = -pulse(t, 10.0, 0.2, 1.0, 14.0) - pulse(t, 13.0, 0.2, 1.0, 14.0)  # 1.6 s at rest in between
    run = run_rod(t, noisy(t, rel, NOISE_DEG, rng))
    assert len(run.of("bite")) == 1


def test_single_sample_spike_is_rejected_by_confirmation(rng):
    t = times(10.0)
    rel = np.zeros_like(t)
    rel[500] = -14.0
    assert run_rod(t, noisy(t, rel, NOISE_DEG, rng)).changes == []


@pytest.mark.parametrize(("sensitivity", "expect"), [(3, 0), (4, 1), (5, 1)])
def test_sensitivity_steps_scale_theta1(sensitivity, expect, rng):
    t = times(20.0)
    rel = -pulse(t, 10.0, 0.3, 2.0, 9.0)  # 9 deg: below theta1 = 10, above 0.8 * 10 and 0.6 * 10
    run = run_rod(t, noisy(t, rel, 0.1, rng), th=RodThresholds(sensitivity=sensitivity))
    assert len(run.of("bite")) == expect


def test_detector_rebaselines_after_rod_settles_at_new_rest(rng):
    t = times(100.0)
    rel = -raised_cosine_step(t, 5.0, 0.3, 15.0) - pulse(t, 80.0, 0.2, 2.0, 14.0)  # bite, rest lower, bite
    run = run_rod(t, noisy(t, rel, NOISE_DEG, rng))
    assert [round(c.alarm.started_at) for c in run.of("bite")] == [5, 80]


def test_line_guard_warning_critical_and_clear(rng):
    t = times(30.0)
    th = RodThresholds(line_switch_deg=20.0, line_limit_deg=35.0)  # critical at 0.9 * 35 = 31.5
    rel = -(raised_cosine_step(t, 5, 0.5, 25.0) + raised_cosine_step(t, 10, 0.5, 8.0)
            - raised_cosine_step(t, 15, 0.5, 33.0))  # fmt: skip
    run = run_rod(t, noisy(t, rel, NOISE_DEG, rng), th=th)
    line = [(c.kind, c.alarm.severity.value) for c in run.changes if c.alarm.type == "line_tension"]
    # coming back down it passes through the warning band before clearing
    assert line == [("raised", "warning"), ("updated", "critical"), ("updated", "warning"), ("cleared", "warning")]
    raised = run.of("line_tension")[0].alarm
    assert 5.0 < raised.started_at < 5.5


def test_line_tension_near_breaking_is_critical(rng):
    t = times(10.0)
    tension = np.where((t > 4) & (t < 6), 85.0, 20.0)  # breaking 100 N, warn fraction 0.8
    run = run_rod(t, noisy(t, np.zeros_like(t), NOISE_DEG, rng), tension_n=tension)
    line = [(c.kind, c.alarm.severity.value, round(c.alarm.updated_at, 2)) for c in run.changes]
    # raised on the sample that crossed; cleared LINE_CLEAR_HOLD_S (2 s) after the first sample back below
    assert line == [("raised", "critical", 4.01), ("cleared", "critical", 8.0)]


def test_line_guard_does_not_flap_when_a_fight_pumps_through_the_band(rng):
    """Issue 17: a level falls only after 2 s below it. Tension pumping 70 <-> 90 N at 1 Hz (warning level 80 N,
    clears under 75 N) raises once and clears once, 2 s after the last pull above 75 N; without the hold it flaps."""
    from gateway.alarm.rules import LineGuard

    t = times(20.0)
    th = RodThresholds(line_breaking_n=100.0)  # warning at 0.8 x 100 N, clears under 75 N
    tension = np.where((t > 4) & (t < 12), 80.0 + 10.0 * np.sign(np.sin(2 * np.pi * t)), 20.0)
    run = run_rod(t, noisy(t, np.zeros_like(t), NOISE_DEG, rng), tension_n=tension, th=th)
    line = [(c.kind, round(c.alarm.updated_at, 1)) for c in run.changes]
    assert line == [("raised", 4.0), ("cleared", 13.5)], line  # the last 90 N half-period ends at 11.5 s
    flappy = LineGuard(th, clear_hold_s=0.0)
    from gateway.alarm.bite import RodBlock

    quiet = RodBlock(events=(), baseline_rad=0.0, deviation_rad=np.zeros(t.size), min_deviation_rad=0.0, t_min_s=0.0)
    assert len(flappy.update("rod-1", t, quiet, tension)) > 10


@pytest.mark.parametrize("block", [1, 7, 50])
def test_block_size_does_not_change_detections(block, rng):
    t = times(30.0)
    rel = -pulse(t, 10.0, 0.3, 2.0, 15.0) + pulse(t, 20.0, 0.3, 2.0, 8.0)
    pitch = noisy(t, rel, NOISE_DEG, rng)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng)
    ref = [(c.kind, c.alarm.type, c.alarm.started_at) for c in run_rod(t, pitch, acc, block=10).changes[:3]]
    got = [(c.kind, c.alarm.type, c.alarm.started_at) for c in run_rod(t, pitch, acc, block=block).changes[:3]]
    assert got == ref and len(ref) == 3


def taps(n: int, rng: np.random.Generator) -> np.ndarray:
    """Vertical tip acceleration (m/s^2): 0.1 noise with 3-sample downward taps of 1-6 g, about 2 per second."""
    acc = 0.1 * rng.standard_normal(n)
    for i in np.flatnonzero(rng.random(n) < 0.02):
        acc[i : i + 3] -= rng.uniform(10.0, 60.0)
    return acc


@settings(max_examples=60, deadline=None)
@given(
    sensitivity=st.integers(1, 5),
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(300, 1500),  # beyond the 2 s warm-up
    block=st.integers(1, 64),
    shape=st.sampled_from(["uniform", "walk", "square"]),
    with_acc=st.booleans(),
)
def test_property_pitch_within_09_theta1_of_baseline_never_bites(sensitivity, seed, n, block, shape, with_acc):
    """Every sample stays within a band 0.9 * theta1 wide; the baseline is an average of past samples, so it lies
    in the same band and |pitch - baseline| < 0.9 theta1 always: no bite, whatever the shape, block or cue input.
    The acceleration (when given) has sharp downward taps of 1-6 g (30 ms) on a quiet floor, the shape that made
    the old cue fire at 0.2 theta1: the cue can never lower theta1 (issue 10)."""
    th = RodThresholds(sensitivity=sensitivity)
    band = 0.9 * th.effective_bite_deg
    rng = np.random.default_rng(seed)
    t = times(n / 100.0)
    if shape == "uniform":
        u = rng.uniform(0.0, 1.0, t.size)
    elif shape == "walk":
        w = np.cumsum(rng.standard_normal(t.size))
        u = (w - w.min()) / max(np.ptp(w), 1e-9)
    else:
        u = (np.sin(2 * np.pi * rng.uniform(0.1, 5.0) * t) > 0).astype(float)
    pitch = REST_DEG + band * (0.999 * u - 0.5)
    acc = taps(t.size, rng) if with_acc else None
    run = run_rod(t, pitch, acc, th=th, block=block)
    assert run.of("bite") == []
    assert math.isfinite(run.baselines[-1])


@pytest.mark.parametrize("during_fight", [False, True])
def test_nan_block_leaves_detector_state_finite(during_fight):
    det = BiteDetector()
    t = np.arange(10) / 100.0
    rest = math.radians(REST_DEG)
    det.rebaseline(rest)  # skip the warm-up
    det.update(t, np.full(10, rest))
    if during_fight:
        det.update(t + 0.1, np.full(10, rest - math.radians(15.0)))
        assert not det.state.bite_armed
    det.update(t + 0.2, np.full(10, np.nan))  # a lost block filled with nan
    s = det.state
    assert s.baseline_rad == pytest.approx(rest)
    assert not math.isnan(s.steady_ref_rad) or math.isnan(s.steady_since_s)


def test_tip_acc_up_matches_scipy_rotation():
    from gateway.alarm.bite import tip_acc_up as acc_up

    rng = np.random.default_rng(3)
    rot = Rotation.random(50, random_state=4)
    acc_body = rng.normal(0.0, 5.0, (50, 3))
    ref = rot.apply(acc_body)[:, 2] - 9.81  # scipy rotates body -> earth with the same rotation
    q_xyzw = rot.as_quat()
    q_wxyz = q_xyzw[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(acc_up(q_wxyz, acc_body), ref, atol=1e-9)
    level_at_rest = acc_up(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 9.81]))
    assert abs(float(level_at_rest)) < 1e-12


@pytest.mark.parametrize("with_acc", [False, True])
def test_one_long_block_with_warm_up_then_a_bite_alarms_like_streaming(with_acc, rng):
    """A burst holding the 2 s warm-up and a bite (at 3 s) must alarm: the warm-up ends inside the block."""
    t = times(6.0)
    rel = -pulse(t, 3.0, 0.15, 1.5, 15.0)
    pitch = noisy(t, rel, NOISE_DEG, rng)
    acc = tip_acc_up(t, rel, ACC_NOISE, rng) if with_acc else None
    streamed = run_rod(t, pitch, acc, block=5).of("bite")
    at_once = run_rod(t, pitch, acc, block=t.size).of("bite")
    assert len(streamed) == len(at_once) == 1
    assert abs(at_once[0].alarm.started_at - streamed[0].alarm.started_at) < 1e-9  # same triggering sample
    assert 3.0 <= at_once[0].alarm.started_at <= 3.2


def test_block_spanning_warm_up_end_learns_from_its_head_only():
    """The first 2 s (20 frames) only learn the rest as their mean, whatever the block; later samples are judged
    against it. A drop inside the warm-up is learnt, not judged (deviation nan)."""
    t = times(3.0)
    pitch = np.radians(np.full(t.size, REST_DEG))
    pitch[t > 2.5] = np.radians(REST_DEG - 5.0)
    pitch[10] = np.radians(REST_DEG - 20.0)  # a head sample at 0.1 s, far below rest
    for block in (t.size, 7):
        det = BiteDetector()
        devs = [det.update(t[i : i + block], pitch[i : i + block]).deviation_rad for i in range(0, t.size, block)]
        dev = np.degrees(np.concatenate(devs))
        assert det.state.warmed
        assert np.isnan(dev[:200]).all()
        rest = REST_DEG - 20.0 / 200  # the mean of the first 200 samples
        np.testing.assert_allclose(dev[200:210], np.degrees(pitch[200:210]) - rest, atol=1e-9)  # first frame after
        assert 0.0 < dev[210] < dev[200]  # then the baseline follows the quiet rod (the 0.1 s frames move it)


@settings(max_examples=60, deadline=None)
@given(sensitivity=st.integers(1, 5), seed=st.integers(0, 2**32 - 1), block=st.integers(1, 64))
def test_property_every_bite_alarm_measured_at_least_theta1_and_says_so(sensitivity, seed, block):
    """Random pulls of 0-20 deg with arbitrary accelerometer input: each bite alarm's sample is >= theta1 below
    the rest it was judged from, and its message states that deviation and theta1 in degrees."""
    th = RodThresholds(sensitivity=sensitivity)
    rng = np.random.default_rng(seed)
    t = times(60.0)
    rel = np.zeros_like(t)
    for t0 in np.arange(4.0, 55.0, 8.0):
        rel -= pulse(t, t0, rng.uniform(0.05, 0.8), rng.uniform(0.0, 2.0), rng.uniform(0.0, 20.0))
    acc = taps(t.size, rng) + rng.uniform(-20.0, 20.0, t.size) * (rng.random() < 0.5)
    run = run_rod(t, noisy(t, rel, 0.3, rng), acc, th=th, block=block)
    theta1 = th.effective_bite_deg
    for c in [c for c in run.conditions if c.type == "bite" and c.severity is not None]:
        assert c.value <= -theta1 + 1e-9 and c.threshold == pytest.approx(-theta1)
        assert c.message.startswith(f"bite: pitch {-c.value:.1f}° below rest ≥ θ1 {theta1:.1f}°")
