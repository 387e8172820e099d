"""Every filter of the registry takes a zero accelerometer or magnetometer sample (free fall, or a device that sends
zeros) and gives a finite unit quaternion: a zero vector has no direction, and normalising it raised
ZeroDivisionError in `kf` (the acc-mag dip gate) and made `ekf` NaN (hypothesis found the first in
`tests/fusion/test_kf.py::test_update_keeps_unit_norm`). In the gateway a filter that raises restarts its device, so
each free-fall sample cost a warm-up."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.fusion import registry

G = np.array([0.0, 0.0, 9.81])
FIELD = np.array([0.0, 20.0, -40.0])
SAMPLES = [(np.zeros(3), FIELD), (G, np.zeros(3)), (np.zeros(3), np.zeros(3)), (G, FIELD)]


@pytest.mark.parametrize("use_mag", [False, True])
@pytest.mark.parametrize("name", sorted(registry.FILTERS))
def test_a_zero_vector_sample_gives_a_unit_quaternion(name: str, use_mag: bool) -> None:
    f = registry.make_filter(name, use_mag=use_mag)
    f.initialise(G, FIELD if use_mag else None)
    for acc, mag in SAMPLES:
        q = np.asarray(f.update(np.zeros(3), acc, mag if use_mag else None, 0.01))
        assert np.all(np.isfinite(q)), (name, acc, mag, q)
        assert abs(float(np.linalg.norm(q)) - 1.0) < 1e-9, (name, q)
