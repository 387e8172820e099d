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


def trial_slice(broad_dir: Path, name: str, seconds: float) -> broad.Trial:
    """The first `seconds` of a BROAD trial (it starts at rest), cached across tests."""
    t = _load(str(broad_dir / f"{name}.mat"))
    return t.slice(0, int(seconds * t.rate_hz))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


# numba compiles on first call (hundreds of ms): timing deadlines would make property tests flaky
settings.register_profile("fusion", deadline=None, max_examples=60)
settings.load_profile("fusion")
