"""Height from specific force (seed 002 eq. 6-8): exact synthetic motion, drift laws, leak and zero-velocity
options, streaming == batch, and BROAD fast translation (opt_pos z) over 1 s windows.

BROAD figures measured on the first 100 s of 15_undisturbed_fast_translation_A (58 windows of 1 s, each started
from the reference height and velocity), RMS end-of-window height error: plain complementary 0.30 m, adaptive
0.085 m (reference moves ~0.3 m per window). Whole trial, 100 windows: plain 0.24 m, adaptive 0.09 m."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.fusion import broad, height
from gateway.fusion import quaternion as quat
from gateway.fusion.complementary import AdaptiveComplementaryFilter, ComplementaryFilter
from tests.fusion.conftest import trial_slice

RATE_HZ = 100.0


def vertical_motion(seconds=10.0, amp_m=0.5, freq_hz=0.5):
    n = int(seconds * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    w = 2 * np.pi * freq_hz
    z = amp_m * np.sin(w * t)
    a_up = -amp_m * w * w * np.sin(w * t)
    q = quat.from_euler(0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.4 * t), 0.5 * t)  # tumbling while it moves
    acc = quat.rotate_inverse(q, np.stack([np.zeros(n), np.zeros(n), a_up + 9.81], axis=-1))
    return t, q, acc, z, amp_m * w * np.cos(w * t)


def test_recovers_known_vertical_motion_with_true_attitude():
    t, q, acc, z, vz = vertical_motion()
    h, v = height.integrate_height(q, acc, 1 / RATE_HZ, v0_m_s=vz[0], h0_m=z[0])
    # trapezoidal rule at 100 Hz on a 0.5 Hz, 0.5 m oscillation: measured max error 1.3 mm over 10 s
    np.testing.assert_allclose(h, z, atol=0.003)
    np.testing.assert_allclose(v, vz, atol=0.001)


def test_streaming_equals_batch():
    t, q, acc, z, vz = vertical_motion(5.0)
    rest = (t > 2.0) & (t < 2.5)
    s = height.HeightSettings(velocity_leak_tau_s=3.0, height_leak_tau_s=20.0)
    h, v = height.integrate_height(q, acc, 1 / RATE_HZ, s, rest=rest, v0_m_s=0.1, h0_m=1.0)
    est = height.HeightEstimator(s, h0_m=1.0, v0_m_s=0.1)
    out = np.array([est.update(qi, ai, 1 / RATE_HZ, bool(r)) for qi, ai, r in zip(q, acc, rest, strict=True)])
    np.testing.assert_allclose(out[:, 0], h, atol=1e-12)
    np.testing.assert_allclose(out[:, 1], v, atol=1e-12)


@pytest.mark.parametrize("bias_m_s2", [0.05, -0.2])
def test_constant_acceleration_bias_drifts_quadratically(bias_m_s2):
    n = int(20 * RATE_HZ)
    q = quat.identity((n,))
    acc = np.tile([0, 0, 9.81 + bias_m_s2], (n, 1))
    h, v = height.integrate_height(q, acc, 1 / RATE_HZ)
    t = np.arange(n) / RATE_HZ
    np.testing.assert_allclose(v, bias_m_s2 * t, atol=1e-9)
    np.testing.assert_allclose(h, 0.5 * bias_m_s2 * t**2, atol=1e-9)


def test_velocity_leak_bounds_the_drift_and_rest_zeroes_velocity():
    n = int(60 * RATE_HZ)
    q = quat.identity((n,))
    acc = np.tile([0, 0, 9.81 + 0.05], (n, 1))
    tau = 2.0
    h, v = height.integrate_height(q, acc, 1 / RATE_HZ, height.HeightSettings(velocity_leak_tau_s=tau))
    assert v[-1] == pytest.approx(0.05 * tau, rel=1e-3)  # steady state a·tau, not a·t
    rest = np.zeros(n, bool)
    rest[::100] = True  # a zero-velocity update every second
    h_z, v_z = height.integrate_height(q, acc, 1 / RATE_HZ, rest=rest)
    assert v_z[::100].max() == 0.0
    # each 1 s interval adds b·1²/2 = 0.025 m: ~1.5 m after 60 s, linear, instead of b·60²/2 = 90 m unbounded
    assert h_z[-1] == pytest.approx(0.025 * 59.99, rel=0.02)


def test_broad_fast_translation_windows(broad_dir):
    t = trial_slice(broad_dir, "15_undisturbed_fast_translation_A", 100.0)
    k = int(0.5 * t.rate_hz)
    rms = {}
    for cls in (ComplementaryFilter, AdaptiveComplementaryFilter):
        q = broad.run_filter(cls(use_mag=False), t, "6D")
        g = height.gravity_from_rest(q[:k], t.acc_m_s2[:k])
        e = height.window_errors(q, t.acc_m_s2, t.pos_m[:, 2], t.dt_s, 1.0, t.movement, g)
        assert e.size > 40
        rms[cls.name] = float(np.sqrt(np.mean(e**2)))
    assert rms["adaptive"] < 0.15  # m; measured 0.085
    assert rms["complementary"] < 0.5  # m; measured 0.30
