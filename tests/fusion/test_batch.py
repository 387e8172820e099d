"""Batched default filter: N devices stepped together equal N single-device filters (to 1e-9), with per-device sample
periods and 6D/9D flags, devices joining and leaving, and rounds in which some devices sent nothing."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.fusion import batch as batch_module
from gateway.fusion.batch import DefaultFilterBatch
from gateway.fusion.default import DefaultFilter
from tests.fusion.conftest import synthetic_imu

RATES_HZ = (50.0, 100.0, 285.714, 1000.0)


def _devices(n_dev: int, seconds: float) -> list[dict[str, np.ndarray]]:
    return [
        synthetic_imu(seconds, rate_hz=RATES_HZ[i % len(RATES_HZ)], seed=i, ext_acc_m_s2=1.5,
                      gyr_bias_rad_s=np.array([0.01, -0.005, 0.003]) * (i + 1))
        for i in range(n_dev)
    ]


@pytest.mark.parametrize("parallel", [False, True])
def test_batch_equals_per_device(parallel, monkeypatch):
    monkeypatch.setattr(batch_module, "PARALLEL_MIN_SAMPLES", 0 if parallel else 10**9)
    n_dev, block, n_blocks = 6, 10, 150
    data = _devices(n_dev, seconds=n_blocks * block / 50.0)
    use_mag = [i % 3 != 2 for i in range(n_dev)]
    batch = DefaultFilterBatch()
    singles = []
    for i, d in enumerate(data):
        batch.add(f"dev{i}", dt_s=d["dt_s"], use_mag=use_mag[i], acc_m_s2=d["acc"][0], mag_uT=d["mag"][0])
        f = DefaultFilter(use_mag=use_mag[i])
        f.initialise(d["acc"][0], d["mag"][0])
        singles.append(f)
    for b in range(n_blocks):
        s = np.s_[b * block : (b + 1) * block]
        gyr = np.stack([d["gyr"][s] for d in data])
        acc = np.stack([d["acc"][s] for d in data])
        mag = np.stack([d["mag"][s] for d in data])
        q_batch = batch.step(gyr, acc, mag)
        for i, f in enumerate(singles):
            q_one = f.update_block(gyr[i], acc[i], mag[i] if use_mag[i] else None, data[i]["dt_s"])
            np.testing.assert_allclose(q_batch[i], q_one, atol=1e-9, rtol=0)
    for i, f in enumerate(singles):
        np.testing.assert_allclose(batch.states[i], f.state, atol=1e-9, rtol=0)
    # the devices really differ (different rates and motions): the comparison is not trivially equal
    assert np.ptp(q_batch[:, -1], axis=0).max() > 0.1


def test_add_remove_and_inactive_rows():
    data = _devices(4, seconds=10.0)
    batch = DefaultFilterBatch()
    for i, d in enumerate(data[:3]):
        batch.add(f"dev{i}", dt_s=d["dt_s"], acc_m_s2=d["acc"][0], mag_uT=d["mag"][0])
    ref = {i: DefaultFilter() for i in range(4)}
    for i in range(4):
        ref[i].initialise(data[i]["acc"][0], data[i]["mag"][0])

    def round_(ids: list[int], start: int, active: list[bool] | None = None) -> None:
        s = np.s_[start : start + 10]
        gyr = np.stack([data[i]["gyr"][s] for i in ids])
        acc = np.stack([data[i]["acc"][s] for i in ids])
        mag = np.stack([data[i]["mag"][s] for i in ids])
        act = np.array(active if active is not None else [True] * len(ids))
        out = batch.step(gyr, acc, mag, active=act)
        for row, i in enumerate(ids):
            if act[row]:
                q = ref[i].update_block(gyr[row], acc[row], mag[row], data[i]["dt_s"])
                np.testing.assert_allclose(out[row], q, atol=1e-9, rtol=0)
            else:
                assert np.isnan(out[row]).all()

    round_([0, 1, 2], 0)
    round_([0, 1, 2], 10, active=[True, False, True])  # dev1 sent nothing this round
    batch.remove("dev0")
    assert batch.device_ids == ["dev1", "dev2"] and batch.row("dev2") == 1
    batch.add("dev3", dt_s=data[3]["dt_s"], acc_m_s2=data[3]["acc"][0], mag_uT=data[3]["mag"][0])
    round_([1, 2, 3], 20)
    assert len(batch) == 3
    with pytest.raises(ValueError):
        batch.add("dev1", dt_s=0.01)
    with pytest.raises(ValueError):
        batch.add("devX", dt_s=0.0)


def test_per_device_sample_period_matters():
    """The same samples at two declared rates give different attitudes: dt really is per device."""
    d = synthetic_imu(5.0, rate_hz=100.0, seed=3)
    batch = DefaultFilterBatch()
    batch.add("a", dt_s=0.01, use_mag=False)
    batch.add("b", dt_s=0.02, use_mag=False)
    gyr = np.stack([d["gyr"], d["gyr"]])
    acc = np.stack([d["acc"], d["acc"]])
    out = batch.step(gyr, acc, None)
    assert np.abs(out[0, -1] - out[1, -1]).max() > 1e-3


def test_strided_and_contiguous_rounds_agree_and_bad_shapes_are_refused():
    """Contiguous rounds go straight to the kernel; a strided round switches the batch to converting. Both give the
    same quaternions; mismatched shapes raise ValueError (the kernel does not bounds-check its indexing)."""
    data = _devices(3, seconds=4.0)
    n = min(len(d["gyr"]) for d in data) // 10 * 10
    stacked = {k: np.stack([d[k][:n] for d in data]) for k in ("gyr", "acc", "mag")}
    batches = [DefaultFilterBatch(), DefaultFilterBatch()]
    for b in batches:
        for i, d in enumerate(data):
            b.add(f"dev{i}", dt_s=d["dt_s"], acc_m_s2=d["acc"][0], mag_uT=d["mag"][0])
    out: list[list[np.ndarray]] = [[], []]
    for r in range(0, n, 10):
        s = np.s_[:, r : r + 10]
        out[0].append(batches[0].step(*(np.ascontiguousarray(stacked[k][s]) for k in ("gyr", "acc", "mag"))))
        out[1].append(batches[1].step(*(stacked[k][s] for k in ("gyr", "acc", "mag"))))  # strided views
    assert batches[0]._fast and not batches[1]._fast
    np.testing.assert_array_equal(np.concatenate(out[0], axis=1), np.concatenate(out[1], axis=1))
    g = np.ascontiguousarray(stacked["gyr"][:, :10])
    for gyr, acc in ((g, g[:, :9].copy()), (g[:2].copy(), g[:2].copy()), (g[:, :, :2].copy(), g[:, :, :2].copy())):
        with pytest.raises(ValueError):
            batches[0].step(gyr, acc)
    with pytest.raises(ValueError):
        batches[0].step(g, g, active=np.ones(2, dtype=bool))


def test_stepping_some_rows_alone_equals_a_masked_step_and_leaves_the_others():
    """`step_rows` (the bank's path for a block length few devices have) gives the masked full step's quaternions
    and states bit for bit, and neither steps nor changes the rows it was not given."""
    data = _devices(5, seconds=6.0)
    twins = [DefaultFilterBatch(), DefaultFilterBatch()]
    for b in twins:
        for i, d in enumerate(data):
            b.add(f"dev{i}", dt_s=d["dt_s"], use_mag=i != 3, acc_m_s2=d["acc"][0], mag_uT=d["mag"][0])
    full, alone = twins
    rows = np.array([3, 1], dtype=np.int64)  # out of order, one of them 6D
    for start in range(0, 200, 20):
        s = np.s_[start : start + 20]
        gyr = np.stack([d["gyr"][s] for d in data])
        acc = np.stack([d["acc"][s] for d in data])
        mag = np.stack([d["mag"][s] for d in data])
        active = np.zeros(5, dtype=np.bool_)
        active[rows] = True
        before = alone.states.copy()
        q_full = full.step(gyr, acc, mag, active)
        q_alone = alone.step_rows(rows, np.ascontiguousarray(gyr[rows]), np.ascontiguousarray(acc[rows]),
                                  np.ascontiguousarray(mag[rows]))
        np.testing.assert_array_equal(q_alone, q_full[rows])
        np.testing.assert_array_equal(alone.states, full.states)
        others = [0, 2, 4]
        np.testing.assert_array_equal(alone.states[others], before[others])
    assert np.isfinite(q_alone).all() and np.abs(q_alone[:, -1] - q_alone[:, 0]).max() > 1e-3  # they turned
