"""A hook not told its rope length and already swinging when the gateway starts (issue 11: ropes 2-30 m; the filter's
prior is 10 m): its first seconds must not run away while the pendulum gives the length (docs/fusion.md "A hook not
told its rope, swinging at start")."""

import numpy as np
import pytest

from bench.hook_suite import RATE_HZ, WARMUP_S, simulate_seed
from gateway.fusion import hook
from gateway.fusion.hook_filter import ACC_OFFSET_ROUND, HookFilter, HookFilterSettings
from tests.fusion.test_hook_compass import _run

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
    """|Θ error| after the warm-up, the filter started as the gateway starts it and fed `calls` samples at a time
    (`test_hook_compass._run`); and the filter."""
    swing_rad, gyr, acc, mag = crane
    f = HookFilter(settings)
    q = _run(f, gyr, acc, mag, calls)
    return np.abs(np.degrees(hook.swing_angle(q) - swing_rad))[round(WARMUP_S * RATE_HZ):], f


@pytest.mark.parametrize("calls", [800, 10, 7])
def test_a_short_rope_not_told_reads_its_start_swing_within_a_few_degrees(crane_29: Crane, calls: int) -> None:
    """Measured over 0.5-8 s: worst 1.8° (in the first second), RMS 0.29° in one call, 0.34-0.35° in 10- and
    7-sample packets, against a true swing of up to 3.7°; the start redone told the length found at 3.0 s, still
    not configured. Each of the session's two changes alone: the tension offset held
    (`moving_acc_offset_not_told_std_m_s2`) 3.3° worst, the pending start's compass at 10 µT
    (`mag_noise_pending_uT`) 2.1°. With neither (the filter before, below) the 10-m prior's tension shortfall went
    into the offset and the swing read 25-41° for 1.5 s (RMS 8.5-10.1°)."""
    err, f = _errors_deg(HookFilterSettings(), crane_29, calls)
    assert not f.settings.rope_length_known and f.start_redone_s is not None and not f.start_pending
    assert err.max() < 3.0 and np.sqrt(np.mean(err**2)) < 0.6, (err.max(), np.sqrt(np.mean(err**2)))


def test_the_filter_before_ran_away(crane_29: Crane) -> None:
    """The same crane with `ACC_OFFSET_ROUND` and `PENDING_COMPASS_ROUND`: the failure the test above guards
    (measured 41.6° worst)."""
    from gateway.fusion.hook_filter import PENDING_COMPASS_ROUND

    before = HookFilterSettings(**ACC_OFFSET_ROUND, **PENDING_COMPASS_ROUND)  # type: ignore[arg-type]
    err, _ = _errors_deg(before, crane_29, 10)
    assert err.max() > 15.0, err.max()


@pytest.fixture(scope="module")
def crane_3226() -> Crane:
    """Crane 3226: a 4.7-m rope swinging 2.6° and twisting in gusts at start, a calibrated board, its first 10 s."""
    case, truth, gyr, acc, mag = simulate_seed(3226, 120.0, "calibrated", True)
    assert mag is not None and case.scenario.initial_swing_rad > 0.04
    n = round(10.0 * RATE_HZ)
    return truth.swing_rad[:n], gyr[:n], acc[:n], mag[:n]


@pytest.mark.parametrize("calls", [1000, 10, 7])
def test_a_pending_start_does_not_let_a_compass_levelled_as_if_plumb_pull_the_swing(crane_3226: Crane,
                                                                                    calls: int) -> None:  # fmt: skip
    """Until the start is redone the compass weighs as 10 µT of noise (`mag_noise_pending_uT`): its reference was
    levelled as if plumb, off by the 2.6° swing's tilt. Measured over 0.5-10 s: RMS 1.42°, worst 4.4°, in one call
    and in 10- and 7-sample packets; at 3 µT (`PENDING_COMPASS_ROUND`) the z bias ran to 8 °/s and the swing read
    7-11° until the start was redone at 6 s: RMS 4.8-5.8°, worst 10.7-11.0°."""
    from gateway.fusion.hook_filter import PENDING_COMPASS_ROUND

    err, f = _errors_deg(HookFilterSettings(), crane_3226, calls)
    assert f.start_pending and f.compass_trusted  # not redone yet (the length's 1σ still over 5 %), compass kept
    assert err.max() < 6.0 and np.sqrt(np.mean(err**2)) < 2.0, (err.max(), np.sqrt(np.mean(err**2)))
    before, _ = _errors_deg(HookFilterSettings(**PENDING_COMPASS_ROUND), crane_3226, calls)  # type: ignore[arg-type]
    assert np.sqrt(np.mean(before**2)) > 3.5, np.sqrt(np.mean(before**2))
