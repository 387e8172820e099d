"""Angle Kalman filter (seed 000): angle conversions against gateway.fusion.quaternion, online R against a known
noise variance, wrap and gimbal-lock handling, unit norm, convergence, filterpy `update()` == numba `run()`, BROAD."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.kf import (
    KalmanAngleFilter,
    KfSettings,
    euler_from_quat,
    first_order_step,
    measured_angles,
    noise_estimate,
    prepare,
    quat_from_euler,
)
from tests.fusion.conftest import (
    FIELD_ENU_UT,
    assert_quat_close,
    static_imu,
    synthetic_imu,
    trial_slice,
    unit_quats,
    vectors,
)

angles = st.tuples(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))


def wrapped_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi


@given(q=unit_quats())
def test_euler_matches_quaternion_module(q):
    ang = euler_from_quat(q)
    # at pitch ±90° roll and yaw are not separable (both atan2 of rounding noise): skip the gimbal-lock region
    if abs(ang[1]) < np.deg2rad(89.0):
        assert_quat_close(quat_from_euler(ang), q, atol=1e-9)
        np.testing.assert_allclose(wrapped_diff(ang, quat.to_euler(q)), 0.0, atol=1e-9)


@given(a=angles)
def test_quat_from_euler_matches_quaternion_module(a):
    assert_quat_close(quat_from_euler(np.array(a)), quat.from_euler(*a), atol=1e-12)


@given(q=unit_quats(), w=vectors(5.0))
def test_first_order_step_matches_quaternion_module(q, w):
    np.testing.assert_allclose(first_order_step(q, w, 0.01), quat.first_order_update(q, w, 0.01), atol=1e-14)


@given(a=st.tuples(st.floats(-3.1, 3.1), st.floats(-1.4, 1.4), st.floats(-3.1, 3.1)))
def test_measured_angles_recover_attitude_from_clean_vectors(a):
    q = quat.from_euler(*a)
    acc = quat.rotate_inverse(q, [0.0, 0.0, 9.81])
    mag = quat.rotate_inverse(q, FIELD_ENU_UT)
    np.testing.assert_allclose(wrapped_diff(measured_angles(acc, mag, True), a), 0.0, atol=1e-9)


def test_noise_estimate_recovers_variance_of_a_sequence(rng):
    """R = E[f²]/2 with f the difference of successive white errors (eq. 44-45) → σ², within 5 % (N = 2·10⁵)."""
    sigma = 0.03
    theta = rng.normal(scale=sigma, size=200_001)
    f = np.diff(theta)
    mean_f2 = 0.0
    for v in f:
        mean_f2 = noise_estimate(mean_f2, v, 1e-4)
    assert abs(0.5 * mean_f2 / sigma**2 - 1.0) < 0.05


def test_online_r_recovers_known_accelerometer_and_magnetometer_noise(rng):
    """Static IMU, exact gyro, white acc and mag noise: R → each measured angle's noise variance.

    Roll and pitch: (σ_a/g)². Yaw: (σ_m/B_h)² from the horizontal field plus the tilt noise carried over by the tilt
    compensation, (B_v/B_h)² (σ_a/g)² (small-angle: a tilt error δ turns the vertical field B_v into B_v·δ of
    horizontal field, along the tilt axis)."""
    q_true = quat.from_euler(0.0, 0.0, 0.3)
    data = static_imu(q_true, seconds=150.0)
    sig_acc, sig_mag = 0.05, 0.3
    acc = data["acc"] + rng.normal(scale=sig_acc, size=data["acc"].shape)
    mag = data["mag"] + rng.normal(scale=sig_mag, size=data["mag"].shape)
    kf = KalmanAngleFilter(KfSettings(paper=True, r_window_s=20.0))
    kf.initialise(acc[:50].mean(0), mag[:50].mean(0))
    kf.run(data["gyr"], acc, mag, data["dt_s"])
    tilt_var = (sig_acc / 9.81) ** 2
    b_h, b_v = np.hypot(*FIELD_ENU_UT[:2]), abs(FIELD_ENU_UT[2])
    expected = np.array([tilt_var, tilt_var, (sig_mag / b_h) ** 2 + (b_v / b_h) ** 2 * tilt_var])
    np.testing.assert_allclose(kf.measurement_noise_rad2, expected, rtol=0.12)


@given(q0=unit_quats(), w=vectors(5.0), acc=vectors(20.0), mag=vectors(60.0), paper=st.booleans())
def test_update_keeps_unit_norm(q0, w, acc, mag, paper):
    acc = acc + np.array([0.0, 0.0, 0.5])
    mag = mag + np.array([0.0, 1.0, 0.0])
    kf = KalmanAngleFilter(KfSettings(paper=paper))
    kf.initialise(quat.rotate_inverse(q0, [0, 0, 9.81]), quat.rotate_inverse(q0, FIELD_ENU_UT))
    for _ in range(3):
        q = kf.update(w, acc, mag, 0.01)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12


@pytest.mark.parametrize("use_mag", [True, False])
def test_converges_from_wrong_start_on_static_data(use_mag):
    q_true = quat.from_euler(0.4, -0.3, 1.0)
    data = static_imu(q_true, seconds=20.0)
    kf = KalmanAngleFilter(use_mag=use_mag)
    q_wrong = quat.from_euler(0.4 + 0.5, -0.3 - 0.4, 1.0 + 0.8)
    kf.initialise(quat.rotate_inverse(q_wrong, [0, 0, 9.81]), quat.rotate_inverse(q_wrong, FIELD_ENU_UT))
    q = kf.run(data["gyr"], data["acc"], data["mag"] if use_mag else None, data["dt_s"])
    total, _, incl = broad.error_angles(broad.error_quaternion(q[-1], q_true))
    assert np.rad2deg(incl) < 0.5
    if use_mag:
        assert np.rad2deg(total) < 0.5
    else:  # 6D: the start yaw is 0 by convention and only the (zero) gyro rate moves it
        assert abs(np.rad2deg(quat.to_euler(q[-1])[2])) < 0.5


def test_yaw_wraps_through_pi_without_a_jump(rng):
    """Heading at 179.9°: noisy measurements fall on both sides of ±180°; the estimate must not swing round."""
    q_true = quat.from_euler(0.1, 0.05, np.pi - 0.002)
    data = static_imu(q_true, seconds=10.0)
    mag = data["mag"] + rng.normal(scale=0.5, size=data["mag"].shape)
    kf = KalmanAngleFilter()
    kf.initialise(data["acc"][0], data["mag"][0])
    q = kf.run(data["gyr"], data["acc"], mag, data["dt_s"])
    total = np.rad2deg(broad.error_angles(broad.error_quaternion(q, q_true))[0])
    # an unwrapped ≈2π innovation would swing the estimate round through large errors
    assert total.max() < 3.0  # first samples: noisy measurements before R has been learnt
    assert total[100:].max() < 1.0


def test_gimbal_lock_leaves_roll_and_yaw_to_the_gyro():
    """Near pitch ±90° the roll and yaw measurement noise is divided by cos²(pitch); pitch's is untouched."""
    settings = KfSettings(paper=True)
    params = settings.as_array()
    aux = np.zeros(11)
    aux[:3] = [2e-4, 3e-4, 4e-4]  # E[f²] per angle; have-previous flag 0 so this sample does not change it
    acc, mag, ref = np.array([0.0, 0.0, 9.81]), np.array([0.0, 18.0, -46.0]), np.array([9.81, 49.4, -1.2])
    r = {}
    for pitch in (0.0, 1.4):
        _, _, _, r[pitch], _ = prepare(np.array([0.1, pitch, 0.3]), aux, np.zeros(3), acc, mag, True, 0.01, ref, params)
    scale = np.diag(r[1.4]) / np.diag(r[0.0])
    np.testing.assert_allclose(scale, [1 / np.cos(1.4) ** 2, 1.0, 1 / np.cos(1.4) ** 2], rtol=1e-9)


