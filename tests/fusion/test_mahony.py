"""Mahony filter (seed 004): streaming == batch, unit norm, convergence from a wrong start, BROAD accuracy.

BROAD thresholds come from the first 80 s of two trials (movement starts after ~35-45 s), measured with the
default gains: 06 fast rotation 9D total 1.65°, 6D incl 0.57°; 24 tapping 9D total 2.26°, incl 2.14°.
Thresholds leave ~30 % margin; a broken correction (e.g. sign error) gives tens of degrees."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.mahony import MahonyFilter, MahonySettings
from tests.fusion.conftest import numba_settings, static_imu, synthetic_imu, trial_slice, unit_quats, vectors


def test_run_equals_repeated_update():
    d = synthetic_imu(20.0, seed=3, gyr_bias_rad_s=np.array([0.01, -0.02, 0.005]), ext_acc_m_s2=2.0)
    for use_mag in (True, False):
        a, b = MahonyFilter(use_mag=use_mag), MahonyFilter(use_mag=use_mag)
        a.initialise(d["acc"][0], d["mag"][0])
        b.initialise(d["acc"][0], d["mag"][0])
        q_run = a.run(d["gyr"], d["acc"], d["mag"] if use_mag else None, d["dt_s"])
        q_upd = np.array([b.update(g, ac, m if use_mag else None, d["dt_s"])
                          for g, ac, m in zip(d["gyr"], d["acc"], d["mag"], strict=True)])
        np.testing.assert_allclose(q_run, q_upd, atol=1e-9, rtol=0)
        np.testing.assert_allclose(a.integral_rad_s, b.integral_rad_s, atol=1e-9)


def test_run_rejects_mismatched_lengths():
    with pytest.raises(ValueError, match="shape"):
        MahonyFilter().run(np.zeros((10, 3)), np.zeros((10, 3)), np.zeros((9, 3)), 0.01)


@numba_settings
@given(unit_quats(), vectors(30.0), vectors(50.0), vectors(80.0), st.floats(1e-3, 0.05))
def test_update_keeps_unit_norm(q0, gyr, acc, mag, dt):
    f = MahonyFilter(MahonySettings(kp=5.0, ki=0.1, kp_mag=2.0))
    f._state[:4] = q0
    for _ in range(5):
        q = f.update(gyr, acc, mag, dt)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("use_mag", [True, False])
def test_converges_from_a_wrong_initial_attitude(use_mag):
    q_true = quat.from_euler(0.4, -0.3, 1.2)
    d = static_imu(q_true, 120.0)
    f = MahonyFilter(use_mag=use_mag)
    f.initialise(quat.rotate_inverse(quat.from_euler(1.0, 0.4, 2.5), [0, 0, 9.81]), None)  # ~50° off in tilt
    q = f.run(d["gyr"], d["acc"], d["mag"] if use_mag else None, d["dt_s"])
    err = broad.error_angles(broad.error_quaternion(q[-1], q_true))
    assert np.rad2deg(err[2]) < 0.5  # inclination settles (kp = 0.2 rad/s: tau 5 s)
    if use_mag:
        assert np.rad2deg(err[0]) < 1.0  # heading too (kp_mag = 0.1 rad/s)
    # the start really was wrong
    assert np.rad2deg(broad.error_angles(broad.error_quaternion(q[0], q_true))[2]) > 30


def test_integral_learns_gyro_bias_on_tilt_axes():
    bias = np.array([0.02, -0.015, 0.0])
    q_true = quat.identity()
    d = static_imu(q_true, 2000.0, rate_hz=50.0)  # slow pole ki/kp = 0.0025 rad/s: ~400 s time constant
    f = MahonyFilter()
    f.initialise(d["acc"][0], d["mag"][0])
    f.run(d["gyr"] + bias, d["acc"], d["mag"], d["dt_s"])
    np.testing.assert_allclose(f.integral_rad_s[:2], -bias[:2], atol=2e-3)


@pytest.mark.parametrize(
    ("name", "max_9d_total", "max_incl"),
    [("06_undisturbed_fast_rotation_A", 2.2, 0.8), ("24_disturbed_tapping_A", 3.0, 2.8)],
)
def test_broad_accuracy_on_short_trials(broad_dir, name, max_9d_total, max_incl):
    t = trial_slice(broad_dir, name, 80.0)
    s9 = broad.score(broad.run_filter(MahonyFilter(), t, "9D"), t, "9D")
    s6 = broad.score(broad.run_filter(MahonyFilter(use_mag=False), t, "6D"), t, "6D")
    assert s9.total_deg < max_9d_total
    assert s9.inclination_deg < max_incl and s6.inclination_deg < max_incl
