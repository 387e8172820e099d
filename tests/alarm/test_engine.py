"""Alarm lifecycle (raise / update / acknowledge / clear), hysteresis levels and the hook rules."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.alarm.engine import AlarmEngine, AlarmStatus, Condition, Severity
from gateway.alarm.hook import HookAlarms, wrap_abs_deg
from gateway.alarm.rules import ALARM_TYPES, hysteresis_level
from gateway.config import HookThresholds


def make_engine() -> AlarmEngine:
    counter = itertools.count()
    return AlarmEngine(id_factory=lambda: f"id{next(counter)}")


def cond(sev: Severity | None, t: float, value: float = 1.0, device: str = "d1", kind: str = "hook_swing"):
    return Condition(device, kind, sev, t, value, 5.0, f"value {value}")


def test_lifecycle_raise_update_ack_clear():
    e = make_engine()
    [raised] = e.evaluate([cond(Severity.WARNING, 1.0, 6.0)])
    assert raised.kind == "raised" and raised.alarm.status is AlarmStatus.ACTIVE and raised.alarm.started_at == 1.0
    assert e.evaluate([cond(Severity.WARNING, 1.5, 6.0)]) == []  # identical: no change, no duplicate
    [upd] = e.evaluate([cond(Severity.WARNING, 2.0, 7.0)])
    assert upd.kind == "updated" and upd.alarm.id == raised.alarm.id
    assert (upd.alarm.count, upd.alarm.peak, upd.alarm.started_at, upd.alarm.updated_at) == (2, 7.0, 1.0, 2.0)
    ack = e.acknowledge(raised.alarm.id, "ops", 3.0)
    assert ack is not None and ack.kind == "acknowledged"
    assert ack.alarm.acknowledged and ack.alarm.status is AlarmStatus.ACTIVE  # ack does not clear
    assert e.acknowledge(raised.alarm.id, "ops", 3.5) is None  # already acknowledged
    [down] = e.evaluate([cond(Severity.WARNING, 4.0, 5.5)])
    assert down.alarm.acknowledged and down.alarm.peak == 7.0  # same severity keeps the ack; peak is kept
    [clr] = e.evaluate([cond(None, 5.0)])
    assert clr.kind == "cleared" and clr.alarm.status is AlarmStatus.CLEARED and clr.alarm.cleared_at == 5.0
    assert e.active() == [] and e.evaluate([cond(None, 6.0)]) == []
    [again] = e.evaluate([cond(Severity.WARNING, 7.0)])
    assert again.kind == "raised" and again.alarm.id != raised.alarm.id


def test_escalation_resets_acknowledgement():
    e = make_engine()
    [r] = e.evaluate([cond(Severity.WARNING, 1.0)])
    e.acknowledge(r.alarm.id, "ops", 2.0)
    [u] = e.evaluate([cond(Severity.CRITICAL, 3.0, 12.0)])
    assert u.alarm.severity is Severity.CRITICAL and not u.alarm.acknowledged and u.alarm.acknowledged_by is None


def test_one_active_alarm_per_device_and_type():
    e = make_engine()
    changes = e.evaluate(
        [cond(Severity.WARNING, 1.0), cond(Severity.CRITICAL, 1.1, 9.0), cond(Severity.WARNING, 1.2, kind="other"),
         cond(Severity.WARNING, 1.3, device="d2")]
    )  # fmt: skip
    assert [c.kind for c in changes] == ["raised", "updated", "raised", "raised"]
    assert len(e.active()) == 3 and len(e.active("d1")) == 2
    assert e.active("d1")[0].severity is Severity.CRITICAL  # most severe first
    assert [c.kind for c in e.forget_device("d1", 2.0)] == ["cleared", "cleared"]


def test_engine_resumes_from_stored_active_alarms():
    e1 = make_engine()
    [r] = e1.evaluate([cond(Severity.WARNING, 1.0)])
    e2 = AlarmEngine(active=e1.active())
    [u] = e2.evaluate([cond(Severity.WARNING, 2.0, 8.0)])
    assert u.kind == "updated" and u.alarm.id == r.alarm.id


def test_alarm_table_types_are_unique():
    assert len({s.type for s in ALARM_TYPES}) == len(ALARM_TYPES)


@pytest.mark.parametrize(
    ("peak", "level", "expect"),
    [(4.9, 0, 0), (5.0, 0, 1), (4.5, 1, 1), (3.9, 1, 0), (10.0, 1, 2), (9.2, 2, 2), (8.9, 2, 1), (12.0, 0, 2)],
)
def test_hysteresis_level_reference_table(peak, level, expect):
    assert hysteresis_level(peak, level, (5.0, 10.0), 1.0) == expect


@given(st.lists(st.floats(0.0, 20.0), min_size=1, max_size=50), st.floats(0.0, 3.0))
def test_hysteresis_level_never_flips_inside_the_band(peaks, hyst):
    """Property: the level changes only if the peak is at/above a threshold (rise) or below threshold - hyst."""
    thresholds = (5.0, 10.0)
    level = 0
    for p in peaks:
        new = hysteresis_level(p, level, thresholds, hyst)
        if new > level:
            assert p >= thresholds[new - 1]
        elif new < level:
            assert p < thresholds[new] - hyst
        level = new


def test_hook_swing_hysteresis_and_torsion_wrap():
    # swing 5 / 10 deg, torsion 30 / 60 deg, hysteresis 1 deg; no hold-off, to see the hysteresis alone
    hook = HookAlarms("hook-1", HookThresholds(), clear_hold_s=0.0)
    engine = make_engine()
    seq_deg = [0.0, 6.0, 4.5, 5.5, 4.2, 3.9, 11.0, 9.5, 8.0, 2.0]
    log = []
    for i, s in enumerate(seq_deg):
        t = np.array([i + 0.0, i + 0.5])
        changes = engine.evaluate(hook.update(t, np.radians([s, s]), np.radians([350.0, 355.0])))
        log += [(i, c.kind, c.alarm.type, c.alarm.severity.value) for c in changes]
    assert log == [
        (1, "raised", "hook_swing", "warning"),
        (5, "cleared", "hook_swing", "warning"),  # 4.5 and 4.2 stay inside the 1 deg band; 3.9 clears
        (6, "raised", "hook_swing", "critical"),
        (8, "updated", "hook_swing", "warning"),  # 9.5 holds critical, 8.0 drops to warning
        (9, "cleared", "hook_swing", "warning"),
    ]  # torsion 350 deg = -10 deg: never alarms


def test_hook_torsion_raises_at_sample_time():
    hook = HookAlarms("hook-1")
    t = np.arange(5) * 0.1
    w, c = hook.update(t, np.zeros(5), np.radians([0.0, 10.0, 31.0, 65.0, 20.0]))  # per sample: warning, critical
    assert (w.type, w.severity, w.t_s, w.threshold) == ("hook_torsion", Severity.WARNING, pytest.approx(0.2), 30.0)
    assert (c.type, c.severity, c.t_s, c.threshold) == ("hook_torsion", Severity.CRITICAL, pytest.approx(0.3), 60.0)


def test_wrap_abs_deg_reference_values():
    np.testing.assert_allclose(wrap_abs_deg(np.radians([0.0, 190.0, -190.0, 350.0, 720.0 + 45.0])),
                               [0.0, 170.0, 170.0, 10.0, 45.0], atol=1e-9)  # fmt: skip


def _run_hook(hook, engine, torsion_deg, rate_hz=100.0, block=10, t0=0.0):
    changes = []
    for k in range(0, len(torsion_deg), block):
        t = t0 + np.arange(k, min(k + block, len(torsion_deg))) / rate_hz
        tor = np.radians(torsion_deg[k : k + block])
        changes += engine.evaluate(hook.update(t, np.zeros(len(t)), tor))
    return changes


def test_hook_torsion_oscillating_around_the_limit_raises_once_then_clears_after_the_hold():
    """Issue 17: torsion swinging 25..35 deg around the 30 deg warning flapped on every half period."""
    hook, engine = HookAlarms("hook-1"), make_engine()  # default hold-off 10 s, hysteresis 1 deg
    t = np.arange(0, 60.0, 0.01)
    flapping = _run_hook(hook, engine, 30.0 + 5.0 * np.sin(2 * np.pi * t / 6.0))
    assert [(c.kind, c.alarm.severity.value) for c in flapping] == [("raised", "warning")]
    raised = flapping[0].alarm
    assert raised.value >= raised.threshold == 30.0 and "≥ warning limit 30.0°" in raised.message
    calm = _run_hook(hook, engine, np.full(2000, 10.0), t0=60.0)  # 20 s at 10 deg
    [cleared] = calm
    assert cleared.kind == "cleared"
    assert cleared.alarm.cleared_at == pytest.approx(60.0 + 10.0, abs=0.11)  # after the 10 s hold, not at once
    assert "peak 35.0°" in cleared.alarm.message and "back to 10.0°" in cleared.alarm.message


def test_hook_hold_off_without_hold_would_flap():
    """The same signal with no hold-off: the test above can fail (hysteresis alone flaps)."""
    hook, engine = HookAlarms("hook-1", clear_hold_s=0.0), make_engine()
    t = np.arange(0, 60.0, 0.01)
    changes = _run_hook(hook, engine, 30.0 + 5.0 * np.sin(2 * np.pi * t / 6.0))
    assert sum(c.kind == "raised" for c in changes) >= 5
