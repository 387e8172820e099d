"""Plain and adaptive complementary filters (seed 002): streaming == batch, unit norm, convergence, the gain
schedule, and BROAD accuracy on the first 80 s of two trials.

Measured with the defaults (80 s slices), inclination RMSE: 06 fast rotation plain 0.57°, adaptive 0.80°;
15 fast translation plain 6.19°, adaptive 2.71°. Thresholds leave margin; a sign error gives tens of degrees."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.complementary import (
    AdaptiveComplementaryFilter,
    AdaptiveSettings,
    ComplementaryFilter,
    ComplementarySettings,
)
from tests.fusion.conftest import numba_settings, static_imu, synthetic_imu, trial_slice, unit_quats, vectors

FILTERS = [ComplementaryFilter, AdaptiveComplementaryFilter]


def _incl_rmse_deg(q, q_true, skip=1000):
    e = np.rad2deg(broad.error_angles(broad.error_quaternion(q, q_true))[2])
    return float(np.sqrt(np.mean(e[skip:] ** 2)))


@pytest.mark.parametrize("cls", FILTERS)
@pytest.mark.parametrize("use_mag", [True, False])
def test_run_equals_repeated_update(cls, use_mag):
    d = synthetic_imu(20.0, seed=4, gyr_bias_rad_s=np.array([0.01, -0.02, 0.005]), ext_acc_m_s2=3.0)
    a, b = cls(use_mag=use_mag), cls(use_mag=use_mag)
    a.initialise(d["acc"][0], d["mag"][0])
    b.initialise(d["acc"][0], d["mag"][0])
    q_run = a.run(d["gyr"], d["acc"], d["mag"] if use_mag else None, d["dt_s"])
    q_upd = np.array([b.update(g, ac, m if use_mag else None, d["dt_s"])
                      for g, ac, m in zip(d["gyr"], d["acc"], d["mag"], strict=True)])
    np.testing.assert_allclose(q_run, q_upd, atol=1e-9, rtol=0)
    assert a.kp_rad_s == pytest.approx(b.kp_rad_s, abs=1e-12)


@numba_settings
@given(unit_quats(), vectors(30.0), vectors(50.0), vectors(80.0), st.floats(1e-3, 0.05))
def test_update_keeps_unit_norm(q0, gyr, acc, mag, dt):
    for f in (ComplementaryFilter(ComplementarySettings(k_rad_s=5.0, k_mag_rad_s=2.0)),
              AdaptiveComplementaryFilter(AdaptiveSettings(kp_still_rad_s=5.0, ki_still_rad_s2=0.5))):
        f._state[:4] = q0
        for _ in range(5):
            q = f.update(gyr, acc, mag, dt)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("cls", FILTERS)
def test_converges_from_a_wrong_initial_attitude(cls):
    q_true = quat.from_euler(-0.5, 0.6, -2.0)
    d = static_imu(q_true, 90.0)
    f = cls()
    f.initialise(quat.rotate_inverse(quat.from_euler(0.5, -0.2, 1.0), [0, 0, 9.81]), None)  # ~70° tilt off
    q = f.run(d["gyr"], d["acc"], d["mag"], d["dt_s"])
    start, end = (broad.error_angles(broad.error_quaternion(x, q_true)) for x in (q[0], q[-1]))
    assert np.rad2deg(start[2]) > 30
    assert np.rad2deg(end[2]) < 0.2  # inclination, K >= 0.2 rad/s over 90 s
    assert np.rad2deg(end[0]) < 1.0  # total, heading via k_mag = 0.1 rad/s


@pytest.mark.parametrize("cls", FILTERS)
def test_run_rejects_mismatched_lengths(cls):
    with pytest.raises(ValueError, match="shape"):
        cls().run(np.zeros((10, 3)), np.zeros((9, 3)), None, 0.01)


def test_plain_is_a_first_order_low_pass_with_crossover_k():
    # a step of accelerometer tilt at zero rate: the estimate follows 1 - exp(-K t) (eq. 5, K/(s+K))
    k = 0.5
    q_true = quat.from_euler(np.deg2rad(10.0), 0.0, 0.0)
    d = static_imu(q_true, 4.0, rate_hz=1000.0)
    f = ComplementaryFilter(ComplementarySettings(k_rad_s=k), use_mag=False)
    f.initialise(np.array([0, 0, 9.81]), None)
    roll = quat.to_euler(f.run(d["gyr"], d["acc"], None, d["dt_s"]))[:, 0]
    t = np.arange(1, len(roll) + 1) * d["dt_s"]
    np.testing.assert_allclose(roll, np.deg2rad(10.0) * (1 - np.exp(-k * t)), atol=np.deg2rad(0.01))


def test_adaptive_gain_drops_in_motion_and_recovers_at_rest():
    s = AdaptiveSettings()
    f = AdaptiveComplementaryFilter(s, use_mag=False)
    f.initialise(np.array([0, 0, 9.81]), None)
    still = np.tile([0, 0, 9.81], (100, 1))
    f.run(np.zeros((100, 3)), still, None, 0.01)
    assert f.kp_rad_s == pytest.approx(s.kp_still_rad_s, rel=1e-6)
    shaking = still + np.array([0, 0, 8.0]) * np.sign(np.sin(np.arange(100)))[:, None]
    f.run(np.zeros((100, 3)), shaking, None, 0.01)
    assert f.kp_rad_s < 0.3 * s.kp_still_rad_s
    f.run(np.zeros((1000, 3)), np.tile([0, 0, 9.81], (1000, 1)), None, 0.01)  # 10 s still, tau 1 s
    assert f.kp_rad_s == pytest.approx(s.kp_still_rad_s, rel=1e-3)


def test_adaptive_integral_removes_gyro_bias_the_plain_filter_cannot():
    d = synthetic_imu(120.0, seed=5, gyr_bias_rad_s=np.array([0.01, -0.01, 0.005]))
    errs = {}
    for cls in FILTERS:
        f = cls(use_mag=False)
        f.initialise(d["acc"][0], None)
        errs[cls.name] = _incl_rmse_deg(f.run(d["gyr"], d["acc"], None, d["dt_s"]), d["q_true"])
    # measured: plain 2.51°, adaptive 0.59° (plain steady error ~ bias / K)
    assert errs["adaptive"] < 0.5 * errs["complementary"]


@pytest.mark.parametrize(
    ("name", "max_incl_plain", "max_incl_adaptive"),
    [("06_undisturbed_fast_rotation_A", 0.8, 1.1), ("15_undisturbed_fast_translation_A", 8.0, 3.6)],
)
def test_broad_accuracy_on_short_trials(broad_dir, name, max_incl_plain, max_incl_adaptive):
    t = trial_slice(broad_dir, name, 80.0)
    for cls, limit in ((ComplementaryFilter, max_incl_plain), (AdaptiveComplementaryFilter, max_incl_adaptive)):
        for mode in ("9D", "6D"):
            s = broad.score(broad.run_filter(cls(use_mag=mode == "9D"), t, mode), t, mode)
            assert s.inclination_deg < limit, (cls.name, mode, s)
