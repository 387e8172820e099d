"""Crane-hook rules: swing angle Theta (seed 001 eq. 6, cos Theta = cos(theta_x) cos(theta_y)) and torsion phi
about the rope (seed 001 eq. 1-3), each with a warning and a critical threshold, clearing hysteresis and a hold-off.

A hook swings and twists back and forth: the value crosses a limit every half period, so hysteresis alone lets an
alarm flap (issue 17: 38 of 95 rows in 20 min were torsion warnings around 30 deg). A level therefore rises at once
but falls only after the value has stayed below `threshold - hysteresis` for `clear_hold_s` seconds. Both are
decided sample by sample in device time (issue 11): the alarms do not depend on how samples were packetized.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from gateway.alarm.bite import FloatArray
from gateway.alarm.engine import Condition
from gateway.alarm.rules import SPECS
from gateway.config import HookThresholds

CLEAR_HOLD_S = 10.0
"""Default hold-off: seconds below the clearing level before an alarm level falls (longer than a hook's swing or
torsion period, ~6 s for a 10 m rope)."""


def wrap_abs_deg(angle_rad: FloatArray) -> FloatArray:
    """|angle| in degrees after wrapping to (-180, 180]: a twist of 350 deg is 10 deg the other way."""
    wrapped: FloatArray = np.abs(np.degrees(np.angle(np.exp(1j * angle_rad))))
    return wrapped


class HeldLevel:
    """One metric (deg, >= 0) against ascending limits: rises at once, falls after `hold_s` below the band.

    Judged sample by sample in device time, so the same samples give the same conditions however they were cut
    into packets and blocks. Emits a Condition only when the level changes: on a rise `value` is the sample that
    crossed the limit, on a fall the episode's peak; `threshold` is the limit the message names, so the message
    never contradicts the numbers.
    """

    def __init__(self, alarm_type: str, label: str, names: Sequence[str]) -> None:
        self.spec = SPECS[alarm_type]
        self.label = label
        self.names = tuple(names)  # "warning", "critical": what each level is called in messages
        self.limits: tuple[float, ...] = ()
        self.hysteresis = 0.0
        self.hold_s = CLEAR_HOLD_S
        self.level = 0
        self.below_since: float | None = None  # device time of the first sample under the current level's band
        self.episode_peak = 0.0

    def update(self, device_id: str, t_s: FloatArray, values: FloatArray, peak: float | None = None,
               low: float | None = None) -> list[Condition]:  # fmt: skip
        """The level changes over one block of samples (t_s, values), in order; `peak` and `low`: the block's
        max and min when the caller has them (`hook_rules`: one reduction for every hook of a batch)."""
        if values.size == 0 or not self.limits:
            return []
        if peak is None:
            peak = float(values.max())
        if self.level == 0 and peak < self.limits[0]:
            return []  # fast path: calm
        if self.level and peak < (self.limits[self.level] if self.level < len(self.limits) else math.inf):
            band = self.limits[self.level - 1] - self.hysteresis
            if (float(values.min()) if low is None else low) >= band:  # fast path: holding the level
                self.episode_peak = max(self.episode_peak, peak)
                self.below_since = None
                return []
        out: list[Condition] = []
        for t, v in zip(t_s.tolist(), values.tolist(), strict=True):
            c = self._sample(device_id, t, v)
            if c is not None:
                out.append(c)
        return out

    def _sample(self, device_id: str, t: float, v: float) -> Condition | None:
        raised = sum(v >= thr for thr in self.limits)
        if raised > self.level:
            self.level, self.below_since = raised, None
            self.episode_peak = max(self.episode_peak, v)
            thr = self.limits[raised - 1]
            msg = f"{self.label} {v:.1f}° ≥ {self.names[raised - 1]} limit {thr:.1f}°"
            return self._condition(device_id, t, v, thr, msg)
        if self.level == 0:
            return None
        self.episode_peak = max(self.episode_peak, v)
        kept = sum(v >= thr - self.hysteresis for thr in self.limits)
        if kept >= self.level:
            self.below_since = None
            return None
        if self.below_since is None:
            self.below_since = t
        if t - self.below_since < self.hold_s:
            return None
        old = self.level
        self.level, self.below_since = kept, None
        band = self.limits[old - 1] - self.hysteresis
        held = f"below {band:.1f}° for {self.hold_s:g} s, peak {self.episode_peak:.1f}°"
        if self.level == 0:
            msg = f"{self.label} back to {v:.1f}° ({held}); {self.names[0]} limit {self.limits[0]:.1f}°"
            c = Condition(device_id, self.spec.type, None, t, self.episode_peak, self.limits[0], msg)
            self.episode_peak = 0.0
            return c
        thr = self.limits[self.level - 1]
        msg = f"{self.label} {v:.1f}° ({held}): {self.names[self.level - 1]}, limit {thr:.1f}°"
        return self._condition(device_id, t, self.episode_peak, thr, msg)

    def _condition(self, device_id: str, t: float, value: float, thr: float, msg: str) -> Condition:
        severity = self.spec.severities[min(self.level, len(self.spec.severities)) - 1]
        return Condition(device_id, self.spec.type, severity, t, value, thr, msg, {"unit": "deg", "level": self.level})


class HookAlarms:
    """Swing and torsion guards for one hook device."""

    def __init__(self, device_id: str, thresholds: HookThresholds | None = None, clear_hold_s: float = CLEAR_HOLD_S):
        self.device_id = device_id
        self.swing = HeldLevel("hook_swing", "swing Θ", ("warning", "critical"))
        self.torsion = HeldLevel("hook_torsion", "torsion φ", ("warning", "critical"))
        self.swing.hold_s = self.torsion.hold_s = clear_hold_s
        self.set_thresholds(thresholds or HookThresholds())

    def set_thresholds(self, th: HookThresholds) -> None:
        """Apply new thresholds; current levels are kept and re-judged on the next block."""
        self.thresholds = th
        self.swing.limits = (th.swing_warn_deg, th.swing_critical_deg)
        self.torsion.limits = (th.torsion_warn_deg, th.torsion_critical_deg)
        self.swing.hysteresis = self.torsion.hysteresis = th.hysteresis_deg

    def update(self, t_s: FloatArray, swing_rad: FloatArray, torsion_rad: FloatArray) -> list[Condition]:
        """One block, shapes (n,): swing angle Theta >= 0 and torsion phi, both in radians."""
        return self.update_deg(t_s, swing_deg(swing_rad), wrap_abs_deg(torsion_rad))

    def update_deg(self, t_s: FloatArray, swing_deg: FloatArray, torsion_deg: FloatArray,
                   extremes: tuple[float, float, float, float] | None = None) -> list[Condition]:  # fmt: skip
        """`update` with the metrics as the guards judge them (`swing_deg`, `wrap_abs_deg`) and optionally their
        (swing max, swing min, torsion max, torsion min) over the block."""
        s_max, s_min, t_max, t_min = extremes or (None, None, None, None)
        out = self.swing.update(self.device_id, t_s, swing_deg, s_max, s_min)
        out += self.torsion.update(self.device_id, t_s, torsion_deg, t_max, t_min)
        return sorted(out, key=lambda c: c.t_s)  # in device-time order, as they happened, whatever the block


def swing_deg(swing_rad: FloatArray) -> FloatArray:
    """|Theta| in degrees, as the swing guard judges it."""
    deg: FloatArray = np.abs(swing_rad) * (180.0 / math.pi)
    return deg


def hook_rules(rules: Sequence[HookAlarms], t_s: FloatArray, swing_rad: FloatArray, torsion_rad: FloatArray,
               start: NDArray[np.int64], stop: NDArray[np.int64], held: Sequence[bool] | None = None
               ) -> list[list[Condition] | Exception]:  # fmt: skip
    """`HookAlarms.update` of many hooks over their concatenated blocks (rows start[i]:stop[i] are hook i's): the
    degrees and each block's max and min are computed once for all (element-wise and exact, so every hook gets
    what it gets alone); the guards then run per hook. A hook whose rules raise gets its exception (it alone
    restarts). `held[i]`: hook i is not judged on this block (its filter's start may still be redone, see
    `HookFilter.start_pending`): no conditions, its guards unchanged."""
    s_deg, t_deg = swing_deg(swing_rad), wrap_abs_deg(torsion_rad)
    if len(rules) and bool((stop > start).all()):
        ext = zip(*(f.reduceat(x, start).tolist() for x in (s_deg, t_deg) for f in (np.maximum, np.minimum)),
                  strict=True)  # fmt: skip
        extremes: list[tuple[float, float, float, float] | None] = list(ext)
    else:
        extremes = [None] * len(rules)
    out: list[list[Condition] | Exception] = []
    for k, (r, a, b, e) in enumerate(zip(rules, start.tolist(), stop.tolist(), extremes, strict=True)):
        if held is not None and held[k]:  # not judged yet: its rules see none of these samples
            out.append([])
            continue
        try:
            out.append(r.update_deg(t_s[a:b], s_deg[a:b], t_deg[a:b], e))
        except Exception as exc:
            out.append(exc)
    return out
