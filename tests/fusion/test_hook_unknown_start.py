"""A hook not told its rope length and already swinging when the gateway starts (issue 11: ropes 2-30 m; the filter's
prior is 10 m): its first seconds must not run away while the pendulum gives the length."""

import numpy as np
import pytest

from bench.hook_suite import RATE_HZ, WARMUP_S, simulate_seed
from gateway.fusion import hook
from gateway.fusion.hook_filter import ACC_OFFSET_ROUND, HookFilter, HookFilterSettings

Crane = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # true Θ (rad), gyr, acc, mag
FIRST_S = 8.0  # the start and the re-start told the length found (`restart_told_std`: at 3.0 s here)


@pytest.fixture(scope="module")
def crane_29() -> Crane:
    """Tuning crane 29: a 2.3-m rope swinging 3.7° at start, an MPU-6050/HMC5883L-class board, its first 8 s."""
    case, truth, gyr, acc, mag = simulate_seed(29, 120.0, "legacy", True)  # the suite's 2-min timeline
    assert mag is not None and case.scenario.initial_swing_rad > 0.05
    n = round(FIRST_S * RATE_HZ)
    return truth.swing_rad[:n], gyr[:n], acc[:n], mag[:n]


def _errors_deg(settings: HookFilterSettings, crane: Crane, calls: int) -> tuple[np.ndarray, HookFilter]:
    """|Θ error| after the warm-up, the filter started as the gateway starts it and fed `calls` samples at a time;
    and the filter."""
    swing_rad, gyr, acc, mag = crane
    f = HookFilter(settings)
    w = round(WARMUP_S * RATE_HZ)
    f.start(gyr[:w], acc[:w], mag[:w], 1.0 / RATE_HZ)
    q = np.concatenate([f.run(gyr[a:a + calls], acc[a:a + calls], mag[a:a + calls], 1.0 / RATE_HZ)
                        for a in range(0, gyr.shape[0], calls)])  # fmt: skip
    return np.abs(np.degrees(hook.swing_angle(q) - swing_rad))[w:], f


@pytest.mark.parametrize("calls", [800, 10, 7])
def test_a_short_rope_not_told_reads_its_start_swing_within_a_few_degrees(crane_29: Crane, calls: int) -> None:
    """Measured over 0.5-8 s: worst 3.3° (in the first second), RMS 0.55° in one call, 0.66-0.67° in 10- and
    7-sample packets, against a true swing of up to 3.7°; the start redone told the length found at 3.0 s, still
    not configured. With the tension offset's old prior (0.5 m/s², `ACC_OFFSET_ROUND`) the 10-m prior's tension
    shortfall went into that offset and the swing read 25-41° for 1.5 s (RMS 8.5-10.1°, below)."""
    err, f = _errors_deg(HookFilterSettings(), crane_29, calls)
    assert not f.settings.rope_length_known and f.start_redone_s is not None and not f.start_pending
    assert err.max() < 5.0 and np.sqrt(np.mean(err**2)) < 1.2, (err.max(), np.sqrt(np.mean(err**2)))


def test_the_old_tension_offset_prior_ran_away(crane_29: Crane) -> None:
    """The same crane with `ACC_OFFSET_ROUND`: the failure the test above guards (measured 41.6° worst)."""
    err, _ = _errors_deg(HookFilterSettings(**ACC_OFFSET_ROUND), crane_29, 10)  # type: ignore[arg-type]
    assert err.max() > 15.0, err.max()
