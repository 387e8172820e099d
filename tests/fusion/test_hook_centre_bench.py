"""bench.hook_centre: the pieces its figures rest on."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from bench.hook_centre import body_xy_to_enu, moving_mean, trace
from bench.hook_suite import RATE_HZ, WARMUP_S, hook_estimate, simulate_seed
from gateway.fusion.hook_filter import N_STATE, HookFilterSettings
from gateway.fusion.quaternion import rotate


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, (5, 4), elements=st.floats(-1.0, 1.0)), arrays(np.float64, (5, 2), elements=st.floats(-2, 2)))
def test_body_xy_to_enu_is_the_attitude_rotation(q, v):
    """The x/y bias turned to ENU is `q ⊗ (v_x, v_y, 0) ⊗ q*`'s x/y, for any attitude (to 1e-12)."""
    norm = np.linalg.norm(q, axis=1)
    q = np.where(norm[:, None] > 0.1, q / np.maximum(norm[:, None], 1e-12), np.array([1.0, 0.0, 0.0, 0.0]))
    full = rotate(q, np.concatenate([v, np.zeros((5, 1))], axis=1))
    np.testing.assert_allclose(body_xy_to_enu(q, v), full[:, :2], atol=1e-12)


def test_the_filter_read_packet_by_packet_is_the_suites_filter():
    """`trace` runs the filter in packets to read its state; its attitudes are the suite's one-call run's (a 20 s
    suite crane with a slew, jumps and their rollbacks across packet ends), to 1e-9."""
    case, _, gyr, acc, mag = simulate_seed(8, 20.0, "calibrated", True)
    q_suite, _ = hook_estimate(gyr, acc, mag, case.physics.rope_length_m)
    q, x = trace(gyr, acc, mag, HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True),
                 7)  # fmt: skip
    assert x.shape == (gyr.shape[0], N_STATE) and int(WARMUP_S * RATE_HZ) < gyr.shape[0]
    np.testing.assert_allclose(q, q_suite, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(rows=st.integers(1, 60), window=st.integers(0, 200))
def test_the_moving_mean_keeps_the_rows_whatever_the_window(rows: int, window: int) -> None:
    """A run shorter than a pendulum period (`--duration 3` on a long rope) crashed: np.convolve's "same" gives the
    longer of the two lengths. Rows kept; a constant column's mean is the constant where the window fits."""
    x = np.full((rows, 2), 3.0)
    m = moving_mean(x, window)
    assert m.shape == (rows, 2)
    w = max(1, min(window, rows))
    if w % 2 == 1:
        np.testing.assert_allclose(m[w // 2 : rows - w // 2], 3.0)
