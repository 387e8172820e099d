"""Quaternion helpers against scipy.spatial.transform.Rotation (reference) plus hypothesis invariants.

Tolerances: 1e-12 for algebra that is exact in float64 up to rounding; 1e-9 where trigonometry is involved.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from gateway.fusion import quaternion as quat
from tests.fusion.conftest import assert_quat_close, from_scipy, numba_settings, to_scipy, unit_quats, vectors

ATOL = 1e-12
TRIG_ATOL = 1e-9


def random_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    return from_scipy(Rotation.random(n, random_state=rng).as_quat())


def test_multiply_matches_scipy_composition(rng):
    p, q = random_quats(rng, 200), random_quats(rng, 200)
    ref = (Rotation.from_quat(to_scipy(p)) * Rotation.from_quat(to_scipy(q))).as_quat()
    assert_quat_close(quat.multiply(p, q), from_scipy(ref), atol=ATOL)


def test_rotate_is_body_to_earth_and_inverse_undoes_it(rng):
    q, v = random_quats(rng, 100), rng.normal(size=(100, 3))
    ref = Rotation.from_quat(to_scipy(q)).apply(v)
    np.testing.assert_allclose(quat.rotate(q, v), ref, atol=ATOL)
    np.testing.assert_allclose(quat.rotate_inverse(q, ref), v, atol=ATOL)


def test_matrix_round_trip_and_scipy(rng):
    q = random_quats(rng, 300)
    r = quat.to_matrix(q)
    np.testing.assert_allclose(r, Rotation.from_quat(to_scipy(q)).as_matrix(), atol=ATOL)
    assert_quat_close(quat.from_matrix(r), q, atol=ATOL)


def test_from_matrix_handles_half_turns():
    # trace = -1: the w pivot vanishes, another pivot must be taken
    for axis in np.eye(3):
        q = quat.from_axis_angle(axis, np.pi)
        assert_quat_close(quat.from_matrix(quat.to_matrix(q)), q, atol=ATOL)


def test_rotvec_matches_scipy_including_tiny_angles(rng):
    rv = np.concatenate([rng.normal(size=(100, 3)), 1e-7 * rng.normal(size=(20, 3)), np.zeros((1, 3))])
    ref = from_scipy(Rotation.from_rotvec(rv).as_quat())
    assert_quat_close(quat.from_rotvec(rv), ref, atol=ATOL)
    # round trip for angles below π (the principal range of to_rotvec)
    short = rv[:100] / np.linalg.norm(rv[:100], axis=-1, keepdims=True) * rng.uniform(0, 3.1, size=(100, 1))
    np.testing.assert_allclose(quat.to_rotvec(quat.from_rotvec(short)), short, atol=TRIG_ATOL)


def test_euler_matches_scipy_zyx_with_pitch_sign_flipped(rng):
    q = random_quats(rng, 300)
    yaw, neg_pitch, roll = Rotation.from_quat(to_scipy(q)).as_euler("ZYX").T
    np.testing.assert_allclose(quat.to_euler(q), np.stack([roll, -neg_pitch, yaw], axis=-1), atol=TRIG_ATOL)


def test_euler_conventions_on_named_poses():
    # tip 30° up, heading North: pitch +30°, yaw +90°
    q = quat.from_euler(0.0, np.deg2rad(30), np.deg2rad(90))
    x_earth = quat.rotate(q, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(x_earth, [0.0, np.cos(np.deg2rad(30)), 0.5], atol=ATOL)
    np.testing.assert_allclose(np.rad2deg(quat.to_euler(q)), [0.0, 30.0, 90.0], atol=TRIG_ATOL)
    # roll +90°: body y points up
    np.testing.assert_allclose(quat.rotate(quat.from_euler(np.pi / 2, 0, 0), [0, 1.0, 0]), [0, 0, 1.0], atol=ATOL)


@numba_settings
@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_euler_round_trip_away_from_gimbal_lock(roll, pitch, yaw):
    np.testing.assert_allclose(quat.to_euler(quat.from_euler(roll, pitch, yaw)), [roll, pitch, yaw], atol=TRIG_ATOL)


@numba_settings
@given(unit_quats(), vectors())
def test_q_and_minus_q_are_the_same_rotation(q, v):
    np.testing.assert_allclose(quat.rotate(q, v), quat.rotate(-q, v), atol=1e-11)
    np.testing.assert_allclose(quat.to_euler(q)[:2], quat.to_euler(-q)[:2], atol=TRIG_ATOL)
    assert quat.angle_between(q, -q) == pytest.approx(0.0, abs=1e-6)


@numba_settings
@given(unit_quats(), vectors(20.0), st.floats(1e-4, 0.05))
def test_updates_keep_unit_norm(q, gyr, dt):
    for update in (quat.first_order_update, quat.picard3_update, quat.integrate_exact):
        assert np.linalg.norm(update(q, gyr, dt)) == pytest.approx(1.0, abs=1e-12)
    assert np.linalg.norm(quat.gyro_step4(q, gyr, dt)) == pytest.approx(1.0, abs=1e-12)


@numba_settings
@given(unit_quats(), vectors(20.0).filter(lambda w: np.linalg.norm(w) > 0.5), st.floats(1e-3, 0.05))
def test_picard3_is_closer_to_exact_than_first_order(q, gyr, dt):
    exact = quat.integrate_exact(q, gyr, dt)
    err1 = np.linalg.norm(quat.first_order_update(q, gyr, dt, renormalise=False) - exact)
    err3 = np.linalg.norm(quat.picard3_update(q, gyr, dt, renormalise=False) - exact)
    assert err3 < err1


def test_picard3_error_is_third_order(rng):
    # halving the step divides the one-step error by ~2^4 for third order (local error O(dt^4)), ~2^2 for first
    q, w = random_quats(rng, 1)[0], np.array([3.0, -2.0, 1.0])
    e = [np.linalg.norm(quat.picard3_update(q, w, dt, renormalise=False) - quat.integrate_exact(q, w, dt))
         for dt in (0.02, 0.01)]
    f = [np.linalg.norm(quat.first_order_update(q, w, dt, renormalise=False) - quat.integrate_exact(q, w, dt))
         for dt in (0.02, 0.01)]
    assert 12 < e[0] / e[1] < 20
    assert 3 < f[0] / f[1] < 5


@numba_settings
@given(unit_quats(), vectors(20.0), st.floats(1e-4, 0.05))
def test_numba_kernels_match_numpy(q, w, dt):
    p = quat.normalise(q[::-1])
    np.testing.assert_allclose(quat.mul4(p, q), quat.multiply(p, q), atol=ATOL)
    np.testing.assert_allclose(quat.rotate4(q, w), quat.rotate(q, w), atol=1e-11)
    np.testing.assert_allclose(quat.rotate_inverse4(q, w), quat.rotate_inverse(q, w), atol=1e-11)
    np.testing.assert_allclose(quat.gyro_step4(q, w, dt), quat.integrate_exact(q, w, dt), atol=ATOL)


@numba_settings
@given(st.lists(st.floats(-0.5, 0.5), min_size=2, max_size=200), st.floats(-3.0, 3.0))
def test_yaw_wrap_then_unwrap_recovers_continuous_yaw(steps, start):
    yaw = start + np.cumsum(steps)
    wrapped = quat.wrap_angle(yaw)
    assert np.all((wrapped > -np.pi) & (wrapped <= np.pi))
    unwrapped = quat.unwrap_yaw(wrapped)
    np.testing.assert_allclose(unwrapped - unwrapped[0], yaw - yaw[0], atol=1e-9)
    streaming = quat.YawUnwrapper()
    np.testing.assert_allclose([streaming.update(float(a)) for a in wrapped], unwrapped, atol=1e-9)


def test_from_acc_reproduces_gravity_direction(rng):
    q = random_quats(rng, 50)
    acc = quat.rotate_inverse(q, [0, 0, 9.81])
    q0 = quat.from_acc(acc)
    np.testing.assert_allclose(quat.rotate(q0, acc), np.tile([0, 0, 9.81], (50, 1)), atol=1e-9)
    np.testing.assert_allclose(quat.to_euler(q0)[:, 2], 0.0, atol=1e-9)


def test_from_acc_mag_recovers_attitude_with_dip(rng):
    # ENU field of Berlin: ~18 µT North, ~46 µT down
    field_earth = np.array([0.0, 18.0, -46.0])
    q = random_quats(rng, 50)
    acc = quat.rotate_inverse(q, [0, 0, 9.81])
    mag = quat.rotate_inverse(q, field_earth)
    assert_quat_close(quat.from_acc_mag(acc, mag), q, atol=1e-9)
    tilt = quat.from_acc(acc)
    np.testing.assert_allclose(
        quat.wrap_angle(quat.heading_from_mag(tilt, mag) - quat.to_euler(q)[:, 2]), 0.0, atol=1e-9
    )
