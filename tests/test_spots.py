"""Spot scoring: each component against hand-computed values, the ranking, and bounds as a property."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.config import SpotPreferences
from gateway.spots import (
    DANGER_CAP,
    SpotReading,
    rank_spots,
    score_depth,
    score_light,
    score_oxygen,
    score_spot,
    score_temperature,
)

CARP = SpotPreferences(species=("carp",))  # 18-26 deg C


def test_dangerous_oxygen_spot_ranks_last_and_says_so():
    spots = [
        SpotReading("good", temp_c=22.0, oxygen_mg_l=7.5, light_lux=3000.0, depth_m=3.0, thermocline_m=4.5),
        SpotReading("deadzone", temp_c=22.0, oxygen_mg_l=1.5, light_lux=3000.0, depth_m=3.0, thermocline_m=4.5),
        SpotReading("cold", temp_c=9.0, oxygen_mg_l=9.0, light_lux=80_000.0, depth_m=0.5),
        SpotReading("unknown"),
    ]
    ranking = rank_spots(spots, CARP, local_hour=12.5)
    assert ranking[0].spot_id == "good" and ranking[-1].spot_id == "deadzone"
    assert ranking[-1].score <= DANGER_CAP
    assert any("dangerous oxygen" in r for r in ranking[-1].reasons)


def test_good_spot_reference_score():
    # temp in range 0.35, oxygen good 0.30, overcast midday 0.8 * 0.15 = 0.12, 1.5 m above thermocline 0.20 -> 0.97
    s = score_spot(SpotReading("a", 22.0, 7.5, 3000.0, 3.0, 4.5), CARP, local_hour=12.5)
    assert s.score == pytest.approx(0.97)
    assert [c.name for c in s.components] == ["temperature", "oxygen", "light", "depth"]
    assert "near but above the thermocline" in s.reasons[3]


@pytest.mark.parametrize(
    ("temp", "expect", "word"),
    [
        (22.0, 1.0, "in carp"),
        (15.0, 0.5, "3.0 °C below"),
        (29.0, 0.5, "above"),
        (40.0, 0.0, "above"),
        (None, 0.5, "no"),
    ],
)
def test_temperature_component(temp, expect, word):
    score, reason = score_temperature(temp, CARP.temp_ranges_c())
    assert score == pytest.approx(expect) and word in reason


def test_temperature_uses_best_species():
    score, reason = score_temperature(12.0, SpotPreferences(species=("carp", "trout")).temp_ranges_c())
    assert score == 1.0 and "trout" in reason


@pytest.mark.parametrize(
    ("o2", "expect", "word"),
    [(8.0, 1.0, "good"), (5.0, 1.0, "good"), (4.0, 0.7, "low"), (2.5, 0.15, "stressful"), (1.5, 0.0, "dangerous")],
)
def test_oxygen_component(o2, expect, word):
    score, reason = score_oxygen(o2)
    assert score == pytest.approx(expect) and reason.startswith(word)


@pytest.mark.parametrize(
    ("lux", "hour", "expect", "word"),
    [(500.0, 6.0, 1.0, "dawn"), (90_000.0, 18.5, 1.0, "dusk"), (5000.0, 13.0, 0.8, "overcast"),
     (90_000.0, 13.0, 0.2, "bright midday"), (30_000.0, 9.0, 0.5, "daylight"), (0.0, 23.0, 0.5, "night")],
)  # fmt: skip
def test_light_component(lux, hour, expect, word):
    score, reason = score_light(lux, hour)
    assert score == pytest.approx(expect) and word in reason


def test_depth_component():
    assert score_depth(3.0, 4.5, 7.0)[0] == 1.0
    assert score_depth(1.0, 6.0, 7.0)[0] == 0.7
    s, why = score_depth(8.0, 5.0, 2.5)
    assert s == pytest.approx(0.05) and "below the thermocline" in why and "low oxygen" in why
    assert score_depth(8.0, 5.0, 8.0)[0] == 0.4


readings = st.builds(
    SpotReading,
    spot_id=st.text(min_size=1, max_size=5),
    temp_c=st.none() | st.floats(-2.0, 40.0),
    oxygen_mg_l=st.none() | st.floats(0.0, 20.0),
    light_lux=st.none() | st.floats(0.0, 120_000.0),
    depth_m=st.none() | st.floats(0.0, 50.0),
    thermocline_m=st.none() | st.floats(0.0, 30.0),
)


@given(st.lists(readings, max_size=8), st.floats(0.0, 24.0))
def test_property_scores_bounded_and_ranked(spots, hour):
    ranking = rank_spots(spots, SpotPreferences(species=("pike", "bass")), hour)
    assert len(ranking) == len(spots)
    assert all(0.0 <= s.score <= 1.0 for s in ranking)
    assert [s.score for s in ranking] == sorted((s.score for s in ranking), reverse=True)
    assert all(len(s.reasons) == 4 and all(s.reasons) for s in ranking)
