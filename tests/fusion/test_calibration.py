"""Calibration on synthetic data with known truth (tolerances stated per test)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gateway.fusion import calibration as cal

G = 9.81


def random_dirs(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def phases(rng, rate_hz=100.0):
    """rest 3 s, motion 4 s, rest 3 s; returns gyr, acc, truth mask (rest)."""
    n_rest, n_move = int(3 * rate_hz), int(4 * rate_hz)
    bias = np.array([0.01, -0.02, 0.015])
    gyr = np.concatenate([
        bias + rng.normal(scale=0.003, size=(n_rest, 3)),
        bias + np.sin(np.linspace(0, 20, n_move))[:, None] * np.array([1.0, 0.5, -0.7]),
        bias + rng.normal(scale=0.003, size=(n_rest, 3)),
    ])
    acc = np.concatenate([
        np.array([0, 0, G]) + rng.normal(scale=0.03, size=(n_rest, 3)),
        np.array([0, 0, G]) + 3 * np.cos(np.linspace(0, 30, n_move))[:, None] * np.array([1.0, -1.0, 0.5]),
        np.array([0, 0, G]) + rng.normal(scale=0.03, size=(n_rest, 3)),
    ])
    truth = np.concatenate([np.ones(n_rest, bool), np.zeros(n_move, bool), np.ones(n_rest, bool)])
    return gyr, acc, truth, bias


def test_rest_detector_finds_the_rest_phases_and_online_matches_offline(rng):
    gyr, acc, truth, _ = phases(rng)
    rest = cal.detect_rest(gyr, acc, 100.0)
    w = 50  # 0.5 s window: the first w-1 samples and w-1 after a motion phase cannot be rest yet
    assert rest[w:300].all() and rest[700 + w:].all()
    assert not rest[300:700].any()
    assert not rest[: w - 1].any()
    online = cal.RestDetector(100.0)
    np.testing.assert_array_equal([online.update(g, a) for g, a in zip(gyr, acc, strict=True)], rest)


def test_gyro_bias_from_rest_offline_and_online(rng):
    gyr, acc, _, bias = phases(rng)
    rest = cal.detect_rest(gyr, acc, 100.0)
    # 550 rest samples of 0.003 rad/s noise: standard error ~1.3e-4 rad/s; 5e-4 is ~4 sigma
    np.testing.assert_allclose(cal.gyro_bias_from_rest(gyr, rest), bias, atol=5e-4)
    est = cal.GyroBiasEstimator(100.0)
    est.update_block(gyr, acc)
    assert est.n_rest == rest.sum()
    np.testing.assert_allclose(est.bias_rad_s, cal.gyro_bias_from_rest(gyr, rest), atol=1e-12)
    with pytest.raises(ValueError):
        cal.gyro_bias_from_rest(gyr, np.zeros(len(gyr), bool))


def test_accel_six_position_recovers_offset_and_scale():
    offset, scale = np.array([0.12, -0.3, 0.25]), np.array([1.02, 0.97, 1.01])
    poses = np.concatenate([np.eye(3), -np.eye(3)]) * G
    raw = poses * scale + offset
    est_offset, est_scale = cal.fit_accel_offset_scale(raw)
    np.testing.assert_allclose(est_offset, offset, atol=1e-9)  # exact data: exact fit
    np.testing.assert_allclose(est_scale, scale, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(cal.apply_accel_calibration(raw, est_offset, est_scale), axis=1), G)


def test_accel_many_noisy_poses_streaming(rng):
    offset, scale = np.array([-0.2, 0.1, 0.35]), np.array([0.98, 1.03, 1.0])
    acc = cal.AxisQuadricAccumulator()
    for d in random_dirs(rng, 30):  # 30 poses x 50 samples, noise 0.02 m/s²
        acc.add(d * G * scale + offset + rng.normal(scale=0.02, size=(50, 3)))
    est_offset, est_scale = acc.solve(G)
    np.testing.assert_allclose(est_offset, offset, atol=0.01)  # m/s²
    np.testing.assert_allclose(est_scale, scale, atol=0.002)


def test_mag_minmax_recovers_hard_iron_and_axis_scale(rng):
    offset, gains = np.array([12.0, -30.0, 5.0]), np.array([1.1, 0.9, 1.0])
    m = random_dirs(rng, 20000) * 50.0 * gains + offset
    c = cal.calibrate_mag_minmax(m)
    np.testing.assert_allclose(c.offset_uT, offset, atol=0.3)  # µT: extremes of 20000 samples on a 50 µT sphere
    ratio = np.diag(c.soft_iron) * gains
    np.testing.assert_allclose(ratio / ratio.mean(), 1.0, atol=0.01)
    online = cal.MinMaxMagCalibrator()
    for block in np.array_split(m, 7):
        online.add(block)
    np.testing.assert_allclose(online.solve().offset_uT, c.offset_uT, atol=1e-12)


def test_mag_ellipsoid_recovers_full_soft_iron(rng):
    # symmetric soft-iron distortion D (with off-diagonal terms) and hard iron; truth field 48 µT
    rot = Rotation.from_euler("xyz", [0.3, -0.5, 0.8]).as_matrix()
    d = rot @ np.diag([1.2, 0.85, 1.05]) @ rot.T
    offset = np.array([20.0, -15.0, 8.0])
    truth = random_dirs(rng, 3000) * 48.0
    raw = truth @ d.T + offset + rng.normal(scale=0.2, size=truth.shape)
    c = cal.calibrate_mag_ellipsoid(raw, radius_uT=48.0)
    np.testing.assert_allclose(c.offset_uT, offset, atol=0.1)  # µT
    np.testing.assert_allclose(c.soft_iron, np.linalg.inv(d), atol=0.005)
    np.testing.assert_allclose(np.linalg.norm(c.apply(raw), axis=1), 48.0, atol=1.0)
    # min/max cannot undo the off-diagonal terms: its residual spread is much larger
    mm = cal.calibrate_mag_minmax(raw)
    spread_mm = np.std(np.linalg.norm(mm.apply(raw), axis=1))
    spread_el = np.std(np.linalg.norm(c.apply(raw), axis=1))
    assert spread_el < 0.3 * spread_mm
    online = cal.EllipsoidAccumulator()
    for block in np.array_split(raw, 10):
        online.add(block)
    np.testing.assert_allclose(online.solve(48.0).soft_iron, c.soft_iron, atol=1e-9)