def test_pitching_through_vertical_stays_on_track(rng):
    """Rotate about body y through pitch ±90° (gimbal lock) and back: error stays small, no blow-up.

    (Behaviour check: the online R also rises there, so this passes without the cos² scaling too; the test above
    checks the scaling itself.)"""
    dt, rate = 0.01, 0.8  # rad/s about body y: pitch goes 0 → beyond 90° → back
    t = np.arange(0.0, 8.0, dt)
    w_y = -rate * np.sign(np.sin(2 * np.pi * t / 8.0))  # negative body-y rate raises body x (pitch up)
    gyr = np.stack([np.zeros_like(t), w_y, np.zeros_like(t)], axis=-1)
    q = np.empty((t.size, 4))
    q[0] = quat.from_euler(0.0, 0.0, 0.5)
    for i in range(1, t.size):
        q[i] = quat.integrate_exact(q[i - 1], gyr[i - 1], dt)
    acc = quat.rotate_inverse(q, [0.0, 0.0, 9.81]) + rng.normal(scale=0.05, size=gyr.shape)
    mag = quat.rotate_inverse(q, FIELD_ENU_UT) + rng.normal(scale=0.3, size=gyr.shape)
    assert quat.to_euler(q)[:, 1].max() > np.deg2rad(89.0)
    kf = KalmanAngleFilter()
    kf.initialise(acc[:20].mean(0), mag[:20].mean(0))
    q_est = kf.run(gyr, acc, mag, dt)
    total = broad.error_angles(broad.error_quaternion(q_est, q))[0]
    assert np.all(np.isfinite(q_est))
    assert np.rad2deg(total.max()) < 3.0


