"""Live heave (seed 002 eq. 6-8 with drift held): exact hoist against its analytic height, rest holding an
accelerometer bias, the depth observer bounding drift, streaming blocks equal to the batch run."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.fusion import heave
from gateway.fusion.quaternion import GRAVITY_M_S2

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def hoist_profile(lift_m: float = 2.0, move_s: float = 4.0, hold_s: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """(height m, vertical acceleration m/s²): hold, z = D (u − sin 2πu / 2π) over `move_s`, hold (analytic a)."""
    hold = np.zeros(int(hold_s * RATE_HZ))
    u = np.arange(int(move_s * RATE_HZ) + 1) / (move_s * RATE_HZ)
    z = np.concatenate([hold, lift_m * (u - np.sin(2 * np.pi * u) / (2 * np.pi)), np.full(hold.shape, lift_m)])
    a = np.concatenate([hold, lift_m / move_s**2 * 2 * np.pi * np.sin(2 * np.pi * u), hold])
    return z, a


def level_imu(a_up: np.ndarray, bias_m_s2: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = a_up.shape[0]
    acc = np.zeros((n, 3))
    acc[:, 2] = GRAVITY_M_S2 + a_up + bias_m_s2
    return np.tile(LEVEL, (n, 1)), np.zeros((n, 3)), acc


def test_exact_hoist_reaches_the_lifted_height_and_stops() -> None:
    """Level, noise-free 2 m lift in 4 s between rests: H ends at 2 m within 2 mm (trapezoid on 100 Hz), V_z 0 at
    rest, and the peak velocity is the analytic 2D/T = 1 m/s within 1 %."""
    z, a = hoist_profile()
    q, gyr, acc = level_imu(a)
    out = heave.run_heave(q, gyr, acc, DT)
    assert abs(out[-1, 0] - 2.0) < 2e-3
    assert out[-1, 1] == 0.0 and out[-1, 2] == 1.0 and heave.AIDED_NAMES[int(out[-1, 3])] == "rest"
    assert abs(out[:, 1].max() - 1.0) < 0.01
    np.testing.assert_allclose(out[:, 0], z, atol=3e-3)


def test_rest_learns_g_and_holds_an_accelerometer_bias() -> None:
    """A still sensor whose accelerometer reads 0.05 m/s² high for 60 s: rest detection learns g and holds H within
    2 mm (½·0.05·0.2² = 1 mm before the first 0.2 s of rest is seen); with rest detection off the same bias
    integrates to ½·0.05·60² = 90 m."""
    q, gyr, acc = level_imu(np.zeros(int(60 * RATE_HZ)), bias_m_s2=0.05)
    held = heave.run_heave(q, gyr, acc, DT)
    free = heave.run_heave(q, gyr, acc, DT, heave.HeaveSettings(rest_gyr_rad_s=0.0, leak_after_s=np.inf))
    assert np.abs(held[:, 0]).max() < 2e-3
    assert abs(free[-1, 0] - 90.0) < 0.5


def test_depth_sensor_bounds_the_drift_of_continuous_motion() -> None:
    """60 s of 0.5 m / 0.2 Hz heave that never rests, accelerometer 0.05 m/s² high, depth (= −height + 4 m) at
    10 Hz: H tracks −depth within 5 cm over the last 30 s and says it is depth-aided; without depth it drifts."""
    t = np.arange(int(60 * RATE_HZ)) * DT
    w = 2 * np.pi * 0.2
    z = 0.5 * np.sin(w * t)
    q, gyr, acc = level_imu(-0.5 * w * w * np.sin(w * t), bias_m_s2=0.05)
    depth = np.full(t.shape, np.nan)
    depth[::10] = 4.0 - z[::10]
    s = heave.HeaveSettings(rest_gyr_rad_s=0.0)
    aided = heave.run_heave(q, gyr, acc, DT, s, depth)
    free = heave.run_heave(q, gyr, acc, DT, heave.HeaveSettings(rest_gyr_rad_s=0.0, leak_after_s=np.inf))
    late = t > 30
    assert np.abs(aided[late, 0] - (z[late] - 4.0)).max() < 0.05
    assert set(aided[late, 3]) == {heave.AIDED_NAMES.index("depth")}
    assert np.abs(free[late, 0] - z[late]).max() > 10.0


@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(1, 1499), min_size=1, max_size=6, unique=True))
def test_streaming_blocks_equal_the_batch_run(cuts: list[int]) -> None:
    z, a = hoist_profile(move_s=3.0, hold_s=6.0)
    q, gyr, acc = level_imu(a[:1500], bias_m_s2=0.02)
    batch = heave.run_heave(q, gyr, acc, DT)
    est = heave.HeaveEstimator()
    edges = [0, *sorted(cuts), 1500]
    parts = [est.update(q[i:j], gyr[i:j], acc[i:j], DT) for i, j in zip(edges, edges[1:], strict=False)]
    np.testing.assert_array_equal(np.vstack(parts), batch)
    assert GRAVITY_M_S2 + 0.01 < est.gravity_m_s2 < GRAVITY_M_S2 + 0.02  # learning the bias at rest (tau 10 s)


def test_a_device_that_never_rests_becomes_heave_about_its_rest_height() -> None:
    """A swinging hook's case: 0.3 m / 0.2 Hz vertical oscillation that never rests, g off by 0.08 m/s² (seeded from
    a swinging warm-up). Default: after 10 s free-running it high-passes and learns g (tau 30 s), so over the last
    30 s of 90 s the height stays within 0.45 m of the truth (measured 0.37 m; the g error decays) and says
    `highpass`; without the high-pass it is tens of metres off."""
    t = np.arange(int(90 * RATE_HZ)) * DT
    w = 2 * np.pi * 0.2
    z = 0.3 * np.sin(w * t)
    q, gyr, acc = level_imu(-0.3 * w * w * np.sin(w * t), bias_m_s2=0.08)
    gyr[:, 0] = 0.2  # swinging: the rest detector never fires
    out = heave.run_heave(q, gyr, acc, DT)
    never = heave.run_heave(q, gyr, acc, DT, heave.HeaveSettings(leak_after_s=np.inf))
    late = t > 60
    assert np.abs(out[late, 0] - z[late]).max() < 0.45
    assert set(out[t > 10.5, 3]) == {heave.AIDED_NAMES.index("highpass")} and not out[:, 2].any()
    assert np.abs(never[late, 0] - z[late]).max() > 20.0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 40), st.integers(0, 2**31), st.booleans(), st.sampled_from([0.01, 0.02])),
                min_size=1, max_size=5))
def test_segments_kernel_is_each_device_alone(devices: list[tuple[int, int, bool, float]]) -> None:
    """`heave_run_segments` over concatenated blocks (the gateway's one call per batch) gives every device, bit for
    bit, what `heave_run` gives its block alone, state included; with depth rows where a device has them."""
    blocks, alone, states = [], [], []
    for n, seed, has_depth, dt in devices:
        rng = np.random.default_rng(seed)
        q = rng.normal(size=(n, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        gyr = rng.normal(0.0, 0.05, (n, 3))
        acc = np.array([0.0, 0.0, GRAVITY_M_S2]) + rng.normal(0.0, 0.5, (n, 3))
        depth = np.where(rng.random(n) < 0.3, rng.uniform(0.0, 5.0, n), np.nan) if has_depth else np.full(n, np.nan)
        est = heave.HeaveEstimator(gravity_m_s2=9.7 + 0.1 * rng.random())
        states.append(est.state.copy())
        alone.append((est.update(q, gyr, acc, dt, depth if has_depth else None), est.state.copy()))
        blocks.append((q, gyr, acc, depth, dt, est.params))
    sizes = np.array([b[0].shape[0] for b in blocks])
    stop = np.cumsum(sizes)
    st_all = np.array(states)
    rows = heave.heave_run_segments(st_all, *(np.concatenate([b[k] for b in blocks]) for k in range(4)), stop - sizes,
                                    stop, np.array([b[4] for b in blocks]), np.array([b[5] for b in blocks]))
    for k, (want_rows, want_state) in enumerate(alone):
        assert np.array_equal(rows[stop[k] - sizes[k] : stop[k]], want_rows)
        assert np.array_equal(st_all[k], want_state, equal_nan=True)
