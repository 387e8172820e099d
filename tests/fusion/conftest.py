"""Fusion test helpers: hypothesis strategies for unit quaternions and rates, sign-insensitive comparison,
and short BROAD slices (the `broad_dir` fixture in tests/conftest.py skips when the data is absent)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.fusion import broad

finite = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_infinity=False)


@st.composite
def unit_quats(draw: st.DrawFn) -> np.ndarray:
    """Unit quaternions, drawn away from the zero vector before normalising."""
    v = draw(arrays(np.float64, 4, elements=finite).filter(lambda a: np.linalg.norm(a) > 0.1))
    return v / np.linalg.norm(v)


def vectors(scale: float = 10.0) -> st.SearchStrategy[np.ndarray]:
    return arrays(np.float64, 3, elements=st.floats(-scale, scale, allow_nan=False, allow_infinity=False))


def assert_quat_close(q_est: np.ndarray, q_ref: np.ndarray, atol: float) -> None:
    """Element-wise comparison after flipping q_est to the sign of q_ref (q and -q are one rotation)."""
    q_est, q_ref = np.asarray(q_est, float), np.asarray(q_ref, float)
    sign = np.where(np.sum(q_est * q_ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(q_est * sign, q_ref, atol=atol, rtol=0)


def to_scipy(q: np.ndarray) -> np.ndarray:
    """wxyz -> xyzw, only at the scipy boundary."""
    return np.asarray(q)[..., [1, 2, 3, 0]]


def from_scipy(q: np.ndarray) -> np.ndarray:
    return np.asarray(q)[..., [3, 0, 1, 2]]


@lru_cache(maxsize=8)
def _load(path: str) -> broad.Trial:
    return broad.load_trial(path)


def trial_path(broad_dir: Path, name: str) -> Path:
    """Path of a named trial; skips the test if the folder (e.g. one set by RIG_BROAD_DIR) does not hold it."""
    path = broad_dir / f"{name}.mat"
    if not path.is_file():
        pytest.skip(f"{name}.mat is not in {broad_dir} (this test needs that trial of the development set)")
    return path


def load_named(broad_dir: Path, name: str) -> broad.Trial:
    """A whole named trial, cached across tests (skips when absent, as `trial_path`)."""
    return _load(str(trial_path(broad_dir, name)))


def trial_slice(broad_dir: Path, name: str, seconds: float) -> broad.Trial:
    """The first `seconds` of a BROAD trial (it starts at rest), cached across tests."""
    t = load_named(broad_dir, name)
    return t.slice(0, int(seconds * t.rate_hz))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


# numba compiles on first call (hundreds of ms): timing deadlines would make property tests flaky.
# `numba_settings` states it per test; the profile keeps it for the other fusion tests that import these helpers.
numba_settings = settings(deadline=None, max_examples=60)
settings.register_profile("fusion", deadline=None, max_examples=60)
settings.load_profile("fusion")


FIELD_ENU_UT = np.array([0.0, 18.0, -46.0])  # Berlin-like field: 18 µT North, 46 µT down


def synthetic_imu(
    seconds: float,
    rate_hz: float = 100.0,
    seed: int = 0,
    rate_amp_rad_s: float = 1.0,
    gyr_bias_rad_s: np.ndarray | None = None,
    ext_acc_m_s2: float = 0.0,
    noise: bool = True,
) -> dict[str, np.ndarray]:
    """Smooth random rotation with exact truth: returns q_true (N,4), gyr, acc, mag (N,3), dt_s.

    Body rate = sum of sinusoids; truth integrated exactly per sample; acc = Rᵀ (g up + external accel),
    external accel = bursts of `ext_acc_m_s2` amplitude sinusoids; mag = Rᵀ field."""
    from gateway.fusion import quaternion as quat

    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    freqs = rng.uniform(0.05, 0.5, size=(3, 3))
    phases = rng.uniform(0, 2 * np.pi, size=(3, 3))
    w = rate_amp_rad_s * np.stack([np.sin(2 * np.pi * freqs[k] * t[:, None] + phases[k]).sum(-1) / 3 for k in range(3)],
                                  axis=-1)
    q = np.empty((n, 4))
    q[0] = quat.normalise(rng.normal(size=4))
    steps = quat.exp_gyro_step(w[:-1], dt)
    for i in range(1, n):
        q[i] = quat.normalise(quat.multiply(q[i - 1], steps[i - 1]))
    ext = np.zeros((n, 3))
    if ext_acc_m_s2 > 0:
        burst = (np.sin(2 * np.pi * 0.1 * t) > 0.3).astype(float)[:, None]
        ext = ext_acc_m_s2 * burst * np.sin(2 * np.pi * np.array([1.3, 1.7, 2.3]) * t[:, None])
    acc = quat.rotate_inverse(q, np.array([0, 0, quat.GRAVITY_M_S2]) + ext)
    mag = quat.rotate_inverse(q, FIELD_ENU_UT)
    gyr = w + (0.0 if gyr_bias_rad_s is None else gyr_bias_rad_s)
    if noise:
        gyr = gyr + rng.normal(scale=0.005, size=gyr.shape)
        acc = acc + rng.normal(scale=0.05, size=acc.shape)
        mag = mag + rng.normal(scale=0.3, size=mag.shape)
    return {"q_true": q, "gyr": gyr, "acc": acc, "mag": mag, "dt_s": dt}


def static_imu(q_true: np.ndarray, seconds: float, rate_hz: float = 100.0) -> dict[str, np.ndarray]:
    """A motionless IMU at attitude q_true: zero rate, gravity and field only (no noise)."""
    from gateway.fusion import quaternion as quat

    n = int(seconds * rate_hz)
    acc = np.tile(quat.rotate_inverse(q_true, [0, 0, quat.GRAVITY_M_S2]), (n, 1))
    mag = np.tile(quat.rotate_inverse(q_true, FIELD_ENU_UT), (n, 1))
    return {"gyr": np.zeros((n, 3)), "acc": acc, "mag": mag, "dt_s": 1.0 / rate_hz}
