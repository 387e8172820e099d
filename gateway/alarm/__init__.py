"""Alarm layer (pure): rules turn blocks of samples into `Condition`s; `AlarmEngine` turns those into alarm changes.

    rod = RodAlarms("rod-1", thresholds)                      # one per rod; HookAlarms for hooks
    block, conditions = rod.update(t_s, pitch_rad, roll_rad, yaw_rad, acc_up_m_s2, tension_n)
    for change in engine.evaluate(conditions):                # raised / updated / cleared / acknowledged
        store.upsert_alarm(change.alarm); publish(change)

See docs/alarms.md for what each alarm means and its thresholds.
"""

from gateway.alarm.bite import BiteDetector, RodBlock, RodEvent
from gateway.alarm.engine import Alarm, AlarmChange, AlarmEngine, AlarmStatus, Condition, Severity
from gateway.alarm.hook import HookAlarms
from gateway.alarm.rules import ALARM_TYPES, AlarmSpec, RodAlarms

__all__ = [
    "ALARM_TYPES", "Alarm", "AlarmChange", "AlarmEngine", "AlarmSpec", "AlarmStatus", "BiteDetector", "Condition",
    "HookAlarms", "RodAlarms", "RodBlock", "RodEvent", "Severity",
]  # fmt: skip
