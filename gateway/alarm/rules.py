"""Alarm rules: the table of alarm types, a level-with-hysteresis guard, and the rod rules (bite, drop-back,
line guard). Each rule turns a block of samples into engine `Condition`s; none reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gateway.alarm.bite import FloatArray, RodBlock, RodEvent
from gateway.alarm.bite_fast import FastBiteDetector
from gateway.alarm.engine import Condition, DetailValue, Severity
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
LINE_CLEAR_HOLD_S = 2.0  # a line level falls only after the samples stayed below it this long (device time): a fight
# pumping the rod through the hysteresis band at ~1 Hz would otherwise raise and clear the alarm every second


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


def hysteresis_levels(
    values: FloatArray, level: int, thresholds: Sequence[float], hysteresis: float
) -> NDArray[np.int64]:
    """Alarm level after each sample (0 = none, i = thresholds[i-1] passed), starting from `level`.

    Per threshold a latch turns on at a sample >= thr and off at a sample < thr - hysteresis (nan holds); with
    ascending thresholds the latches nest, so the level is how many are on. Sample by sample, so the levels do
    not depend on how the samples were cut into blocks. `thresholds` ascend.
    """
    n = values.size
    out = np.zeros(n, dtype=np.int64)
    idx = np.arange(n)
    with np.errstate(invalid="ignore"):
        for j, thr in enumerate(thresholds):
            step = np.where(values >= thr, 1, np.where(values < thr - hysteresis, -1, 0))
            last = np.maximum.accumulate(np.where(step != 0, idx, -1))
            on = np.where(last >= 0, step[np.maximum(last, 0)] > 0, level > j)
            out += on
    return out


def _nan_max(x: FloatArray | float) -> float:
    """Largest number of an array, skipping nan (nan if none), or the value itself."""
    return float(np.fmax.reduce(x)) if isinstance(x, np.ndarray) else x


def _deg(x_rad: float) -> str:
    return f"{math.degrees(x_rad):.1f}°"


def _event_condition(device_id: str, e: RodEvent) -> Condition:
    """The engine condition of a latch change, with the measured deviation and the threshold it passed."""
    dev_deg, thr_deg = math.degrees(e.deviation_rad), math.degrees(e.threshold_rad)
    details: dict[str, DetailValue] = {"deviation_deg": round(dev_deg, 3), "cue": e.cue}
    if e.kind == "bite":
        how = " (confirmed early by the accel cue)" if e.cue == "accel" else ""
        msg = f"bite: pitch {_deg(-e.deviation_rad)} below rest ≥ θ1 {_deg(-e.threshold_rad)}{how}"
        return Condition(device_id, "bite", Severity.MAJOR, e.t_s, dev_deg, thr_deg, msg, details)
    if e.kind == "drop_back":
        msg = f"drop-back: pitch {_deg(e.deviation_rad)} above rest ≥ {_deg(e.threshold_rad)}"
        return Condition(device_id, "drop_back", Severity.MINOR, e.t_s, dev_deg, thr_deg, msg, details)
    details["peak_deg"] = round(math.degrees(e.peak_rad), 3)
    if e.kind == "bite_rearmed":
        msg = f"pitch back at rest, re-armed (bite peak {_deg(-e.peak_rad)} below rest)"
        return Condition(device_id, "bite", None, e.t_s, dev_deg, thr_deg, msg, details)
    msg = f"pitch back at rest, re-armed (drop-back peak {_deg(e.peak_rad)} above rest)"
    return Condition(device_id, "drop_back", None, e.t_s, dev_deg, thr_deg, msg, details)


class LineGuard:
    """Line-tension alarm of one rod, sample by sample: level 1 (warning) at a drop >= theta2, level 2 (critical)
    at a drop >= line_critical_fraction * theta3 or a reel tension >= tension_warn_fraction * breaking load."""

    def __init__(self, th: RodThresholds, clear_hold_s: float = LINE_CLEAR_HOLD_S) -> None:
        self.level = 0
        self._angle_level = 0
        self._tension_level = 0
        self.clear_hold_s = clear_hold_s
        self._below_since_s: float | None = None  # first sample whose raw level was below `level`
        self._held_level = 0  # highest raw level since then: where the level falls to when the hold ends
        self.set_thresholds(th)

    def set_thresholds(self, th: RodThresholds) -> None:
        """New levels; the current alarm level is kept until the samples say otherwise."""
        self.angle_deg = (th.line_switch_deg, th.line_critical_fraction * th.line_limit_deg)
        self.critical_name = f"{th.line_critical_fraction:g}·θ3"
        self.tension_n = th.tension_warn_fraction * th.line_breaking_n
        self.tension_hyst_n = TENSION_HYSTERESIS_FRACTION * th.line_breaking_n

    def update(self, device_id: str, t_s: FloatArray, block: RodBlock, tension_n: FloatArray | float | None
               ) -> list[Condition]:  # fmt: skip
        """Conditions for every level change in the block, at the sample that caused it. `tension_n` is per sample,
        or one value for every sample (the reel's latest status: no array is made unless the guard needs it)."""
        peak_drop_deg = -math.degrees(block.min_deviation_rad)  # nan (warm-up) counts as quiet
        quiet = self.level == 0 and not peak_drop_deg >= self.angle_deg[0] - LINE_HYSTERESIS_DEG
        if quiet and (tension_n is None or not _nan_max(tension_n) >= self.tension_n - self.tension_hyst_n):
            return []
        if tension_n is not None and not isinstance(tension_n, np.ndarray):
            tension_n = np.full(t_s.shape, tension_n)
        drop_deg = np.degrees(-block.deviation_rad)
        by_angle = hysteresis_levels(drop_deg, self._angle_level, self.angle_deg, LINE_HYSTERESIS_DEG)
        by_tension = (np.zeros(t_s.size, dtype=np.int64) if tension_n is None
                      else hysteresis_levels(tension_n, self._tension_level, (self.tension_n,), self.tension_hyst_n))
        raw = np.maximum(by_angle, 2 * by_tension)
        self._angle_level, self._tension_level = int(by_angle[-1]), int(by_tension[-1])
        out = []
        for k in range(t_s.size):  # per sample: rises at once, falls after clear_hold_s below (no flapping)
            new = self._held(int(raw[k]), float(t_s[k]))
            if new != self.level:
                out.append(self._condition(device_id, float(t_s[k]), new, float(drop_deg[k]), by_tension[k] > 0,
                                           None if tension_n is None else float(tension_n[k])))  # fmt: skip
                self.level = new
        return out

    def _held(self, raw: int, t_s: float) -> int:
        """The level after one sample whose hysteresis level is `raw`: up at once; down to the highest raw level
        of the last `clear_hold_s` once every sample for that long was below the current level."""
        if raw >= self.level:
            self._below_since_s = None
            return raw
        if self._below_since_s is None:
            self._below_since_s, self._held_level = t_s, raw
        self._held_level = max(self._held_level, raw)
        if t_s - self._below_since_s < self.clear_hold_s - 1e-9:
            return self.level
        new = self._held_level
        self._below_since_s = None if raw >= new else t_s
        self._held_level = raw
        return new

    def _condition(self, device_id: str, t_s: float, new: int, drop_deg: float, by_tension: bool,
                   tension_n: float | None) -> Condition:  # fmt: skip
        """Message with the measured value and the threshold it passed (or fell back under)."""
        if new == 0:
            msg = f"line: rod drop back to {drop_deg:.1f}° < {self.angle_deg[0] - LINE_HYSTERESIS_DEG:.1f}°"
            if tension_n is not None:
                msg += f", tension {tension_n:.1f} N < {self.tension_n - self.tension_hyst_n:.1f} N"
            return Condition(device_id, "line_tension", None, t_s, drop_deg, self.angle_deg[0], msg, {"level": 0})
        severity = SPECS["line_tension"].severities[new - 1]
        if by_tension and tension_n is not None:
            msg = f"line: tension {tension_n:.1f} N ≥ {self.tension_n:.1f} N (near breaking)"
            return Condition(device_id, "line_tension", severity, t_s, tension_n, self.tension_n, msg, {"level": new})
        thr = self.angle_deg[new - 1]
        name = "θ2" if new == 1 else self.critical_name
        if new < self.level:
            msg = f"line: rod drop {drop_deg:.1f}°, back under {self.angle_deg[new] - LINE_HYSTERESIS_DEG:.1f}°"
        else:
            msg = f"line: rod drop {drop_deg:.1f}° ≥ {name} {thr:.1f}°"
        return Condition(device_id, "line_tension", severity, t_s, drop_deg, thr, msg, {"level": new})


class RodAlarms:
    """All rod rules for one device: bite / drop-back latches and the line guard (theta2, theta3, tension).

    Every decision is per sample, so the conditions do not depend on how the samples were cut into blocks."""

    def __init__(self, device_id: str, thresholds: RodThresholds | None = None) -> None:
        self.device_id = device_id
        th = thresholds or RodThresholds()
        self.detector = FastBiteDetector(th)  # bite.BiteDetector's results, one numba call per block
        self.line = LineGuard(th)
        self.thresholds = th

    def set_thresholds(self, th: RodThresholds) -> None:
        """Apply new thresholds (REST update) without losing the baseline or active latches."""
        self.thresholds = th
        self.detector.set_thresholds(th)
        self.line.set_thresholds(th)

    def update(
        self,
        t_s: FloatArray,
        pitch_rad: FloatArray,
        roll_rad: FloatArray | None = None,
        yaw_rad: FloatArray | None = None,
        acc_up_m_s2: FloatArray | None = None,
        tension_n: FloatArray | float | None = None,
    ) -> tuple[RodBlock, list[Condition]]:
        """One block (shapes (n,)) -> detector summary and the conditions for the engine, in time order.
        `tension_n` may be one value for the whole block (the reel's latest status)."""
        block = self.detector.update(t_s, pitch_rad, roll_rad, yaw_rad, acc_up_m_s2)
        out = [_event_condition(self.device_id, e) for e in block.events] if block.events else []
        line = self.line.update(self.device_id, t_s, block, tension_n)
        if line:
            out = sorted(out + line, key=lambda c: c.t_s)
        return block, out