@pytest.mark.parametrize("use_mag", [True, False])
@pytest.mark.parametrize(("paper", "fig4"), [(True, False), (False, False), (True, True)])
def test_filterpy_update_equals_numba_run(use_mag, paper, fig4):
    data = synthetic_imu(4.0, rate_hz=100.0, seed=3, gyr_bias_rad_s=np.array([0.01, 0.0, -0.01]), ext_acc_m_s2=2.0)
    n = 300
    still = static_imu(data["q_true"][0], seconds=1.0)
    gyr = np.vstack([still["gyr"], data["gyr"]])[:n]
    acc = np.vstack([still["acc"], data["acc"]])[:n]
    mag = np.vstack([still["mag"], data["mag"]])[:n]
    gains = {"fig4_kp_rad_s": 0.2, "fig4_ki_rad_s2": 0.01} if fig4 else {}
    a, b = (KalmanAngleFilter(KfSettings(paper=paper, rest_time_s=0.3, **gains), use_mag=use_mag) for _ in range(2))
    for f in (a, b):
        f.initialise(acc[:20].mean(0), mag[:20].mean(0))
    q_run = a.run(gyr, acc, mag if use_mag else None, data["dt_s"])
    q_upd = np.array([b.update(gyr[i], acc[i], mag[i] if use_mag else None, data["dt_s"]) for i in range(n)])
    np.testing.assert_allclose(q_upd, q_run, atol=1e-9, rtol=0)
    np.testing.assert_allclose(b.measurement_noise_rad2, a.measurement_noise_rad2, rtol=1e-9)


@pytest.mark.parametrize(
    ("name", "limit_9d_deg", "limit_6d_incl_deg"),
    [("01_undisturbed_slow_rotation_A", 2.0, 1.0), ("10_undisturbed_slow_translation_A", 3.5, 3.5)],
)
def test_broad_slice_accuracy(broad_dir, name, limit_9d_deg, limit_6d_incl_deg):
    """First 70 s (20k samples, ≈10k scored) of two undisturbed trials; full-trial figures are in docs/fusion.md."""
    trial = trial_slice(broad_dir, name, 70.0)
    _, s9 = broad.evaluate_trial(lambda: KalmanAngleFilter(use_mag=True), trial, "9D")
    _, s6 = broad.evaluate_trial(lambda: KalmanAngleFilter(use_mag=False), trial, "6D")
    assert s9.total_deg < limit_9d_deg
    assert s6.inclination_deg < limit_6d_incl_deg


def test_fig4_integral_learns_minus_the_gyro_bias_on_the_tilt_axes():
    """Fig. 4's cross-product PI: on a still, level sensor the integral converges to −bias on x and y (z, the axis
    about gravity, is unobservable from â × v̂). 60 s at 100 Hz, kp 0.5, ki 0.2: within
    0.002 rad/s. With the correction off the integral stays 0."""
    bias = np.array([0.02, -0.015, 0.01])
    still = static_imu(np.array([1.0, 0.0, 0.0, 0.0]), seconds=60.0, rate_hz=100.0)
    gyr = still["gyr"] + bias
    on = KalmanAngleFilter(KfSettings(paper=True, fig4_kp_rad_s=0.5, fig4_ki_rad_s2=0.2), use_mag=False)
    off = KalmanAngleFilter(KfSettings(paper=True), use_mag=False)
    for f in (on, off):
        f.initialise(still["acc"][:50].mean(0), None)
        f.run(gyr, still["acc"], None, 0.01)
    np.testing.assert_allclose(on.fig4_integral_rad_s[:2], -bias[:2], atol=0.002)
    assert abs(on.fig4_integral_rad_s[2]) < 1e-6
    np.testing.assert_array_equal(off.fig4_integral_rad_s, 0.0)


@pytest.mark.parametrize("paper", [False, True])
def test_a_free_fall_sample_is_taken_without_an_error(paper):
    """A zero accelerometer vector (free fall, or a device that sends zeros) with the magnetometer gates on: the
    acc-mag dip has no angle, and dividing by |acc| |mag| raised ZeroDivisionError (hypothesis found it in
    `test_update_keeps_unit_norm`); the sample is taken, the quaternion stays a unit one."""
    kf = KalmanAngleFilter(KfSettings(paper=paper))
    kf.initialise(np.array([0.0, 0.0, 9.81]), np.asarray(FIELD_ENU_UT))
    for _ in range(3):
        q = kf.update(np.zeros(3), np.zeros(3), np.array([0.0, 1.0, 0.0]), 0.01)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
