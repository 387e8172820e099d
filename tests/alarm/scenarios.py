"""Synthetic rod scenarios: rest pitch, noise, bites, drop-backs, wind, drift; tip acceleration consistent with them.

The tip's vertical position is z = L sin(pitch) for an effective lever L, so its acceleration is the second
derivative of that (numerically), which keeps pitch and acceleration physically in step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gateway.alarm.engine import AlarmChange, AlarmEngine, Condition
from gateway.alarm.rules import RodAlarms
from gateway.config import RodThresholds

RATE_HZ = 100.0
LEVER_M = 2.0
REST_DEG = 20.0


def times(duration_s: float, rate_hz: float = RATE_HZ) -> np.ndarray:
    return np.arange(int(round(duration_s * rate_hz))) / rate_hz


def raised_cosine_step(t: np.ndarray, t0_s: float, rise_s: float, depth_deg: float) -> np.ndarray:
    """0 before t0, smoothly to depth_deg over rise_s, then held (degrees)."""
    x = np.clip((t - t0_s) / rise_s, 0.0, 1.0)
    return depth_deg * 0.5 * (1.0 - np.cos(np.pi * x))


def pulse(t: np.ndarray, t0_s: float, rise_s: float, hold_s: float, depth_deg: float) -> np.ndarray:
    """Step to depth_deg at t0, hold, then back to 0 over the same rise time (degrees)."""
    return raised_cosine_step(t, t0_s, rise_s, depth_deg) - raised_cosine_step(t, t0_s + rise_s + hold_s, rise_s,
                                                                               depth_deg)  # fmt: skip


def tip_acc_up(t: np.ndarray, rel_deg: np.ndarray, noise_m_s2: float, rng: np.random.Generator) -> np.ndarray:
    """Accelerometer-derived vertical tip acceleration for the noise-free motion `rel_deg` about rest, plus noise."""
    z = LEVER_M * np.sin(np.radians(REST_DEG + rel_deg))
    dt = t[1] - t[0]
    return np.gradient(np.gradient(z, dt), dt) + noise_m_s2 * rng.standard_normal(t.size)


@dataclass
class Run:
    conditions: list[Condition] = field(default_factory=list)
    changes: list[AlarmChange] = field(default_factory=list)
    baselines: list[float] = field(default_factory=list)

    def of(self, alarm_type: str, kind: str = "raised") -> list[AlarmChange]:
        return [c for c in self.changes if c.alarm.type == alarm_type and c.kind == kind]

    def raised_types(self) -> set[str]:
        return {c.alarm.type for c in self.changes if c.kind == "raised"}


def run_rod(
    t: np.ndarray,
    pitch_deg: np.ndarray,
    acc: np.ndarray | None = None,
    th: RodThresholds | None = None,
    block: int = 10,
    tension_n: np.ndarray | None = None,
) -> Run:
    rod = RodAlarms("rod-1", th)
    engine = AlarmEngine(id_factory=iter(f"a{i}" for i in range(10**6)).__next__)
    out = Run()
    pitch = np.radians(pitch_deg)
    for i in range(0, t.size, block):
        sl = slice(i, i + block)
        blk, conds = rod.update(
            t[sl], pitch[sl], None, None, None if acc is None else acc[sl], None if tension_n is None else tension_n[sl]
        )
        out.conditions += conds
        out.changes += engine.evaluate(conds)
        out.baselines.append(math.degrees(blk.baseline_rad))
    return out


def noisy(t: np.ndarray, deg: np.ndarray, noise_deg: float, rng: np.random.Generator) -> np.ndarray:
    return REST_DEG + deg + noise_deg * rng.standard_normal(t.size)
