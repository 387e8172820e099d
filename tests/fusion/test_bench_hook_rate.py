"""bench.hook_suite at another IMU rate (`rate_hz`, `--rate-hz`): the simulation, the samples and the filters all
take it, not the 100 Hz default."""

from __future__ import annotations

import numpy as np
import pytest

from bench.hook_suite import hook_estimate, simulate_seed
from gateway.fusion import hook


def test_a_seed_simulated_at_50_hz_has_half_the_samples_and_the_filter_runs_at_that_rate() -> None:
    case50, truth50, gyr50, acc50, mag50 = simulate_seed(8, 10.0, "ideal", True, rate_hz=50.0)
    _, truth100, gyr100, _, _ = simulate_seed(8, 10.0, "ideal", True)
    assert gyr100.shape[0] == pytest.approx(2 * gyr50.shape[0], abs=2)
    assert np.diff(truth50.t_s) == pytest.approx(0.02)
    q, _ = hook_estimate(gyr50, acc50, mag50, case50.physics.rope_length_m, rate_hz=50.0)
    err_deg = np.degrees(np.abs(hook.swing_angle(q) - truth50.swing_rad))[25:]  # after the 0.5 s warm-up
    assert err_deg.max() < 1.0  # error-free sensors: a filter run with the wrong dt would drift far off
    assert truth100.t_s[-1] == pytest.approx(truth50.t_s[-1], abs=0.02)
