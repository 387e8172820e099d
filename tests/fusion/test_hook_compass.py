"""A compass the hook filter cannot trust (docs/fusion.md): the default filter's twin without the magnetometer, which
it becomes when the compass misleads the swing, and `hook-6d`, the hook EKF that never takes the magnetometer. Crane
suite seed 7 (10.9 m rope, 13.7 t, swinging at start) with the raw board's errors (`ImuErrorModel.uncalibrated()`:
~30 mg accelerometer offset, 15 µT hard iron, 3 % soft iron); without the twin (`COMPASS_ROUND`) the 9D filter read
it at 64° Θ RMSE over 5-60 s through the pipeline."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.hook_suite import simulate_seed, suite_board
from devices.common import ImuErrorModel, SensorModel
from gateway import schemas
from gateway.config import DeviceSettings, HookThresholds
from gateway.fusion import hook as hook_geo
from gateway.fusion.bank import HOOK_FILTER, HOOK_FILTER_6D, make_filter
from gateway.fusion.hook_filter import (
    COMPASS_ROUND,
    DROP_ROUND,
    IRON_PRIOR_ROUND,
    JUMP_ROPE_ROUND,
    LOOSE_ROUND,
    MAG_NOISE_ROUND,
    SOFT_IRON_ROUND,
    STEADY_ROUND,
    TILT_GAIN_ROUND,
    ZSCALE_ROUND,
    ZSEED_ROUND,
    HookFilter,
    HookFilterSettings,
)
from gateway.pipeline import Pipeline

SEED, DURATION_S, SPP, RATE_HZ = 7, 60.0, 10, 100.0
WARM_S = 0.5  # `compass_dropped_s` counts the filter's own seconds; they start at most this far into the data (the
# gateway's warm-up), so errors are taken from this long after the drop time on

# The filter before 2026-12-06's twenty-eighth and twenty-ninth sessions: a calibrated board's hard-iron prior and no
# soft iron learnt. The tests of the compass's drop need a compass the filter cannot fit; since the iron is learnt
# (both changes), these cranes' compasses are kept (raw crane 7: Θ 0.076° RMSE over 5-60 s; with the 0.5-µT prior
# alone, soft iron learnt, 0.340°, dropped only at 25 s). Nor the z gyro's scale learnt (2026-12-07's thirty-first
# session): with it, legacy crane 1740's compass is kept too; nor the compass's noise 1.5 µT (the thirty-second); nor
# its gain on the swing at 0.3 (the thirty-fourth: with it alone 1740's compass is kept, raw crane 7's dropped at 10 s);
# nor a jump opening the told length by 3 % (the thirty-fifth: with it 1740's compass is kept).
MISLED: dict[str, float] = {**MAG_NOISE_ROUND, **IRON_PRIOR_ROUND, **SOFT_IRON_ROUND, **ZSCALE_ROUND,
                            **TILT_GAIN_ROUND, **JUMP_ROPE_ROUND}


@pytest.fixture(scope="module")
def raw_board() -> tuple:
    case, truth, gyr, acc, mag = simulate_seed(SEED, DURATION_S, "uncalibrated", True)
    assert mag is not None
    return case, truth, gyr, acc, mag


def _packets(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray) -> list[schemas.ImuPacket]:
    """10-sample packets of the samples, magnetometer included, as a 9-axis hook would send them."""
    def rows(a: np.ndarray) -> list[tuple[float, ...]]:
        return [tuple(r) for r in a.tolist()]

    return [schemas.ImuPacket(v=1, device_id="hook-1", kind="hook", boot_id=1, seq=k, t0_us=round(i * 1e6 / RATE_HZ),
                              rate_hz=RATE_HZ, gyr_rad_s=rows(gyr[i:i + SPP]), acc_m_s2=rows(acc[i:i + SPP]),
                              mag_uT=rows(mag[i:i + SPP]))
            for k, i in enumerate(range(0, gyr.shape[0] - SPP + 1, SPP))]  # fmt: skip


def _swing_errors_deg(name: str | None, raw_board: tuple, from_s: float = 5.0) -> tuple[np.ndarray, Pipeline]:
    """|Θ_est - Θ_true| (degrees) at every published attitude from `from_s`, the hook on filter `name` (None:
    default)."""
    case, truth, gyr, acc, mag = raw_board
    th = {"rope_length_m": case.physics.rope_length_m}
    pipe = Pipeline(device_settings={"hook-1": ("hook", DeviceSettings(filter_name=name, thresholds=th))})
    errors = []
    for p in _packets(gyr, acc, mag):
        for a in pipe.process([p], 1.8e9 + p.t0_us * 1e-6).attitudes:
            i = round(a.t_us * RATE_HZ / 1e6)
            if a.t_us >= from_s * 1e6 - 1.0:
                theta = float(hook_geo.swing_angle(np.array([a.quat_wxyz]))[0])
                errors.append(abs(math.degrees(theta - truth.swing_rad[i])))
    return np.array(errors), pipe


def test_the_hook_6d_filter_never_takes_the_magnetometer(raw_board: tuple) -> None:
    """Given the magnetometer's samples or not, `hook-6d` gives the same quaternions, bit for bit (the 9D filter
    does not: the check can fail)."""
    _, _, gyr, acc, mag = raw_board
    n, dt_s, warm = 3000, 1.0 / RATE_HZ, 50

    def quats(name: str, with_mag: bool) -> np.ndarray:
        f = make_filter(name, use_mag=True, rope_length_m=HookThresholds().rope_length_m)
        m = mag[:n] if with_mag else None
        f.start(gyr[:warm], acc[:warm], None if m is None else m[:warm], dt_s)
        return np.asarray(f.run(gyr[warm:n], acc[warm:n], None if m is None else m[warm:n], dt_s))

    assert not make_filter(HOOK_FILTER_6D, use_mag=True, rope_length_m=8.0).use_mag
    np.testing.assert_array_equal(quats(HOOK_FILTER_6D, True), quats(HOOK_FILTER_6D, False))
    assert not np.array_equal(quats(HOOK_FILTER, True), quats(HOOK_FILTER, False))


def test_hook_6d_keeps_the_swing_of_a_hook_whose_compass_is_raw(raw_board: tuple) -> None:
    """Through the pipeline with the device's `filter_name` set to `hook-6d`: Θ within 0.3° RMSE and 1° max from 5 to
    60 s (measured 0.075° / 0.17°); the default filter on the same packets printed beside it."""
    err_6d, pipe = _swing_errors_deg(HOOK_FILTER_6D, raw_board)
    assert pipe.devices["hook-1"].filter_name == HOOK_FILTER_6D and not pipe.devices["hook-1"].use_mag
    assert err_6d.size > 100
    rmse_6d = float(np.sqrt(np.mean(err_6d**2)))
    err_9d, _ = _swing_errors_deg(None, raw_board)
    print(f"seed {SEED}, raw board, 5-{DURATION_S:.0f} s: hook-6d Θ RMSE {rmse_6d:.3f}° max {err_6d.max():.2f}°; "
          f"hook {float(np.sqrt(np.mean(err_9d**2))):.3f}° max {err_9d.max():.2f}°")
    assert rmse_6d < 0.3
    assert err_6d.max() < 1.0


def test_the_default_hook_filter_learns_a_raw_compass_s_hard_iron(raw_board: tuple) -> None:
    """The default filter (9D, with its twin) on the same packets through the pipeline: since 2026-12-06's
    twenty-eighth session (a 3-µT hard-iron prior) it learns the raw board's 30 µT of hard iron as the hook twists,
    keeps the compass, and Θ is within 0.3° RMSE and 1° max over 5-60 s (measured 0.075° / 0.19°, what the twin gave
    after the drop that came before, next test); its hard-iron estimate is within 2 µT of the board's (x/y measured
    1.3 / 0.2 µT off)."""
    err, pipe = _swing_errors_deg(None, raw_board)
    f = pipe.devices["hook-1"].filt
    assert isinstance(f, HookFilter) and pipe.devices["hook-1"].use_mag
    assert f.compass_trusted and f.compass_dropped_s is None
    assert err.size > 100
    assert float(np.sqrt(np.mean(err**2))) < 0.3
    assert err.max() < 1.0
    board = suite_board(SEED, "uncalibrated")
    assert np.hypot(*board.mag_hard_iron_uT[0, :2]) > 25.0
    np.testing.assert_allclose(f.x[21:23], board.mag_hard_iron_uT[0, :2], atol=2.0)


def test_a_raw_compass_held_to_a_calibrated_board_s_hard_iron_is_found_out(raw_board: tuple) -> None:
    """With a calibrated board's 0.5-µT hard-iron prior and no soft iron learnt (`MISLED`, the filter before) the raw
    compass misleads the swing and the twin drops it within the first 10 s (measured at 7 s in 10-sample calls; 5.7 s
    through the pipeline before the prior changed), and Θ is then the twin's, within 0.3° RMSE and 1° max from the
    drop to 60 s (measured 0.075° / 0.18°; 64° / 81° over 5-60 s without the twin). The dropped compass is kept as
    a loose heading anchor (`compass_dropped_noise_uT`) but its samples far off what the filter expects are not heard
    (`compass_dropped_gate_uT`): heard, it went on misleading the swing, 1.02° / 3.06° from the drop."""
    case, truth, gyr, acc, mag = raw_board
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True,
                                      **MISLED))  # type: ignore[arg-type]
    q = _run(f, gyr, acc, mag, SPP)
    assert not f.compass_trusted and f.compass_dropped_s is not None and f.compass_dropped_s < 10.0
    assert f.compass == "dropped"
    after = round((WARM_S + f.compass_dropped_s) * RATE_HZ)
    err = np.abs(np.degrees(hook_geo.swing_angle(q) - truth.swing_rad))[after:]
    assert err.size > 100
    assert float(np.sqrt(np.mean(err**2))) < 0.3
    assert err.max() < 1.0


def _run(f: HookFilter, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, calls: int) -> np.ndarray:
    f.start(gyr[:50], acc[:50], mag[:50], 1.0 / RATE_HZ)
    return np.concatenate([f.run_with_length(gyr[a:a + calls], acc[a:a + calls], mag[a:a + calls], 1.0 / RATE_HZ)[0]
                           for a in range(0, gyr.shape[0], calls)])  # fmt: skip


def test_the_compass_test_does_not_hang_on_the_call_size(raw_board: tuple) -> None:
    """One call for the whole run (as `bench.hook_suite`), 1-s calls, 10- and 7-sample packets: the compass test runs
    every second of samples counted from the start whatever the call size, so the compass is dropped at the same
    time and the quaternions are the same bit for bit, but for the second before the drop (the call that drops
    the compass returns the twin's output for all its samples: a whole second in one, the last packet in another).
    Before the test ran at call ends: within a packet of the same time, not the same state."""
    case, truth, gyr, acc, mag = raw_board
    settings = HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True, told_doubt_sigmas=0,
                                  **MISLED)  # type: ignore[arg-type]  # (the default keeps this compass)
    # (the misled compass pulls the learnt length 3.5σ off the told one by 3 s: the start redone there would return
    # the redone output for the call's samples before it, `test_hook_told_doubt`; here the compass test alone)
    quats, drops = {}, {}
    for calls in (gyr.shape[0], 100, 10, 7):
        f = HookFilter(settings)
        quats[calls] = _run(f, gyr, acc, mag, calls)
        drops[calls] = f.compass_dropped_s
    assert drops[gyr.shape[0]] is not None and len(set(drops.values())) == 1, drops
    # `_run` feeds the warm-up window again from sample 0; the test counts from `start()`, so the drop's second
    # ends `drop` s of samples after sample 0
    end = round(drops[gyr.shape[0]] * RATE_HZ)
    for calls, q in quats.items():
        assert np.array_equal(q[:end - round(RATE_HZ)], quats[gyr.shape[0]][:end - round(RATE_HZ)]), calls
        assert np.array_equal(q[end:], quats[gyr.shape[0]][end:]), calls


@pytest.mark.parametrize("seed", [30, 1])
def test_a_calibrated_compass_is_kept_and_changes_nothing(seed: int) -> None:
    """Tuning seeds 30 and 1 on the calibrated board, where the two filters' likelihoods differed most (79 and 71
    over 10 s, against a bar of 120): the compass is kept, and the quaternions are those of the filter without the
    twin (`COMPASS_ROUND`), bit for bit."""
    case, _, gyr, acc, mag = simulate_seed(seed, 60.0, "calibrated", True)
    assert mag is not None
    told = {"rope_length_m": case.physics.rope_length_m, "rope_length_known": True}
    with_twin = HookFilter(HookFilterSettings(**told))  # type: ignore[arg-type]
    q = _run(with_twin, gyr, acc, mag, 10)
    q_old = _run(HookFilter(HookFilterSettings(**told, **COMPASS_ROUND)), gyr, acc, mag, 10)  # type: ignore[arg-type]
    assert with_twin.compass_trusted and with_twin.compass_dropped_s is None  # tested, or trusted after 60 s swinging
    assert np.array_equal(q, q_old)


def test_a_compass_trusted_through_a_minute_of_swinging_is_kept_and_the_twin_stops() -> None:
    """Tuning seed 30 (calibrated, the largest excess of the tuning sets) over 180 s: the twin stops once the compass
    has been trusted through `compass_check_evidence_s` (60 s) of swinging, and the output is still that of the
    filter without the twin, bit for bit."""
    case, _, gyr, acc, mag = simulate_seed(30, 180.0, "calibrated", True)
    assert mag is not None
    told = {"rope_length_m": case.physics.rope_length_m, "rope_length_known": True}
    f = HookFilter(HookFilterSettings(**told))  # type: ignore[arg-type]
    assert f.settings.compass_check_evidence_s == 60.0
    q = _run(f, gyr, acc, mag, 10)
    q_old = _run(HookFilter(HookFilterSettings(**told, **COMPASS_ROUND)), gyr, acc, mag, 10)  # type: ignore[arg-type]
    assert f.compass == "trusted" and f._twin is None
    assert np.array_equal(q, q_old)


def test_a_still_hook_pauses_its_twin_and_a_swing_restarts_it_from_the_filter() -> None:
    """A calibrated hook hanging still (8 m, 2 t) for 25 s, then a 600 N tag-line pull for 3 s: once it has hung still
    for `compass_check_still_s` (10 s) the twin is not stepped (its state stands); within 3 s of the true swing
    passing `compass_check_swing_rad` (the filter's swing energy is a running mean) a new twin starts from the
    filter's state; the output is the filter's without the twin, bit for bit (the compass is kept)."""
    from devices.hook_physics import HookPhysicsSettings, HookScenario, Pull, simulate

    physics = HookPhysicsSettings(rope_length_m=8.0, hook_mass_kg=2000.0)
    truth = simulate(physics, HookScenario(duration_s=40.0, pulls=(Pull(25.0, 3.0, (600.0, 0.0)),)))
    sensor = SensorModel(ImuErrorModel.preset("calibrated"), 1, np.random.default_rng(5))
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, 1.0 / RATE_HZ)
    told = {"rope_length_m": 8.0, "rope_length_known": True}
    f = HookFilter(HookFilterSettings(**told))  # type: ignore[arg-type]
    assert f.settings.compass_check_still_s == 10.0
    f.start(gyr[:50], acc[:50], mag[:50], 1.0 / RATE_HZ)
    paused_at = resumed_at = None
    quats = []
    for a in range(0, gyr.shape[0], SPP):
        twin_before = f._twin
        assert twin_before is not None
        x_before, was_paused = twin_before.x.copy(), f._twin_paused
        quats.append(f.run_with_length(gyr[a:a + SPP], acc[a:a + SPP], mag[a:a + SPP], 1.0 / RATE_HZ)[0])
        t_s = (a + SPP) / RATE_HZ
        if f._twin_paused:
            paused_at = t_s if paused_at is None else paused_at
            if was_paused:
                assert f._twin is twin_before and np.array_equal(twin_before.x, x_before)  # not stepped
        elif paused_at is not None and resumed_at is None:
            resumed_at = t_s
            assert f._twin is not twin_before and f._twin is not None and not f._twin.use_mag
            np.testing.assert_array_equal(f._twin.x, f.x)
            np.testing.assert_array_equal(f._twin.P, f.P)
    assert paused_at is not None and 10.0 <= paused_at < 13.0, paused_at
    swings_at = float(truth.t_s[np.argmax(truth.swing_rad > f.settings.compass_check_swing_rad)])
    assert resumed_at is not None and swings_at < resumed_at < swings_at + 3.0, (swings_at, resumed_at)
    assert f.compass_trusted
    q_old = _run(HookFilter(HookFilterSettings(**told, **COMPASS_ROUND)), gyr, acc, mag, SPP)  # type: ignore[arg-type]
    assert np.array_equal(np.concatenate(quats), q_old)


def _torsion_rmse_deg(q: np.ndarray, truth: object, from_s: float) -> float:
    i = round(from_s * RATE_HZ)
    wrapped = np.remainder(hook_geo.torsion(q, 0.0) - truth.torsion_rad + np.pi, 2 * np.pi)  # type: ignore[attr-defined]
    err = np.degrees(wrapped - np.pi)
    return float(np.sqrt(np.mean(err[i:] ** 2)))


def test_a_hook_not_told_its_length_and_swinging_at_start_starts_again_told_what_it_found() -> None:
    """Crane seed 1696 (15 m, swinging 6.3° and twisting at start), not told its rope length: the start is redone
    once the pendulum gives the length (`restart_told_std`, at 6 s), and the torsion from 10 to 60 s is within 1° RMSE
    (measured 0.29°; without the re-start, `RESTART_ROUND`, the compass reference levelled as if plumb: 5.9°);
    the filter still says its length was not configured. One call, 10- and 7-sample packets redo it at the same
    sample and give the same quaternions from then on (it is decided where the compass test runs)."""
    from gateway.fusion.hook_filter import RESTART_ROUND

    case, truth, gyr, acc, mag = simulate_seed(1696, 60.0, "calibrated", True)
    assert mag is not None
    runs, redone = {}, {}
    for calls in (gyr.shape[0], 10, 7):
        f = HookFilter(HookFilterSettings())
        runs[calls] = _run(f, gyr, acc, mag, calls)
        redone[calls] = f.start_redone_s
        assert f.compass_trusted and not f.settings.rope_length_known
    assert redone[gyr.shape[0]] is not None and 2.0 <= redone[gyr.shape[0]] <= 15.0, redone
    assert len(set(redone.values())) == 1, redone
    at = round(redone[gyr.shape[0]] * RATE_HZ)  # `_run` feeds the warm-up window again from sample 0
    for q in runs.values():
        assert np.array_equal(q[at:], runs[gyr.shape[0]][at:])
    without = _run(HookFilter(HookFilterSettings(**RESTART_ROUND)), gyr, acc, mag, 10)  # type: ignore[arg-type]
    assert _torsion_rmse_deg(runs[10], truth, 10.0) < 1.0 < 3.0 < _torsion_rmse_deg(without, truth, 10.0)


@pytest.fixture(scope="module")
def legacy_1740() -> tuple:
    """Suite crane 1740 on the legacy board (5 µT hard iron, 3 % soft iron): with a calibrated board's hard-iron prior
    and no soft iron learnt (`MISLED`) its compass is dropped at 23 s although it was sound (the twin's swing rates
    fit better for a while); the default keeps it (below)."""
    case, truth, gyr, acc, mag = simulate_seed(1740, 120.0, "legacy", True)  # the suite's 2-min timeline
    assert mag is not None
    n = round(40.0 * RATE_HZ)  # its first 40 s
    return case, truth.quat[:n], gyr[:n], acc[:n], mag[:n]


@pytest.mark.parametrize("mode", ["loose", "kept", "twin"])
def test_a_dropped_compass_leaves_the_published_heading_where_it_was(legacy_1740: tuple, mode: str) -> None:
    """At the drop the filter goes on as its twin turned to the heading it had published, not the twin's own (the
    start heading carried by the gyroscope alone for 23 s: 60° off here; `twin`, `DROP_ROUND`). Measured with the
    compass dropped altogether (`kept`: `LOOSE_ROUND`): heading error vs truth 1.8° before the drop, 1.1° 1-3 s
    after (the twin's own: -59.5°), 2.2° RMS from the drop to 40 s (62°); β, the output's North turn, stays at 42.3°
    (it fell to 0), so the gateway's torsion reference does not jump either. The default keeps the compass as a loose
    anchor (`loose`, `compass_dropped_noise_uT`): the same step, and the heading error from the drop to 40 s smaller
    than the dropped compass's (measured 0.91° against 1.60° RMS). 10-sample calls, as the gateway feeds it."""
    case, truth, gyr, acc, mag = legacy_1740
    over = {"loose": {}, "kept": LOOSE_ROUND, "twin": DROP_ROUND}[mode]
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True,
                                      **{**MISLED, **over}))  # type: ignore[arg-type]
    f.start(gyr[:50], acc[:50], mag[:50], 1.0 / RATE_HZ)
    quats, north = [], []
    for a in range(0, gyr.shape[0], 10):
        quats.append(f.run_with_length(gyr[a:a + 10], acc[a:a + 10], mag[a:a + 10], 1.0 / RATE_HZ)[0])
        north.append(f.north_turn_rad)
    q = np.concatenate(quats)
    assert f.compass_dropped_s is not None and 20.0 < f.compass_dropped_s < 26.0, f.compass_dropped_s
    drop = round(f.compass_dropped_s * RATE_HZ)  # `_run`-style feeding: counted from sample 0, as the test counts
    err = np.degrees(np.unwrap(hook_geo.twist_heading(q) - hook_geo.twist_heading(truth)))
    before, after = float(np.mean(err[drop - 300:drop - 100])), float(np.mean(err[drop + 100:drop + 300]))
    if mode == "twin":  # the filter before: the twin's own heading
        assert abs(after - before) > 30.0, (before, after)
        return
    assert abs(after - before) < 5.0, (before, after)
    assert float(np.sqrt(np.mean(err[drop:] ** 2))) < (1.3 if mode == "loose" else 6.0)
    assert north[drop // 10 + 5] == pytest.approx(north[drop // 10 - 20], abs=math.radians(0.5))


@pytest.fixture(scope="module")
def loose_1740(legacy_1740: tuple) -> tuple[HookFilter, np.ndarray, np.ndarray, np.ndarray]:
    """Crane 1740's filter (`MISLED`) 2 s after its compass was dropped and kept loose, and the next 10 samples."""
    case, truth, gyr, acc, mag = legacy_1740
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True,
                                      **MISLED))  # type: ignore[arg-type]
    n = 2600
    _run(f, gyr[:n], acc[:n], mag[:n], 10)
    assert f.compass == "dropped" and f.use_mag
    return f, gyr[n:n + 10], acc[n:n + 10], mag[n:n + 10]


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 2.0 * math.pi), st.floats(-1.0, 1.0), st.floats(1.05, 20.0))
def test_a_loose_compass_far_off_is_not_heard(loose_1740: tuple, azimuth: float, z: float, times_gate: float
                                              ) -> None:  # fmt: skip
    """A dropped compass kept loose (`compass_dropped_noise_uT`) whose reading is more than `compass_dropped_gate_uT`
    off what the filter expects says nothing on that sample: 10 samples each pushed further off than the gate (any
    direction) leave the state as the same samples without a magnetometer do; the same samples as read move it."""
    f0, gyr, acc, mag = loose_1740
    gate = f0.settings.compass_dropped_gate_uT
    push = np.array([math.sqrt(1.0 - z * z) * math.cos(azimuth), math.sqrt(1.0 - z * z) * math.sin(azimuth), z])
    far, heard, deaf = copy.deepcopy(f0), copy.deepcopy(f0), copy.deepcopy(f0)
    far.run_with_length(gyr, acc, mag + (times_gate * gate + 60.0) * push, 1.0 / RATE_HZ)  # 60 µT: past any error
    deaf._run(gyr, acc, None, 1.0 / RATE_HZ, 1.0, None)
    heard.run_with_length(gyr, acc, mag, 1.0 / RATE_HZ)
    np.testing.assert_allclose(far.x, deaf.x, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(far.P, deaf.P, rtol=0.0, atol=1e-15)
    assert abs(heard.x[4] - deaf.x[4]) > 1e-9  # α: the loose compass near what is expected is heard


def test_a_sound_legacy_compass_is_kept_with_the_board_class_hard_iron_prior(legacy_1740: tuple) -> None:
    """The same crane and board with the default 3-µT hard-iron prior: the hard iron is learnt, the compass is not
    dropped, and the heading error over the 40 s is smaller than the dropped compass's (RMS measured 7.3° against
    11.7°)."""
    case, truth, gyr, acc, mag = legacy_1740
    told = {"rope_length_m": case.physics.rope_length_m, "rope_length_known": True}
    heading_rms = []
    for over in ({}, MISLED):
        f = HookFilter(HookFilterSettings(**told, **over))  # type: ignore[arg-type]
        q = _run(f, gyr, acc, mag, 10)
        err = np.degrees(np.unwrap(hook_geo.twist_heading(q) - hook_geo.twist_heading(truth)))[50:]
        heading_rms.append(float(np.sqrt(np.mean(err**2))))
        assert (f.compass_dropped_s is None) == (not over), f.compass_dropped_s
    assert heading_rms[0] < 0.8 * heading_rms[1], heading_rms


def test_a_slow_twist_at_start_is_not_taken_for_the_z_bias_with_a_compass() -> None:
    """Crane 2196 on an error-free board twists at 0.89 °/s through the warm-up with 0.51 °/s of spread, under the
    rest test's 0.57 °/s: with a magnetometer the window's mean z rate is no longer seeded as gyro bias (the compass
    finds the z bias), so the torsion over 0.5-15 s stays within 0.8° (measured 0.74°; 0.52° with the compass's noise
    and hard-iron prior before, `MAG_NOISE_ROUND`; 0.50° without the soft-iron states; it was -2.5° at 9 s with the
    seed, `ZSEED_ROUND`); without one (6D) the z bias is still seeded, nothing else could tell it."""
    case, truth, gyr, acc, mag = simulate_seed(2196, 30.0, "ideal", True)  # (the timeline is drawn over 30 s)
    assert mag is not None
    told = {"rope_length_m": case.physics.rope_length_m, "rope_length_known": True}

    def torsion_err_deg(f: HookFilter, m: np.ndarray | None) -> np.ndarray:
        f.start(gyr[:50], acc[:50], None if m is None else m[:50], 1.0 / RATE_HZ)
        q = f.run(gyr, acc, m, 1.0 / RATE_HZ)
        err = hook_geo.torsion(q, 0.0) - truth.torsion_rad
        return np.degrees(np.abs(np.remainder(err + math.pi, 2.0 * math.pi) - math.pi))[50:1500]

    now, before = HookFilter(HookFilterSettings(**told)), HookFilter(HookFilterSettings(**told, **ZSEED_ROUND))
    assert torsion_err_deg(now, mag).max() < 0.8
    assert torsion_err_deg(before, mag).max() > 2.0  # the seeded twist, taken back by the compass over ~20 s
    six_d = HookFilter(HookFilterSettings(**told), use_mag=False)
    six_d.start(gyr[:50], acc[:50], None, 1.0 / RATE_HZ)
    assert math.degrees(six_d.gyro_bias_rad_s[2]) == pytest.approx(0.885, abs=0.01)
    assert abs(math.degrees(now.gyro_bias_rad_s[2])) < 0.2


def test_a_compass_whose_field_holds_steady_is_not_dropped_on_a_small_excess() -> None:
    """Crane 2371 (6 m, a 30-s trolley move from 9 s) on the calibrated board: from the move on, the twin's swing-rate
    likelihood beat the filter's by 12 a second (its z bias, free in 6D, learnt -2.5 °/s for a true 0.14), and the
    compass was dropped at 20 s; the twin's heading then drifted, torsion 16° off by 60 s (4.5° at most with the
    dropped compass kept as a loose anchor, `compass_dropped_noise_uT`). The field's magnitude held
    steady (its 1-s means within 0.2 µT), which a hard iron turning with the hook would not let it, so the bar stays
    the first 20 s's 600: the compass is kept, torsion within 0.5° RMS and 2.5° at most over 0.5-60 s (measured
    0.29° / 1.94°, the most at 0.7 s, while the start's hard iron is learnt; 0.34° / 0.98° with the compass's noise and
    hard-iron prior before, `MAG_NOISE_ROUND`), the same whatever the call size (one call, 7-sample packets). The
    raw board's drop above (held to a calibrated board's hard-iron prior) still comes; and a steady field's compass
    is still dropped on a larger excess (the next test)."""
    case, truth, gyr, acc, mag = simulate_seed(2371, 120.0, "calibrated", True)  # (the timeline is drawn over 120 s)
    assert mag is not None
    n = 6000
    told = {"rope_length_m": case.physics.rope_length_m, "rope_length_known": True}

    def torsion_err_deg(f: HookFilter, calls: int) -> tuple[np.ndarray, np.ndarray]:
        q = _run(f, gyr[:n], acc[:n], mag[:n], calls)
        err = hook_geo.torsion(q, 0.0) - truth.torsion_rad[:n]
        return q, np.degrees(np.abs(np.remainder(err + math.pi, 2.0 * math.pi) - math.pi))[50:]

    before = HookFilter(HookFilterSettings(**told, **STEADY_ROUND, **LOOSE_ROUND))  # type: ignore[arg-type]
    _, err_before = torsion_err_deg(before, 10)
    assert before.compass == "dropped" and before.compass_dropped_s == 20.0
    assert err_before.max() > 10.0
    loose = HookFilter(HookFilterSettings(**told, **STEADY_ROUND))  # type: ignore[arg-type]
    _, err_loose = torsion_err_deg(loose, 10)  # dropped the same, but kept as a loose anchor: measured 4.5° at most
    assert loose.compass == "dropped" and loose.compass_dropped_s == 20.0
    assert err_loose.max() < 7.0
    quats = {}
    for calls in (n, 7):
        now = HookFilter(HookFilterSettings(**told))  # type: ignore[arg-type]
        quats[calls], err = torsion_err_deg(now, calls)
        assert now.compass_trusted and now.compass_dropped_s is None, calls
        assert float(np.sqrt(np.mean(err**2))) < 0.5 and err.max() < 2.5, calls
    assert np.array_equal(quats[n], quats[7])


def test_a_steady_field_does_not_shield_a_compass_against_a_wrong_reference() -> None:
    """Crane 2413 (2.5 m, swinging at start) on the calibrated board, not told its rope: the start is levelled as if
    plumb, so the compass reference is wrong, and with the compass at its usual noise while the start is pending
    (`PENDING_COMPASS_ROUND`, the filter before 2026-12-07's thirty-third session; the default weighs it as 10 µT
    then and keeps it: Θ 0.105° RMSE over 5-40 s, 0.67° over 0.5-5 s against 9.8°) it misleads the swing though its
    field holds steady (the twin's excess 663 at 3 s and rising). The compass is dropped at 3-4 s with the field
    steady (its 1-s means within 0.5 µT), and Θ stays within 0.3° RMSE / 1° over 5-40 s (measured 0.08° / 0.26°); a
    first version of the steady check that never dropped such a compass read this crane at 66° RMSE."""
    from gateway.fusion.hook_filter import PENDING_COMPASS_ROUND

    case, truth, gyr, acc, mag = simulate_seed(2413, 120.0, "calibrated", True)  # (the timeline is drawn over 120 s)
    assert mag is not None
    n = 4000
    f = HookFilter(HookFilterSettings(**PENDING_COMPASS_ROUND))  # type: ignore[arg-type]
    q = _run(f, gyr[:n], acc[:n], mag[:n], 10)
    assert f.compass == "dropped" and f.compass_dropped_s is not None and f.compass_dropped_s < 5.0
    assert f._field_steady()
    err = np.degrees(hook_geo.swing_angle(q) - truth.swing_rad[:n])[500:]
    assert float(np.sqrt(np.mean(err**2))) < 0.3
    assert np.abs(err).max() < 1.0
