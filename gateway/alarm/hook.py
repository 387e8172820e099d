"""Crane-hook rules: swing angle Theta (seed 001 eq. 6, cos Theta = cos(theta_x) cos(theta_y)) and torsion phi
about the rope (seed 001 eq. 1-3), each with a warning and a critical threshold and clearing hysteresis."""

from __future__ import annotations

import math

import numpy as np

from gateway.alarm.bite import FloatArray
from gateway.alarm.engine import Condition
from gateway.alarm.rules import LevelGuard
from gateway.config import HookThresholds


def wrap_abs_deg(angle_rad: FloatArray) -> FloatArray:
    """|angle| in degrees after wrapping to (-180, 180]: a twist of 350 deg is 10 deg the other way."""
    wrapped: FloatArray = np.abs(np.degrees(np.angle(np.exp(1j * angle_rad))))
    return wrapped


class HookAlarms:
    """Swing and torsion guards for one hook device."""

    def __init__(self, device_id: str, thresholds: HookThresholds | None = None) -> None:
        self.device_id = device_id
        self.swing = LevelGuard("hook_swing", (0.0, 0.0), 0.0, "deg")
        self.torsion = LevelGuard("hook_torsion", (0.0, 0.0), 0.0, "deg")
        self.set_thresholds(thresholds or HookThresholds())

    def set_thresholds(self, th: HookThresholds) -> None:
        """Apply new thresholds; current levels are kept and re-judged on the next block."""
        self.thresholds = th
        self.swing.thresholds = (th.swing_warn_deg, th.swing_critical_deg)
        self.torsion.thresholds = (th.torsion_warn_deg, th.torsion_critical_deg)
        self.swing.hysteresis = self.torsion.hysteresis = th.hysteresis_deg

    def update(self, t_s: FloatArray, swing_rad: FloatArray, torsion_rad: FloatArray) -> list[Condition]:
        """One block, shapes (n,): swing angle Theta >= 0 and torsion phi, both in radians."""
        out = []
        c = self.swing.update(self.device_id, t_s, np.abs(swing_rad) * (180.0 / math.pi), "swing")
        if c is not None:
            out.append(c)
        c = self.torsion.update(self.device_id, t_s, wrap_abs_deg(torsion_rad), "torsion")
        if c is not None:
            out.append(c)
        return out
