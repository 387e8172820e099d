"""Fixtures for the gateway service: settings in a temp dir, an app on a MemoryBus, simulated rod packets."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from devices.common import FleetSettings
from devices.sim_rod import RodFleet
from gateway.app import create_app
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus


def wait_for(cond: Callable[[], bool], timeout_s: float = 20.0, show: Callable[[], object] = lambda: "") -> None:
    """Poll `cond` until true; on timeout fail with `show()` (what was seen instead)."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"condition not met in {timeout_s} s: {show()}"
        time.sleep(0.05)


def serve_packets(data_dir: Path, packets: Sequence[Any]) -> tuple[MemoryBus, dict[str, int]]:
    """Each IMU packet as its own batch through the service `gateway.app.compose` builds (a memory bus, the store in
    `data_dir`, no threads), at a gateway clock that follows the packets' device time: what was put on the bus, and
    the `rejected` counters."""
    from gateway import schemas
    from gateway.app import compose
    from gateway.store import Store

    bus = MemoryBus()
    data_dir.mkdir(parents=True, exist_ok=True)
    store = Store(data_dir / "gw.db")
    svc = compose(Settings(data_dir=data_dir, zenoh_listen=[]), bus, store, blocking_thread=False)
    try:
        for p in packets:
            svc.handle([(schemas.imu_key(p.kind, p.device_id), p.to_json(), time.monotonic())],
                       now_wall_s=1e9 + p.t0_us * 1e-6)  # fmt: skip
        return bus, dict(svc.counters.rejected)
    finally:
        svc.writer.close()
        store.close()


def rod_messages(seconds: float, script: Sequence[dict[str, Any]] = (), seed: int = 1) -> list[tuple[str, bytes]]:
    """(key, payload) of a simulated rod's data packets (imu + reel), 5 samples per packet at 100 Hz."""
    fleet = RodFleet(FleetSettings(count=1, seed=seed, samples_per_packet=5, progress=False, id_prefix="rod"),
                     script=list(script))
    out = []
    for k in range(int(round(seconds / 0.05))):
        data, _ = fleet.tick(k)
        out += [(m.key, m.payload) for m in data[0]]
    return out


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data", zenoh_listen=[])


class Running:
    """A running app on a MemoryBus, with its token and a helper to wait for the ingest task."""

    def __init__(self, client: TestClient, bus: MemoryBus, token: str) -> None:
        self.client, self.bus, self.token = client, bus, token

    @property
    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"}

    def feed(self, messages: list[tuple[str, bytes]], timeout_s: float = 30.0, paced: bool = False) -> None:
        """Put messages on the bus and wait until the gateway has counted them all. At once, they are one burst: a
        few batches, whose attitudes are coalesced to one per device per batch. `paced`: one message at a time, each
        processed before the next is put, as a gateway that keeps up sees them (one attitude per packet)."""
        if paced:
            service = self.client.app.state.service  # type: ignore[attr-defined]
            deadline = time.monotonic() + timeout_s
            for key, payload in messages:
                n = service.counters.received
                self.bus.put(key, payload, encoding="application/json")
                while service.counters.received <= n:
                    assert time.monotonic() < deadline, "gateway did not ingest the messages in time"
                    time.sleep(0.0005)
            self.flush()
            return
        before = self.client.get("/api/stats").json()["received"]
        for key, payload in messages:
            self.bus.put(key, payload, encoding="application/json")
        deadline = time.monotonic() + timeout_s
        while self.client.get("/api/stats").json()["received"] < before + len(messages):
            assert time.monotonic() < deadline, "gateway did not ingest the messages in time"
            time.sleep(0.05)
        self.flush()

    def flush(self, timeout_s: float = 5.0) -> None:
        """Wait until the BLOCK puts queued so far (alarms, swing, reel commands) are on the bus."""
        publisher = self.client.app.state.service.hub.publisher  # type: ignore[attr-defined]
        assert publisher is None or publisher.flush(timeout_s), "blocking puts still queued"


@pytest.fixture
def running(settings: Settings) -> Iterator[Callable[[], Running]]:
    """Factory: start (or restart) the app on the same data dir; each call gives a fresh bus and process state."""
    clients: list[TestClient] = []

    def start() -> Running:
        for c in clients:
            c.__exit__(None, None, None)
        clients.clear()
        bus = MemoryBus()
        client = TestClient(create_app(settings, lambda _: bus, warm_up=False))
        client.__enter__()
        clients.append(client)
        token = (settings.data_dir / "api_token").read_text().strip()
        return Running(client, bus, token)

    yield start
    for c in clients:
        c.__exit__(None, None, None)
