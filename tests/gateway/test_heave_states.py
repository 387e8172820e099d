"""The batched heave step with every device's state as a row of `kinds.base.HeaveStates` gives, bit for bit, the
rows and states each device's own `HeaveEstimator.update` gives (random batches: devices coming, going and
restarting, more of them than the store's first allocation); `FusionBank.biases` is `bias` of each device."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import schemas
from gateway.fusion import _default_kernels as K
from gateway.kinds import base
from gateway.kinds.base import Fused, FusedDevice, HeaveStates, KindBatch
from gateway.pipeline import Pipeline
from tests.gateway.conftest import rod_messages

TOL = 0.5  # rest_acc_tol_m_s2, as PipelineSettings


def block(rng: np.random.Generator, dev: FusedDevice, packets: int, depth: bool) -> Fused:
    """A device's block of `packets` 5-sample packets: unit quaternions near level, gyro and specific force
    near rest or moving; `depth`: some packets carry a depth reading."""
    n = 5 * packets
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) + rng.normal(0.0, 0.05, (n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    moving = rng.random() < 0.5
    gyr = rng.normal(0.0, 0.3 if moving else 0.002, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 1.0 if moving else 0.01, (n, 3))
    pkts = [SimpleNamespace(n=5, depth_m=float(rng.uniform(0, 10)) if depth and rng.random() < 0.5 else None)
            for _ in range(packets)]  # fmt: skip
    ends = [(5 * k + 4, k, 0) for k in range(packets)]
    return Fused(dev, q, gyr, acc, np.arange(n) * dev.dt_s, ends, pkts)  # type: ignore[arg-type]


def alone(f: Fused, bias: np.ndarray) -> np.ndarray:
    """The rows of the per-device path (`heights` before the batch: the device's own estimator)."""
    heave, depth = base._heave_of(f, TOL), None
    if any(p.depth_m is not None for p in f.packets):
        depth = np.full(f.t_s.shape[0], np.nan)
        base._depth_into(f, depth, 0)
    rows: np.ndarray = heave.update(f.q, f.gyr - bias, f.acc, f.dev.dt_s, depth)
    return rows


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 6))
def test_heave_rows_equal_each_device_alone(seed: int, n_devices: int, n_batches: int) -> None:
    rng = np.random.default_rng(seed)
    store = HeaveStates()
    ids = [f"rod-{k}" for k in range(n_devices)]
    mine: dict[str, FusedDevice] = {}
    ref: dict[str, FusedDevice] = {}
    for _ in range(n_batches):
        for d in ids:  # a device restarts now and then: a fresh record (and estimator), the same id
            if d not in mine or rng.random() < 0.1:
                dt = float(rng.choice([0.01, 0.005]))
                mine[d], ref[d] = (FusedDevice("rod", d, "default", dt, False, None) for _ in range(2))
        present = [d for d in ids if rng.random() < 0.8] or ids[:1]
        depth = rng.random() < 0.3
        items, refs = [], []
        for d in present:
            k = int(rng.integers(1, 4))
            state = rng.bit_generator.state
            items.append(block(rng, mine[d], k, depth))
            rng.bit_generator.state = state  # the same samples for the reference
            refs.append(block(rng, ref[d], k, depth))
        kb = KindBatch(items)
        live = sorted(rng.choice(len(items), size=max(1, len(items) - 1), replace=False).tolist())
        bias = rng.normal(0.0, 0.01, (len(live), 3)) * (rng.random((len(live), 1)) < 0.7)
        rows = base.heave_rows(kb, live, bias, TOL, store)
        for k, i in enumerate(live):
            want = alone(refs[i], bias[k])
            np.testing.assert_array_equal(rows[kb.rows(i)], want)
            np.testing.assert_array_equal(items[i].dev.heave.state, refs[i].dev.heave.state)
            np.testing.assert_array_equal(store.states[items[i].dev.heave_row], refs[i].dev.heave.state)
    assert len(store.slots) <= n_devices  # a row per device id, restarts included


def test_an_estimator_made_alone_joins_the_batch_with_its_state() -> None:
    """A device whose first block went through the per-device path (`heights`) keeps its state in the batch."""
    rng = np.random.default_rng(3)
    dev, twin = FusedDevice("rod", "rod-1", "default", 0.01, False, None), FusedDevice("rod", "rod-1", "d", 0.01,
                                                                                       False, None)  # fmt: skip
    first = block(rng, dev, 2, False)
    alone(first, np.zeros(3))
    alone(Fused(twin, first.q, first.gyr, first.acc, first.t_s, first.ends, first.packets), np.zeros(3))
    second = block(rng, dev, 2, False)
    store = HeaveStates()
    rows = base.heave_rows(KindBatch([second]), [0], np.zeros((1, 3)), TOL, store)
    want = alone(Fused(twin, second.q, second.gyr, second.acc, second.t_s, second.ends, second.packets), np.zeros(3))
    np.testing.assert_array_equal(rows, want)
    np.testing.assert_array_equal(store.states[dev.heave_row], twin.heave.state)


def test_biases_are_each_devices_bias() -> None:
    """Rods on the default filter (rows of its batch, stepped in another order than read), a filter with a bias
    estimate and one without, read together."""
    p = Pipeline()
    imu = [schemas.decode(k, v) for k, v in rod_messages(1.0) if k.endswith("/imu")]
    for d in (3, 1, 2):
        p.process([m.model_copy(update={"device_id": f"rod-{d}"}) for m in imu], now_wall_s=1e9)
    devs = [p.devices[f"rod-{d}"] for d in (1, 2, 3)]
    assert p.bank.batch is not None
    for d in (1, 2, 3):  # each its own estimate (the same packets gave them the same one)
        p.bank.batch.states[p.bank.batch.row(f"rod-{d}"), K.S_BIAS : K.S_BIAS + 3] += 0.01 * d
    with_bias = FusedDevice("hook", "h", "hook", 0.01, False,
                            SimpleNamespace(bias_rad_s=[0.1, -0.2, 0.3]))  # type: ignore[arg-type]
    without = FusedDevice("rod", "x", "other", 0.01, False, SimpleNamespace())  # type: ignore[arg-type]
    got = p.bank.biases([*devs, with_bias, without])
    want = np.array([*(p.bank.bias(d) for d in devs), [0.1, -0.2, 0.3], np.zeros(3)])
    np.testing.assert_array_equal(got, want)
    assert np.abs(got[:3]).sum() > 0 and len({tuple(r) for r in got[:3]}) == 3
