"""Quaternion EKF (seed 001): Jacobians against finite differences, Picard-3 against the exact rotation, unit norm,
convergence from a wrong start, filterpy `update()` == numba `run()`, and accuracy on short BROAD slices."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.ekf import (
    EkfSettings,
    QuaternionEkf,
    observation_jacobian,
    picard3_matrix,
    rotate_to_body,
    transition,
)
from tests.fusion.conftest import assert_quat_close, static_imu, synthetic_imu, trial_slice, unit_quats, vectors


def numerical_jacobian(func, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Central differences, column per input component (truncation error O(eps²))."""
    cols = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = eps
        cols.append((func(x + dx) - func(x - dx)) / (2 * eps))
    return np.stack(cols, axis=-1)


@given(q=unit_quats(), v=vectors(2.0), scale=st.floats(0.5, 2.0))
def test_observation_jacobian_matches_finite_differences(q, v, scale):
    q = q * scale  # h(Q) is a polynomial in Q: the Jacobian must hold off the unit sphere too
    analytic = observation_jacobian(q, v)
    numeric = numerical_jacobian(lambda qq: rotate_to_body(qq, v), q)
    np.testing.assert_allclose(analytic, numeric, atol=1e-7 * (1 + np.linalg.norm(v)))


@given(q=unit_quats(), v=vectors(5.0))
def test_rotate_to_body_is_inverse_rotation(q, v):
    np.testing.assert_allclose(rotate_to_body(q, v), quat.rotate_inverse(q, v), atol=1e-12)


@given(q=unit_quats(), w=vectors(3.0), b=vectors(0.05))
def test_transition_jacobian_matches_finite_differences(q, w, b):
    """∂f/∂q is exact (the Picard step is linear in Q); ∂f/∂b keeps the first-order term only: O(Δθ²) off."""
    dt = 0.01
    x = np.concatenate([q, b])
    _, analytic = transition(x, w, dt)
    numeric = numerical_jacobian(lambda xx: transition(xx, w, dt)[0], x)
    np.testing.assert_allclose(analytic[:, :4], numeric[:, :4], atol=1e-8)
    theta = np.linalg.norm((w - b) * dt)
    np.testing.assert_allclose(analytic[:, 4:], numeric[:, 4:], atol=dt * theta + 1e-8)


@given(q=unit_quats(), w=vectors(10.0))
def test_picard3_matches_exact_rotation(q, w):
    """Picard-3 truncates the series of exp(ΔΘ/2) after the cubic term: error ≤ Δθ⁴/384 + normalisation."""
    dt = 0.005
    approx = picard3_matrix(w * dt) @ q
    exact = quat.integrate_exact(q, w, dt)
    theta = np.linalg.norm(w) * dt
    np.testing.assert_allclose(approx, exact, atol=theta**4 / 100 + 1e-14)
    np.testing.assert_allclose(approx, quat.picard3_update(q, w, dt, renormalise=False), atol=1e-14)


@given(q0=unit_quats(), w=vectors(5.0), acc=vectors(20.0), mag=vectors(60.0), paper=st.booleans())
def test_update_keeps_unit_norm(q0, w, acc, mag, paper):
    acc = acc + np.array([0.0, 0.0, 0.5])  # keep away from the zero vector
    mag = mag + np.array([0.0, 1.0, 0.0])
    ekf = QuaternionEkf(EkfSettings(paper=paper))
    ekf.initialise(quat.rotate_inverse(q0, [0, 0, 9.81]), quat.rotate_inverse(q0, [0, 18.0, -46.0]))
    for _ in range(3):
        q = ekf.update(w, acc, mag, 0.01)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
        assert np.all(np.isfinite(q))


@pytest.mark.parametrize("use_mag", [True, False])
@pytest.mark.parametrize("paper", [True, False])
def test_converges_from_wrong_start_on_static_data(use_mag, paper):
    q_true = quat.from_euler(0.4, -0.3, 1.0)
    data = static_imu(q_true, seconds=40.0)  # heading time constant ≈ 5 s (σ_m / σ_g), start ≈ 60° off
    ekf = QuaternionEkf(EkfSettings(paper=paper), use_mag=use_mag)
    q_wrong = quat.from_euler(0.4 + 0.5, -0.3 - 0.4, 1.0 + 0.8)
    ekf.initialise(quat.rotate_inverse(q_wrong, [0, 0, 9.81]), quat.rotate_inverse(q_wrong, [0, 18.0, -46.0]))
    q = ekf.run(data["gyr"], data["acc"], data["mag"] if use_mag else None, data["dt_s"])
    err = broad.error_angles(broad.error_quaternion(q[-1], q_true))
    assert np.rad2deg(err[2]) < 0.5  # inclination
    if use_mag:
        assert np.rad2deg(err[0]) < 0.5  # total


