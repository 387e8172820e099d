"""A filter that raises (HookFilter's LinAlgError on non-pendulum motion) or returns NaN takes down neither its
device nor the others: the failure is counted per device and reason, and that device's fusion restarts from a
fresh warm-up window while other devices and ingest carry on."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from gateway import schemas
from gateway.app import compose
from gateway.config import DeviceSettings, Settings
from gateway.fusion import registry
from gateway.fusion.base import FloatArray
from gateway.ingest.bus import MemoryBus
from gateway.pipeline import Output, Pipeline
from gateway.store import Store
from tests.gateway.conftest import Running, rod_messages

WARMUP_PACKETS = 10  # 0.5 s of 5-sample packets at 100 Hz
FAIL_ON_CALL = 3  # the first call fuses the warm-up window, two more packets succeed, the third fails


class _ScriptedFilter:
    """Holds the starting attitude; its FAIL_ON_CALL-th `update_block` since creation fails (`_fail`)."""

    def __init__(self, *, use_mag: bool = True) -> None:
        self.calls = 0

    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None = None) -> None:
        pass

    def update_block(self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None,
                     dt_s: float) -> FloatArray:  # fmt: skip
        self.calls += 1
        q = np.tile([1.0, 0.0, 0.0, 0.0], (gyr_rad_s.shape[0], 1))
        return self._fail(q) if self.calls == FAIL_ON_CALL else q

    def _fail(self, q: FloatArray) -> FloatArray:
        raise NotImplementedError


class RaisingFilter(_ScriptedFilter):
    def _fail(self, q: FloatArray) -> FloatArray:
        raise np.linalg.LinAlgError("Matrix is singular.")


class NanFilter(_ScriptedFilter):
    def _fail(self, q: FloatArray) -> FloatArray:
        q[-1] = np.nan
        return q


@pytest.fixture(autouse=True)
def scripted_filters(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(registry.FILTERS, "raising", f"{__name__}:RaisingFilter")
    monkeypatch.setitem(registry.FILTERS, "nan", f"{__name__}:NanFilter")
    yield


def two_rods(seconds: float) -> list[schemas.Packet]:
    """IMU packets of rod-1 and rod-2 interleaved (the same simulated motion under two ids)."""
    out: list[schemas.Packet] = []
    for key, payload in rod_messages(seconds):
        if key.endswith("/imu"):
            out.append(schemas.decode(key, payload))
            out.append(schemas.decode(key.replace("rod-1", "rod-2"), payload.replace(b'"rod-1"', b'"rod-2"')))
    return out


def run_pairs(p: Pipeline, packets: list[schemas.Packet]) -> list[Output]:
    """One batch per pair of packets (one packet of each rod), as a live stream arrives."""
    return [p.process(packets[i : i + 2], now_wall_s=1e9 + 0.05 * i) for i in range(0, len(packets), 2)]


@pytest.mark.parametrize(("name", "reason"), [("raising", "LinAlgError"), ("nan", "non_finite")])
def test_a_failing_filter_restarts_its_device_only(name: str, reason: str) -> None:
    p = Pipeline(device_settings={"rod-1": ("rod", DeviceSettings(filter_name=name))})
    packets = two_rods(3.0)
    n = len(packets) // 2
    outs = run_pairs(p, packets)
    fails = [(k, f) for k, o in enumerate(outs) for f in o.filter_failures]
    # warm-up (10 packets) + 3 calls -> fails on packet 11, then again every 12 packets
    first = WARMUP_PACKETS - 1 + FAIL_ON_CALL - 1
    period = WARMUP_PACKETS + FAIL_ON_CALL - 1
    assert [k for k, _ in fails] == list(range(first, n, period))
    assert {(f.kind, f.device_id, f.reason) for _, f in fails} == {("rod", "rod-1", reason)}
    seqs = {d: [a.seq for o in outs for a in o.attitudes if a.device_id == d] for d in ("rod-1", "rod-2")}
    assert seqs["rod-2"] == list(range(n)), "the other device carries on, every packet"
    # rod-1: only the failing packets lack an attitude (a new warm-up window is fused once it is full)
    lost = {k for k, _ in fails}
    assert seqs["rod-1"] == [s for s in range(n) if s not in lost]
    assert all(np.isfinite(a.quat_wxyz).all() for o in outs for a in o.attitudes)


def test_failures_are_counted_per_device_and_reason_on_diag_ingest(tmp_path: Path) -> None:
    bus = MemoryBus()
    with Store(tmp_path / "gw.sqlite3") as store:
        service = compose(Settings(data_dir=tmp_path, zenoh_listen=[]), bus, store, blocking_thread=False)
        service.pipeline.set_device_settings("rod-1", "rod", DeviceSettings(filter_name="raising"))
        raw = [(k, p) for k, p in rod_messages(2.0) if k.endswith("/imu")]
        for key, payload in raw:
            service.handle([(key, payload, time.monotonic())], now_wall_s=1e9)
        snap = service.counters.snapshot(0)
    expected = len(range(WARMUP_PACKETS + FAIL_ON_CALL - 2, len(raw), WARMUP_PACKETS + FAIL_ON_CALL - 1))
    assert expected >= 2
    assert snap.filter_restarts == {"LinAlgError": expected}
    assert [(d.device_id, d.ok, d.filter_restarts) for d in snap.devices] == [
        ("rod-1", len(raw), {"LinAlgError": expected})]  # fmt: skip
    assert schemas.IngestStats.model_validate_json(snap.to_json()) == snap  # what gw/diag/ingest carries


def test_failures_show_in_api_stats(running: Callable[[], Running]) -> None:
    gw = running()
    r = gw.client.put("/api/devices/rod-1/settings", json={"kind": "rod", "filter_name": "raising"}, headers=gw.auth)
    assert r.status_code == 200, r.text
    for m in rod_messages(1.0):  # one packet per batch, as a live stream arrives (20 IMU packets: one failure)
        gw.feed([m])
    assert gw.client.get("/api/stats").json()["filter_restarts"] == {"LinAlgError": 1}
