"""Fish-walking controller: safety rules (timeout, manual takeover, θ2 cap, θ3 guard, hysteresis) and a short fight."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.control.fish_walking import (
    BangBang,
    DragOnly,
    FishWalkingController,
    FishWalkingSettings,
    Observation,
    estimated_tension_n,
)
from gateway.control.pid import PidSettings

S = FishWalkingSettings()  # θ2 20°, θ3 35°, breaking 100 N, linear bend curve
DT = 0.02


def obs(t, bend_rad, rate=0.0, tension=None, line=30.0):
    return Observation(t, -bend_rad, -rate, tension, line)


def run_steady(c, bend_rad, n=150, **kw):
    return [c.step(k * DT, obs(k * DT, bend_rad, **kw)) for k in range(n)]


def test_reels_in_when_slack_and_pays_out_beyond_theta2():
    assert run_steady(FishWalkingController(), 0.02)[-1].speed_m_s > 0.0
    last = run_steady(FishWalkingController(), S.theta2_rad * 1.05)[-1]
    assert last.speed_m_s <= -S.min_payout_m_s


def test_data_timeout_stops_the_motor():
    c = FishWalkingController()
    for k in range(150):
        assert c.step(k * DT, obs(k * DT, 0.02)).speed_m_s >= 0.0
    t_last = 149 * DT
    assert c.step(t_last + 0.2, None).reason != "timeout"  # within the 0.3 s budget
    d = c.step(t_last + S.attitude_timeout_s + 0.01, None)
    assert (d.action, d.speed_m_s, d.reason) == ("stop", 0.0, "timeout")
    # A stale sample (old time stamp) is no better than none.
    d = c.step(5.0, obs(4.0, 0.02))
    assert d.reason == "timeout" and d.speed_m_s == 0.0
    # Fresh data resumes control.
    assert c.step(5.02, obs(5.02, 0.02)).reason != "timeout"


def test_manual_takeover_overrides_everything_until_re_enabled():
    c = FishWalkingController()
    run_steady(c, 0.02)
    c.manual(-0.4)
    for k in range(10):  # even past θ3 and with no data, the angler's command stands
        d = c.step(1.0 + k * DT, obs(1.0 + k * DT, S.theta3_rad * 1.1) if k % 2 else None)
        assert (d.speed_m_s, d.reason) == (-0.4, "manual")
    c.enable()
    d = c.step(2.0, obs(2.0, 0.02))
    assert d.reason != "manual"
    assert c.cascade.inner.state.integral == 0.0  # reset on enable


def test_disable_stops():
    c = FishWalkingController()
    c.disable()
    assert c.step(0.0, obs(0.0, 0.02)).action == "stop"


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.2, 1.0), st.floats(-3.0, 3.0), st.booleans()), min_size=1, max_size=60))
def test_never_reels_in_at_or_above_theta2(samples):
    c = FishWalkingController(FishWalkingSettings(min_payout_m_s=0.1))
    for k, (bend, rate, lost) in enumerate(samples):
        t = k * DT
        d = c.step(t, None if lost else obs(t, bend, rate))
        if not lost and bend >= S.theta2_rad:
            assert d.speed_m_s <= -0.1
    c = FishWalkingController()  # default: stop at θ2 and let the drag give line
    for k, (bend, rate, lost) in enumerate(samples):
        d = c.step(k * DT, None if lost else obs(k * DT, bend, rate))
        if not lost and bend >= S.theta2_rad:
            assert d.speed_m_s <= 0.0


def test_tension_guard_uses_the_load_cell_when_there_is_one():
    # 0.8·θ3 reads 80 N on the linear bend curve (guard at 75 N); a load cell says 30 N.
    bend = 0.8 * S.theta3_rad
    d = run_steady(FishWalkingController(), bend, tension=30.0)[-1]
    assert d.reason != "tension_guard" and d.speed_m_s <= 0.0  # above θ2: not reeling in, not guard pay-out
    d = run_steady(FishWalkingController(FishWalkingSettings(trust_load_cell=False)), bend, tension=30.0)[-1]
    assert d.reason == "tension_guard"
    d = run_steady(FishWalkingController(), 0.02, tension=S.payout_fraction * S.line_breaking_n + 1.0)[-1]
    assert (d.reason, d.speed_m_s) == ("tension_guard", -S.max_out_m_s)  # the load cell alone trips it


@pytest.mark.parametrize(
    ("bend_rad", "tension_n"),
    [(0.95 * math.radians(35.0), None), (0.02, 80.0), (0.8 * math.radians(35.0), None)],
)
def test_pays_out_hard_near_theta3(bend_rad, tension_n):
    # 0.95·θ3 ⇒ T̂ = 95 N; a load-cell reading of 80 N; 0.8·θ3 ⇒ 80 N: all above the 75 % guard.
    d = run_steady(FishWalkingController(), bend_rad, tension=tension_n)[-1]
    assert (d.speed_m_s, d.reason) == (-S.max_out_m_s, "tension_guard")


def test_tension_guard_releases_only_below_the_hold_level():
    c = FishWalkingController()
    run_steady(c, 0.8 * S.theta3_rad, n=5)  # trips (80 N)
    d = [c.step(1 + k * DT, obs(1 + k * DT, 0.7 * S.theta3_rad)) for k in range(20)][-1]  # 70 N: still guarded
    assert d.reason == "tension_guard"
    d = [c.step(2 + k * DT, obs(2 + k * DT, 0.3 * S.theta3_rad)) for k in range(20)][-1]  # 30 N: released
    assert d.reason != "tension_guard"


def test_direction_hysteresis_prevents_chatter():
    # P-only loops: speed = kp_i·kp_o·(setpoint − bend) ≈ ±0.05 m/s, inside the on-threshold (0.08 m/s).
    gains = {"angle": PidSettings(1.0), "rate": PidSettings(1.0), "measurement_filter_s": 1e-6, "cruise_in_m_s": 0.0}
    gains["setpoint_fraction"] = 0.8  # setpoint ± 0.05 rad stays below θ2, so the θ2 cap is not involved
    sp = 0.8 * S.theta2_rad

    def changes(**kw):
        c = FishWalkingController(FishWalkingSettings(**gains, **kw))
        actions = [c.step(k * DT, obs(k * DT, sp + (0.05 if k % 2 else -0.05))).action for k in range(100)]
        return sum(a != b for a, b in zip(actions, actions[1:], strict=False))

    assert changes() == 0
    assert changes(on_threshold_m_s=0.0, off_threshold_m_s=0.0, reverse_dwell_s=0.0) > 50  # what it prevents


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 2.0), st.floats(0.0, 2.0))
def test_tension_estimate_is_monotonic_in_bend(a, b):
    curve = ((0.0, 1.0), (0.3, 10.0), (0.5, 30.0), (0.6, 40.0))
    s = FishWalkingSettings(theta2_rad=0.4, theta3_rad=0.6, tension_curve=curve)
    lo, hi = sorted((a, b))
    assert estimated_tension_n(s, lo, None) <= estimated_tension_n(s, hi, None)
    assert estimated_tension_n(s, 0.6, None) == pytest.approx(40.0)
    assert estimated_tension_n(s, 0.4, None) == pytest.approx(20.0)  # interpolated between 0.3 and 0.5


def test_baselines():
    bb = BangBang(theta2_rad=0.3, max_in_m_s=1.0, max_out_m_s=2.0)
    assert bb.step(0.0, obs(0.0, 0.29)).speed_m_s == 1.0
    assert bb.step(0.1, obs(0.1, 0.31)).speed_m_s == -2.0
    assert bb.step(0.2, None).speed_m_s == -2.0  # keeps acting on the newest data
    assert bb.step(0.3, obs(0.3, 0.1, line=0.5)).action == "stop"  # landed
    assert DragOnly().step(0.0, obs(0.0, 0.5)).action == "stop"


def test_command_fields_map_to_reel_command():
    c = FishWalkingController()
    d = run_steady(c, 0.02)[-1]
    assert d.speed_m_s > 0.0
    assert d.command_fields() == {"action": "speed", "speed_m_s": d.speed_m_s, "drag_n": 0.6 * S.line_breaking_n}
    c.disable()
    assert c.step(5.0, None).command_fields() == {"action": "stop"}  # off: the angler's drag stays


def test_short_closed_loop_fight_lands_without_breaking_the_line():
    # Locked spool (drag 60 N > 40 N breaking): a fresh 6 kg fish breaks the line unless the policy acts.
    fights = pytest.importorskip("bench.fights")
    kw = {"seed": 3, "horizon_s": 60.0, "fish": [(6.0, 1.0), (1.0, 0.3)], "drag_n": 60.0, "detect_delay_s": 0.0}
    res = fights.run_fights("cascade", 0, progress=False, **kw)
    assert all(r.outcome != "escaped" for r in res)
    assert all(r.max_tension_frac < 0.7 for r in res)  # the controller's drag request (60 %) caps it
    assert res[1].outcome == "landed" and np.isfinite(res[1].time_s)
    baseline = fights.run_fights("drag_only", 0, progress=False, **kw)
    assert baseline[0].outcome == "escaped"  # what the controller prevented


def test_fish_walking_lands_faster_than_bang_bang_and_breaks_nothing():
    # 5 seeded fights (seed 7, the tuning seed; held-out figures in docs/control.md), rod defaults, load cell on.
    fights = pytest.importorskip("bench.fights")
    res = {p: fights.run_fights(p, 5, 7, horizon_s=90.0, progress=False) for p in ("bang_bang", "cascade")}
    times = {p: [r.time_s if r.outcome == "landed" else 90.0 for r in rs] for p, rs in res.items()}  # unlanded: 90
    assert not any(r.outcome == "escaped" for rs in res.values() for r in rs), times
    assert all(r.outcome == "landed" for r in res["cascade"]), times
    assert np.mean(times["cascade"]) < 0.9 * np.mean(times["bang_bang"]), times
    assert np.median(times["cascade"]) < np.median(times["bang_bang"]), times