def test_learns_gyro_bias_at_rest():
    bias = np.array([0.01, -0.008, 0.012])
    q_true = quat.from_euler(0.1, 0.2, -0.5)
    data = static_imu(q_true, seconds=5.0)
    ekf = QuaternionEkf(use_mag=False)
    ekf.initialise(data["acc"][0], None)
    ekf.run(data["gyr"] + bias, data["acc"], None, data["dt_s"])
    np.testing.assert_allclose(ekf.gyro_bias_rad_s, bias, atol=5e-4)
    paper = QuaternionEkf(EkfSettings(paper=True), use_mag=False)
    paper.initialise(data["acc"][0], None)
    paper.run(data["gyr"] + bias, data["acc"], None, data["dt_s"])
    np.testing.assert_array_equal(paper.gyro_bias_rad_s, 0.0)


@pytest.mark.parametrize("use_mag", [True, False])
@pytest.mark.parametrize("paper", [True, False])
def test_filterpy_update_equals_numba_run(use_mag, paper):
    data = synthetic_imu(4.0, rate_hz=100.0, seed=3, gyr_bias_rad_s=np.array([0.01, 0.0, -0.01]), ext_acc_m_s2=2.0)
    n = 300
    # a still start so the rest detector and zero-rate update are exercised too
    still = static_imu(data["q_true"][0], seconds=1.0)
    gyr = np.vstack([still["gyr"], data["gyr"]])[:n]
    acc = np.vstack([still["acc"], data["acc"]])[:n]
    mag = np.vstack([still["mag"], data["mag"]])[:n]
    a, b = (QuaternionEkf(EkfSettings(paper=paper, rest_time_s=0.3), use_mag=use_mag) for _ in range(2))
    for f in (a, b):
        f.initialise(acc[:20].mean(0), mag[:20].mean(0))
    q_run = a.run(gyr, acc, mag if use_mag else None, data["dt_s"])
    q_upd = np.array([b.update(gyr[i], acc[i], mag[i] if use_mag else None, data["dt_s"]) for i in range(n)])
    np.testing.assert_allclose(q_upd, q_run, atol=1e-9, rtol=0)
    np.testing.assert_allclose(b.gyro_bias_rad_s, a.gyro_bias_rad_s, atol=1e-9, rtol=0)


def test_tracks_synthetic_motion():
    data = synthetic_imu(30.0, rate_hz=200.0, seed=5, gyr_bias_rad_s=np.array([0.005, -0.004, 0.003]))
    ekf = QuaternionEkf()
    q0 = data["q_true"][0]
    ekf.initialise(quat.rotate_inverse(q0, [0, 0, 9.81]), quat.rotate_inverse(q0, [0, 18.0, -46.0]))
    q = ekf.run(data["gyr"], data["acc"], data["mag"], data["dt_s"])
    total = broad.error_angles(broad.error_quaternion(q, data["q_true"]))[0]
    assert np.rad2deg(np.sqrt(np.mean(total**2))) < 2.0
    assert_quat_close(q[-1], data["q_true"][-1], atol=0.03)


@pytest.mark.parametrize(
    ("name", "limit_9d_deg", "limit_6d_incl_deg"),
    [("01_undisturbed_slow_rotation_A", 1.5, 1.0), ("10_undisturbed_slow_translation_A", 2.0, 2.0)],
)
def test_broad_slice_accuracy(broad_dir, name, limit_9d_deg, limit_6d_incl_deg):
    """First 70 s (20k samples, ≈10k scored) of two undisturbed trials; full-trial figures are in docs/fusion.md."""
    trial = trial_slice(broad_dir, name, 70.0)
    _, s9 = broad.evaluate_trial(lambda: QuaternionEkf(use_mag=True), trial, "9D")
    _, s6 = broad.evaluate_trial(lambda: QuaternionEkf(use_mag=False), trial, "6D")
    assert s9.total_deg < limit_9d_deg
    assert s6.inclination_deg < limit_6d_incl_deg
