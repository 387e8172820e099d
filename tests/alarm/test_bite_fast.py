"""The numba bite detector against the readable reference (`bite.BiteDetector`): the same blocks out, bit for bit,
on random streams (bites, drop-backs, wind, nan gaps, lost packets) cut into random blocks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.alarm.bite import BiteDetector, RodBlock
from gateway.alarm.bite_fast import FastBiteDetector, mean_square, np_add_reduce
from gateway.config import RodThresholds

RATE_HZ = 100.0


def stream(seed: int, seconds: float, rate_hz: float = RATE_HZ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Device times, pitch (rad) and vertical tip acceleration (m/s^2) of a rod with frequent bites, drop-backs,
    slow drift, wind, taps, re-sets to a new rest, nan gaps and lost stretches (jumps in time)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    dt = np.full(n, 1.0 / rate_hz)
    dt[rng.random(n) < 0.003] *= rng.integers(2, 40)  # lost packets: the frames skip
    t = rng.uniform(-5.0, 5.0) + np.cumsum(dt)
    pitch_deg = 30.0 + rng.uniform(0.05, 1.5) * rng.standard_normal(n) + np.cumsum(rng.normal(0, 0.02, n))
    for start in rng.integers(0, n, int(seconds / 4)):  # pulls and drop-backs, 0.05-4 s, 3-30 deg
        length = int(rng.uniform(0.05, 4.0) * rate_hz)
        pitch_deg[start : start + length] += rng.choice([-1.0, 1.0], p=[0.7, 0.3]) * rng.uniform(3.0, 30.0)
    for start in rng.integers(0, n, max(1, int(seconds / 30))):  # re-set at a new rest
        pitch_deg[start:] += rng.uniform(-15.0, 15.0)
    acc = rng.uniform(0.05, 2.0) * rng.standard_normal(n)
    for i in np.flatnonzero(rng.random(n) < 0.02):
        acc[i : i + 3] -= rng.uniform(3.0, 60.0)
    for start in rng.integers(0, n, int(seconds / 10)):  # gaps filled with nan
        pitch_deg[start : start + rng.integers(1, 30)] = np.nan
    if rng.random() < 0.5:
        acc[rng.random(n) < 0.01] = np.nan
    return t, np.radians(pitch_deg), acc


def assert_same_block(ref: RodBlock, got: RodBlock) -> None:
    assert got.events == ref.events
    assert np.array_equal(got.deviation_rad, ref.deviation_rad, equal_nan=True)
    for name in ("baseline_rad", "min_deviation_rad", "t_min_s"):
        a, b = getattr(ref, name), getattr(got, name)
        assert (math.isnan(a) and math.isnan(b)) or a == b, (name, a, b)


def run_both(seed: int, seconds: float, max_block: int, sensitivity: int, quiet_s: float, with_acc: str,
             rate_hz: float = RATE_HZ) -> int:  # fmt: skip
    """Feed both detectors the same blocks; returns how many events they gave (so callers can see it is > 0)."""
    rng = np.random.default_rng(seed + 1)
    t, pitch, acc = stream(seed, seconds, rate_hz)
    th = RodThresholds(sensitivity=sensitivity, rearm_quiet_s=quiet_s)
    ref, fast = BiteDetector(th), FastBiteDetector(th)
    events, i = 0, 0
    while i < t.size:
        n = int(rng.integers(0, max_block + 1))
        sl = slice(i, i + n)
        a = None if with_acc == "never" or (with_acc == "some" and rng.random() < 0.3) else acc[sl]
        r, f = ref.update(t[sl], pitch[sl], None, None, a), fast.update(t[sl], pitch[sl], None, None, a)
        assert_same_block(r, f)
        events += len(r.events)
        u = rng.random()
        if u < 0.003:
            base = float(pitch[min(i, t.size - 1)])
            ref.rebaseline(base)
            fast.rebaseline(base)
        elif u < 0.006:
            th = RodThresholds(sensitivity=int(rng.integers(1, 6)), rearm_quiet_s=float(rng.uniform(0.5, 5.0)))
            ref.set_thresholds(th)
            fast.set_thresholds(th)
        i += n
    s_ref, s_fast = ref.state, fast.state
    for name in ("baseline_rad", "bite_armed", "drop_armed", "acc_ms", "acc_ms_lagged", "warmed", "frame_k"):
        a, b = getattr(s_ref, name), getattr(s_fast, name)
        assert a == b or (a != a and b != b), (name, a, b)
    return events


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    max_block=st.sampled_from([1, 5, 10, 13, 40, 300]),
    sensitivity=st.integers(1, 5),
    quiet_s=st.sampled_from([0.5, 1.0, 3.0]),
    with_acc=st.sampled_from(["always", "never", "some"]),
)
def test_fast_detector_equals_reference_on_random_streams(seed, max_block, sensitivity, quiet_s, with_acc):
    run_both(seed, 40.0, max_block, sensitivity, quiet_s, with_acc)


@pytest.mark.parametrize(("rate_hz", "seconds"), [(25.0, 600.0), (100.0, 300.0), (1000.0, 60.0)])
def test_fast_detector_equals_reference_long_stream_with_many_events(rate_hz, seconds):
    """Minutes at three rates (frames of 2.5 to 100 samples): the comparison sees a good number of alarms."""
    assert run_both(11, seconds, 25, 3, 2.0, "always", rate_hz) >= 5


@settings(max_examples=200, deadline=None)
@given(n=st.integers(0, 600), seed=st.integers(0, 2**32 - 1), spread=st.floats(0.0, 30.0))
def test_np_add_reduce_is_numpys_sum(n, seed, spread):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n) * np.exp(rng.uniform(-spread, spread, n))
    if n and rng.random() < 0.2:
        x[rng.integers(0, n)] = rng.choice([np.nan, np.inf, -np.inf, -0.0])
    ref, got = np.add.reduce(x), np_add_reduce(x, n)
    assert (math.isnan(ref) and math.isnan(got)) or (ref == got and math.copysign(1, ref) == math.copysign(1, got))


def test_np_add_reduce_of_negative_zeros_is_positive_zero():
    assert math.copysign(1.0, np_add_reduce(np.array([-0.0] * 9), 9)) == 1.0


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 600), seed=st.integers(0, 2**32 - 1), spread=st.floats(0.0, 30.0))
def test_mean_square_is_numpys_dot(n, seed, spread):
    """The vibration level: numba's BLAS call (scipy's OpenBLAS) gives numpy's result to the last bit."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n) * np.exp(rng.uniform(-spread, spread, n))
    assert mean_square(x) == np.dot(x, x) / n


def test_rod_rules_take_one_tension_value_per_block_as_the_array_of_it():
    """The rod kind passes the reel's latest tension as one value: the same conditions as that value per sample."""
    from gateway.alarm.rules import RodAlarms

    t, pitch, acc = stream(5, 120.0)
    rng = np.random.default_rng(6)
    th = RodThresholds()
    by_value, by_array = RodAlarms("rod-1", th), RodAlarms("rod-1", th)
    conds: list[object] = []
    for i in range(0, t.size, 10):
        sl = slice(i, i + 10)
        tension = float(rng.choice([np.nan, 5.0, 0.75 * th.line_breaking_n, 0.9 * th.line_breaking_n]))
        _, a = by_value.update(t[sl], pitch[sl], None, None, acc[sl], tension)
        _, b = by_array.update(t[sl], pitch[sl], None, None, acc[sl], np.full(t[sl].shape, tension))
        assert a == b
        conds += a
    assert any(c.type == "line_tension" for c in conds)  # type: ignore[attr-defined]
