"""Fishing-spot suggestion (seed 000: the environment ball's readings judge whether a spot suits fish). Pure.

Each spot gets a score in [0, 1] (as on the wire, `SpotScore.score`) from four components, each a score in [0, 1]
times its weight (the weights sum to 1), with a reason:

- temperature (0.35): inside a target species' preferred range = 1, falling linearly to 0 at TEMP_FALLOFF_C
  outside it (the best species counts);
- oxygen (0.30): >= 5 mg/L good (1); 3..5 low (0.4..1); 2..3 stressful (0.15); < 2 dangerous (0) -- and a
  spot with dangerous oxygen is capped at DANGER_CAP overall, so it always ranks last;
- light (0.15): dawn and dusk best; overcast (< 10 klx) by day good; bright midday sun (>= 50 klx) poor;
- depth (0.20): near (<= 2 m) above the thermocline best; well above fine; below it with low oxygen bad.
A missing reading scores 0.5 ("no reading") so a spot is neither favoured nor buried for it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from gateway.config import SpotPreferences

WEIGHTS: Mapping[str, float] = {"temperature": 0.35, "oxygen": 0.30, "light": 0.15, "depth": 0.20}
TEMP_FALLOFF_C = 6.0
OXYGEN_GOOD_MG_L = 5.0
OXYGEN_STRESS_MG_L = 3.0
OXYGEN_DANGER_MG_L = 2.0
DANGER_CAP = 0.10
NEAR_THERMOCLINE_M = 2.0
DAWN_H = (5.0, 8.0)
DUSK_H = (17.0, 20.0)
OVERCAST_LUX = 10_000.0
BRIGHT_LUX = 50_000.0
MIDDAY_H = (10.0, 16.0)
UNKNOWN = 0.5


@dataclass(frozen=True, slots=True)
class SpotReading:
    """Latest environment-ball readings at one spot; None = no reading."""

    spot_id: str
    temp_c: float | None = None
    oxygen_mg_l: float | None = None
    light_lux: float | None = None
    depth_m: float | None = None
    thermocline_m: float | None = None


@dataclass(frozen=True, slots=True)
class Component:
    """One scoring component: score in [0, 1], its weight (a fraction of the total), and why."""

    name: str
    score: float
    weight: float
    reason: str

    @property
    def points(self) -> float:
        return self.score * self.weight


@dataclass(frozen=True, slots=True)
class SpotScore:
    """A spot's total (0..1) and its components."""

    spot_id: str
    score: float
    components: tuple[Component, ...]

    @property
    def reasons(self) -> list[str]:
        return [c.reason for c in self.components]


def score_temperature(temp_c: float | None, ranges_c: Mapping[str, tuple[float, float]]) -> tuple[float, str]:
    """Best match over the target species' preferred ranges (deg C)."""
    if temp_c is None:
        return UNKNOWN, "no water temperature reading"
    best = (-1.0, "")
    for species, (lo, hi) in ranges_c.items():
        if lo <= temp_c <= hi:
            cand = (1.0, f"{temp_c:.1f} °C is in {species}'s preferred {lo:g}-{hi:g} °C")
        else:
            off = lo - temp_c if temp_c < lo else temp_c - hi
            side = "below" if temp_c < lo else "above"
            cand = (max(0.0, 1.0 - off / TEMP_FALLOFF_C),
                    f"{temp_c:.1f} °C is {off:.1f} °C {side} {species}'s preferred {lo:g}-{hi:g} °C")  # fmt: skip
        best = max(best, cand, key=lambda c: c[0])
    return best


