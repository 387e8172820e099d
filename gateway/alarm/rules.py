"""Alarm rules: the table of alarm types, a level-with-hysteresis guard, and the rod rules (bite, drop-back,
line guard). Each rule turns a block of samples into engine `Condition`s; none reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.alarm.bite import BiteDetector, FloatArray, RodBlock, RodEvent
from gateway.alarm.engine import Condition, Severity
from gateway.config import RodThresholds


@dataclass(frozen=True, slots=True)
class AlarmSpec:
    """One alarm type: who raises it, its severities by level (index 1 = first level) and what it means."""

    type: str
    kind: str
    severities: tuple[Severity, ...]
    meaning: str


ALARM_TYPES: tuple[AlarmSpec, ...] = (
    AlarmSpec("bite", "rod", (Severity.MAJOR,), "rod pitch dropped >= theta1 below rest: a fish is biting"),
    AlarmSpec("drop_back", "rod", (Severity.MINOR,), "rod tip rose above rest: slack line, fish swimming towards you"),
    AlarmSpec(
        "line_tension",
        "rod",
        (Severity.WARNING, Severity.CRITICAL),
        "drop >= theta2: pay out line; near theta3 or tension near breaking: line about to break",
    ),
    AlarmSpec("hook_swing", "hook", (Severity.WARNING, Severity.CRITICAL), "hook swing angle Theta over limit"),
    AlarmSpec("hook_torsion", "hook", (Severity.WARNING, Severity.CRITICAL), "hook twist phi about rope over limit"),
    AlarmSpec("device_conflict", "any", (Severity.CRITICAL,),
              "two publishers on one device's keys (spoofing or a duplicated id); raised by ingest, clears 10 s after"),
)
SPECS: dict[str, AlarmSpec] = {s.type: s for s in ALARM_TYPES}

LINE_HYSTERESIS_DEG = 2.0  # line-guard angle levels clear this far below their threshold
TENSION_HYSTERESIS_FRACTION = 0.05  # ... and tension this share of the breaking load below its threshold


def hysteresis_level(peak: float, level: int, thresholds: Sequence[float], hysteresis: float) -> int:
    """Alarm level (0 = none, i = thresholds[i-1] passed) after a block whose largest value is `peak`.

    Rises as soon as the peak reaches a threshold; falls only once the peak is below threshold - hysteresis.
    `thresholds` ascend.
    """
    raised = sum(peak >= thr for thr in thresholds)
    kept = sum(peak >= thr - hysteresis for thr in thresholds)
    return max(raised, min(level, kept))


class LevelGuard:
    """A metric with ascending thresholds, hysteresis and one alarm type; emits a Condition when the level changes."""

    def __init__(self, alarm_type: str, thresholds: Sequence[float], hysteresis: float, unit: str) -> None:
        self.spec = SPECS[alarm_type]
        self.thresholds = tuple(thresholds)
        self.hysteresis = hysteresis
        self.unit = unit
        self.level = 0

    def update(
        self,
        device_id: str,
        t_s: FloatArray,
        values: FloatArray | Callable[[], FloatArray],
        label: str,
        peak: float | None = None,
    ) -> Condition | None:
        """Feed one block of non-negative values; returns a Condition if the level changed, else None.

        With `peak` given, `values` may be a callable that is only evaluated when the level changes.
        """
        if peak is None:
            values = values() if callable(values) else values
            if values.size == 0:
                return None
            peak = float(values.max())
        new = hysteresis_level(peak, self.level, self.thresholds, self.hysteresis)
        if new == self.level:
            return None
        rising = new > self.level
        self.level = new
        values = values() if callable(values) else values
        if new == 0:
            return Condition(device_id, self.spec.type, None, float(t_s[-1]), peak, self.thresholds[0],
                             f"{label} back to {peak:.1f} {self.unit}")  # fmt: skip
        thr = self.thresholds[new - 1]
        t = float(t_s[int(np.argmax(values >= thr))]) if rising else float(t_s[-1])
        severity = self.spec.severities[min(new, len(self.spec.severities)) - 1]
        return Condition(device_id, self.spec.type, severity, t, peak, thr,
                         f"{label} {peak:.1f} {self.unit} >= {thr:.1f} {self.unit}")  # fmt: skip


def _event_condition(device_id: str, e: RodEvent) -> Condition:
    dev_deg, thr_deg = math.degrees(e.deviation_rad), math.degrees(e.threshold_rad)
    details = {"deviation_deg": round(dev_deg, 3), "cue": e.cue}
    if e.kind == "bite":
        msg = f"bite: pitch {-dev_deg:.1f} deg below rest (threshold {-thr_deg:.1f} deg, by {e.cue})"
        return Condition(device_id, "bite", Severity.MAJOR, e.t_s, dev_deg, thr_deg, msg, details)
    if e.kind == "drop_back":
        msg = f"drop-back: pitch {dev_deg:.1f} deg above rest (threshold {thr_deg:.1f} deg)"
        return Condition(device_id, "drop_back", Severity.MINOR, e.t_s, dev_deg, thr_deg, msg, details)
    alarm_type = "bite" if e.kind == "bite_rearmed" else "drop_back"
    return Condition(device_id, alarm_type, None, e.t_s, dev_deg, thr_deg, "pitch back at rest: re-armed", details)


class RodAlarms:
    """All rod rules for one device: bite / drop-back latches and the line guard (theta2, theta3, tension)."""

    def __init__(self, device_id: str, thresholds: RodThresholds | None = None) -> None:
        self.device_id = device_id
        self.detector = BiteDetector(thresholds)
        self._angle = LevelGuard("line_tension", (0.0, 0.0), LINE_HYSTERESIS_DEG, "deg")
        self._tension = LevelGuard("line_tension", (0.0,), 0.0, "N")
        self._level = 0
        self.set_thresholds(thresholds or RodThresholds())

    def set_thresholds(self, th: RodThresholds) -> None:
        """Apply new thresholds (REST update) without losing the baseline or active latches."""
        self.thresholds = th
        self.detector.set_thresholds(th)
        self._angle.thresholds = (th.line_switch_deg, th.line_critical_fraction * th.line_limit_deg)
        self._tension.thresholds = (th.tension_warn_fraction * th.line_breaking_n,)
        self._tension.hysteresis = TENSION_HYSTERESIS_FRACTION * th.line_breaking_n

    def update(
        self,
        t_s: FloatArray,
        pitch_rad: FloatArray,
        roll_rad: FloatArray | None = None,
        yaw_rad: FloatArray | None = None,
        acc_up_m_s2: FloatArray | None = None,
        tension_n: FloatArray | None = None,
    ) -> tuple[RodBlock, list[Condition]]:
        """One block (shapes (n,)) -> detector summary and the conditions for the engine."""
        block = self.detector.update(t_s, pitch_rad, roll_rad, yaw_rad, acc_up_m_s2)
        out = [_event_condition(self.device_id, e) for e in block.events]
        line = self._line(t_s, block, lambda: pitch_rad - block.baseline_rad, tension_n)
        if line is not None:
            out.append(line)
        return block, out

    def _line(
        self, t_s: FloatArray, block: RodBlock, dev_rad: Callable[[], FloatArray], tension_n: FloatArray | None
    ) -> Condition | None:
        """Line guard: level = max(angle level, tension level); tension has only the critical level."""
        by_angle = self._angle.update(
            self.device_id, t_s, lambda: np.degrees(-dev_rad()), "rod drop", math.degrees(-block.min_deviation_rad)
        )
        by_tension = None
        if tension_n is not None:
            by_tension = self._tension.update(self.device_id, t_s, tension_n, "line tension")
        new = max(self._angle.level, 2 * self._tension.level)
        if new == self._level:
            return None
        self._level = new
        source = by_tension if self._tension.level and by_tension is not None else by_angle or by_tension
        assert source is not None
        severity = None if new == 0 else SPECS["line_tension"].severities[new - 1]
        return Condition(self.device_id, "line_tension", severity, source.t_s, source.value, source.threshold,
                         source.message, {"level": new})  # fmt: skip
