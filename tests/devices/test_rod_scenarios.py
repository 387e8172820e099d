"""The rod scenario suite (devices.rod_scenarios): reproducible, each family inside the ranges issue 10 states,
and only bites and runs take the true pitch theta1 below rest (so 0 false alarms is a fair target)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from devices.common import G_M_S2
from devices.rod_scenarios import ALARMING, FAMILIES, Scenario, make_scenario

SEEDS = (0, 1, 2)  # tuning seeds; the bench reports on 1000-1023


@pytest.fixture(scope="module")
def scenarios() -> list[Scenario]:
    return [make_scenario(s) for s in SEEDS]


def deviation_deg(sc: Scenario) -> np.ndarray:
    return np.degrees(sc.euler_rad[:, 1] - sc.rest_pitch_rad)


def test_same_seed_same_recording() -> None:
    a, b = make_scenario(5), make_scenario(5)
    assert np.array_equal(a.acc_m_s2, b.acc_m_s2) and np.array_equal(a.quat_wxyz, b.quat_wxyz)
    assert a.events == b.events
    assert not np.array_equal(a.acc_m_s2, make_scenario(6).acc_m_s2)


def test_every_family_appears_and_recordings_are_five_minutes(scenarios: list[Scenario]) -> None:
    assert {e.family for sc in scenarios for e in sc.events} == set(FAMILIES)
    for sc in scenarios:
        assert sc.t_s.size == 30_000 and sc.hours == pytest.approx(300.0 / 3600.0)
        assert np.allclose(np.diff(sc.t_s), 0.01)


def test_only_bites_and_runs_reach_theta1_below_rest(scenarios: list[Scenario]) -> None:
    for sc in scenarios:
        dev = deviation_deg(sc)
        for e in sc.events:
            w = (sc.t_s >= e.t_start_s) & (sc.t_s <= e.t_end_s + 2.0)
            if e.family in ALARMING:
                assert e.t_start_s < e.cross_s < e.t_end_s, e
                assert dev[w].min() <= -10.0
            else:
                assert math.isnan(e.cross_s) and dev[w].min() > -7.0, e  # nibbles dip <= 6 deg + 0.3 ripple


@pytest.mark.parametrize(
    ("family", "lo_deg", "hi_deg"),
    [("bite", -35.5, -12.0), ("run", -35.0, -15.0), ("nibble", -6.4, -0.5), ("handling", -2.8, 2.8),
     ("drop_back", 7.5, 21.5), ("knock", -1.9, 1.9), ("wind", -5.4, 5.4)],
)  # fmt: skip
def test_family_excursions_within_stated_ranges(scenarios: list[Scenario], family: str, lo_deg: float,
                                                hi_deg: float) -> None:  # fmt: skip
    """Peak true pitch excursion of each event (ranges from the issue, plus the 0.3 deg wave ripple and ringing)."""
    peaks = [e.peak_deg for sc in scenarios for e in sc.events if e.family == family]
    assert peaks and all(lo_deg <= p <= hi_deg for p in peaks), peaks


def test_accelerometer_clips_at_2g_on_knocks_and_never_reads_beyond(scenarios: list[Scenario]) -> None:
    fs = 2.0 * G_M_S2
    clipped_knocks = 0
    for sc in scenarios:
        assert np.abs(sc.acc_m_s2).max() <= fs + 1e-9
        for e in sc.events:
            if e.family == "knock":
                w = (sc.t_s >= e.t_start_s - 0.01) & (sc.t_s <= e.t_end_s + 0.05)
                assert sc.acc_true_max_g[w].max() >= 2.0  # 2-6 g of jolt (plus gravity)
                clipped_knocks += bool((np.abs(sc.acc_m_s2[w]) >= 0.999 * fs).any())
    assert clipped_knocks >= 3


def test_at_rest_the_imu_reads_gravity_and_no_rotation(scenarios: list[Scenario]) -> None:
    sc = scenarios[0]
    quiet = sc.t_s < 7.0
    assert np.linalg.norm(sc.acc_m_s2[quiet].mean(axis=0)) == pytest.approx(G_M_S2, rel=0.05)
    assert np.degrees(np.abs(sc.gyr_rad_s[quiet].mean(axis=0))).max() < 5.0  # MPU-6050 bias, not motion