def score_oxygen(oxygen_mg_l: float | None) -> tuple[float, str]:
    """Dissolved oxygen: >= 5 mg/L good, < 3 stressful, < 2 dangerous."""
    if oxygen_mg_l is None:
        return UNKNOWN, "no dissolved-oxygen reading"
    o = oxygen_mg_l
    if o >= OXYGEN_GOOD_MG_L:
        return 1.0, f"good oxygen ({o:.1f} mg/L)"
    if o >= OXYGEN_STRESS_MG_L:
        frac = (o - OXYGEN_STRESS_MG_L) / (OXYGEN_GOOD_MG_L - OXYGEN_STRESS_MG_L)
        return 0.4 + 0.6 * frac, f"low oxygen ({o:.1f} mg/L)"
    if o >= OXYGEN_DANGER_MG_L:
        return 0.15, f"stressful oxygen ({o:.1f} mg/L): fish are sluggish"
    return 0.0, f"dangerous oxygen ({o:.1f} mg/L): fish avoid or die here"


def score_light(light_lux: float | None, local_hour: float) -> tuple[float, str]:
    """Dawn/dusk best; by day, overcast beats bright midday sun."""
    h = local_hour % 24.0
    if DAWN_H[0] <= h < DAWN_H[1] or DUSK_H[0] <= h < DUSK_H[1]:
        return 1.0, f"{'dawn' if h < 12 else 'dusk'}: feeding time"
    if h < DAWN_H[0] or h >= DUSK_H[1]:
        return 0.5, "night"
    if light_lux is None:
        return UNKNOWN, "daytime, no light reading"
    if light_lux < OVERCAST_LUX:
        return 0.8, f"overcast or shaded ({light_lux:.0f} lx)"
    if light_lux >= BRIGHT_LUX and MIDDAY_H[0] <= h < MIDDAY_H[1]:
        return 0.2, f"bright midday sun ({light_lux:.0f} lx): fish go deep or into cover"
    return 0.5, f"daylight ({light_lux:.0f} lx)"


def score_depth(depth_m: float | None, thermocline_m: float | None, oxygen_mg_l: float | None) -> tuple[float, str]:
    """Depth relative to the thermocline: just above it is best; below it with low oxygen is bad."""
    if depth_m is None:
        return UNKNOWN, "no depth reading"
    if thermocline_m is None:
        return (0.4, f"very shallow ({depth_m:.1f} m)") if depth_m < 1.0 else (0.6, "thermocline unknown")
    if depth_m <= thermocline_m:
        gap = thermocline_m - depth_m
        if gap <= NEAR_THERMOCLINE_M:
            return 1.0, f"{depth_m:.1f} m: near but above the thermocline ({thermocline_m:.1f} m)"
        return 0.7, f"{depth_m:.1f} m: well above the thermocline ({thermocline_m:.1f} m)"
    if oxygen_mg_l is None or oxygen_mg_l < OXYGEN_GOOD_MG_L - 1.0:
        return 0.05, f"{depth_m:.1f} m: below the thermocline ({thermocline_m:.1f} m) with low oxygen"
    return 0.4, f"{depth_m:.1f} m: below the thermocline ({thermocline_m:.1f} m)"


def score_spot(r: SpotReading, prefs: SpotPreferences, local_hour: float) -> SpotScore:
    """All four components and the total (0..1) for one spot."""
    parts = {
        "temperature": score_temperature(r.temp_c, prefs.temp_ranges_c()),
        "oxygen": score_oxygen(r.oxygen_mg_l),
        "light": score_light(r.light_lux, local_hour),
        "depth": score_depth(r.depth_m, r.thermocline_m, r.oxygen_mg_l),
    }
    comps = tuple(Component(name, s, WEIGHTS[name], why) for name, (s, why) in parts.items())
    total = sum(c.points for c in comps)
    if r.oxygen_mg_l is not None and r.oxygen_mg_l < OXYGEN_DANGER_MG_L:
        total = min(total, DANGER_CAP)
    return SpotScore(r.spot_id, round(total, 3), comps)


def rank_spots(readings: Iterable[SpotReading], prefs: SpotPreferences, local_hour: float) -> list[SpotScore]:
    """Spots best first (ties by id). `local_hour` is the local time of day in hours, e.g. 6.5 = 06:30."""
    scored = [score_spot(r, prefs, local_hour) for r in readings]
    return sorted(scored, key=lambda s: (-s.score, s.spot_id))
