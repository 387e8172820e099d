"""Ingest over real zenoh on loopback (multicast off, explicit endpoints, free ports): malformed packets are
counted by reason and published on gw/diag/rejected while ingest goes on; presence follows liveliness tokens;
the bounded hand-off counts drops."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Coroutine, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from fastapi.testclient import TestClient

from bench.bite_latency import free_port, observer_config
from gateway import schemas
from gateway.app import compose, create_app
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.ingest.runner import Inbox
from gateway.store import Store
from tests.gateway.conftest import rod_messages, wait_for

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def live(tmp_path: Path) -> Iterator[tuple[TestClient, zenoh.Session]]:
    """The gateway on a real zenoh peer listening on a free port, and a device-side session connected to it."""
    port = free_port()
    settings = Settings(data_dir=tmp_path / "data", zenoh_listen=[f"tcp/127.0.0.1:{port}"])
    with TestClient(create_app(settings, warm_up=False)) as client, zenoh.open(observer_config(port)) as session:
        # Puts made before the gateway's subscriptions reach this session are dropped here, unseen (a fixed sleep
        # was not always enough under load): wait until a publisher on a device key has a matching subscriber.
        probe = session.declare_publisher(schemas.imu_key("rod", "rod-1"))
        wait_for(lambda: probe.matching_status.matching, timeout_s=30.0)
        probe.undeclare()
        yield client, session


def put(session: zenoh.Session, key: str, payload: bytes) -> None:
    """A device put that a busy transmit queue cannot drop (session.put defaults to CongestionControl.DROP)."""
    session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)


def test_malformed_packets_are_counted_by_reason_and_ingest_goes_on(live: tuple[TestClient, zenoh.Session]) -> None:
    client, session = live
    rejected: list[dict[str, object]] = []
    diag: list[dict[str, object]] = []

    def on_diag(s: zenoh.Sample) -> None:
        (rejected if str(s.key_expr) == schemas.DIAG_REJECTED_KEY else diag).append(json.loads(s.payload.to_bytes()))

    # One subscriber for both diagnostics keys: once the 1 Hz gw/diag/ingest reaches it, the gateway knows the
    # subscription, so no gw/diag/rejected message can be published before the route exists.
    sub = session.declare_subscriber("gw/diag/**", on_diag)
    wait_for(lambda: bool(diag), timeout_s=30.0)
    good = rod_messages(1.0)
    imu = [(k, p) for k, p in good if k.endswith("/imu")]
    garbage = [
        ("rig/rod/rod-1/imu", b"\x00\xffnot json"),  # bad_json
        ("rig/rod/rod-1/imu", b'{"v": 2}'),  # version
        ("rig/rod/rod-1/imu", b"[" * 600_000),  # too_large
        ("rig/ball/ball-1/imu", imu[0][1]),  # unknown_key: balls have no imu topic
        ("rig/rod/rod-2/imu", imu[0][1]),  # key_mismatch: payload says rod-1
        ("rig/rod/rod-1/imu", imu[0][1].replace(b'"rate_hz":100.0', b'"rate_hz":1e9')),  # out_of_range
        ("rig/rod/rod-1/imu", imu[0][1].replace(b'"boot_id":', b'"boot":')),  # schema
    ]
    for key, payload in imu[:5]:
        put(session, key, payload)
    for key, payload in garbage:
        put(session, key, payload)
    for key, payload in imu[5:]:
        put(session, key, payload)
    expect = {"bad_json": 1, "version": 1, "too_large": 1, "unknown_key": 1, "key_mismatch": 1, "out_of_range": 1,
              "schema": 1}  # fmt: skip
    wait_for(lambda: client.get("/api/stats").json()["rejected"] == expect, show=lambda: client.get("/api/stats").text)
    wait_for(lambda: client.get("/api/stats").json()["devices"][0]["ok"] == len(imu),  # the good ones after too
             show=lambda: client.get("/api/stats").text)  # fmt: skip
    stats = client.get("/api/stats").json()
    assert stats["received"] == len(imu) + len(garbage)
    assert stats["batch_delay_ms"]["n"] >= 1 and 0.0 <= stats["batch_delay_ms"]["p50"] <= stats["batch_delay_ms"]["max"]
    dev = client.get("/api/devices/rod-1").json()
    assert dev["stream"]["rejected"] == {"bad_json": 1, "version": 1, "too_large": 1, "out_of_range": 1,
                                         "schema": 1}  # fmt: skip
    wait_for(lambda: len(rejected) == len(garbage), show=lambda: rejected)
    assert sorted(r["reason"] for r in rejected) == sorted(expect)
    wait_for(lambda: bool(diag) and diag[-1]["rejected"] == expect, timeout_s=15.0)  # 1 Hz, DROP
    sub.undeclare()


def test_duplicates_and_losses_are_accounted(live: tuple[TestClient, zenoh.Session]) -> None:
    client, session = live
    imu = [(k, p) for k, p in rod_messages(1.0) if k.endswith("/imu")]
    sent = imu[:3] + imu[2:3] + imu[5:]  # one duplicate, two lost
    for key, payload in sent:
        put(session, key, payload)
    wait_for(lambda: client.get("/api/stats").json()["received"] == len(sent),
             show=lambda: client.get("/api/stats").text)  # fmt: skip
    stream = client.get("/api/devices/rod-1").json()["stream"]
    assert (stream["ok"], stream["duplicates"], stream["lost"]) == (len(imu) - 2, 1, 2)


def test_presence_follows_liveliness_within_a_second(live: tuple[TestClient, zenoh.Session]) -> None:
    client, session = live
    token = session.liveliness().declare_token(schemas.device_token_key("hook", "hook-7"))
    wait_for(lambda: client.get("/api/devices/hook-7").status_code == 200
             and client.get("/api/devices/hook-7").json()["online"], timeout_s=5.0)  # fmt: skip
    t0 = time.monotonic()
    token.undeclare()
    wait_for(lambda: not client.get("/api/devices/hook-7").json()["online"], timeout_s=5.0)
    assert time.monotonic() - t0 < 1.0


def test_inbox_counts_drops_when_full() -> None:
    async def run() -> tuple[int, int]:
        inbox = Inbox(asyncio.get_running_loop(), maxsize=3)
        for i in range(5):
            inbox.offer(f"k{i}", b"x")
        got = await asyncio.wait_for(inbox.drain(10), 1.0)
        return len(got), inbox.drops

    assert asyncio.run(run()) == (3, 2)


def test_inbox_drains_in_batches_in_order() -> None:
    async def run() -> list[list[str]]:
        inbox = Inbox(asyncio.get_running_loop(), maxsize=100)
        for i in range(7):
            inbox.offer(f"k{i}", b"")
        return [[k for k, _, _ in await asyncio.wait_for(inbox.drain(3), 1.0)] for _ in range(3)]

    assert asyncio.run(run()) == [["k0", "k1", "k2"], ["k3", "k4", "k5"], ["k6"]]


def test_a_short_batch_waits_the_coalescing_window_for_more_packets() -> None:
    """Cost is paid per device per batch: a lightly loaded gateway ran one batch per packet (0.76 ms of CPU a
    packet at 100 devices). A batch now waits until its oldest packet is `coalesce_s` old, unless it is full."""

    async def run(coalesce_s: float, max_n: int) -> list[int]:
        loop = asyncio.get_running_loop()
        inbox = Inbox(loop, maxsize=100, coalesce_s=coalesce_s)
        inbox.offer("k0", b"")
        inbox.offer("k1", b"")
        loop.call_later(0.05, inbox.offer, "k2", b"")  # arrives within the window
        sizes = [len(await asyncio.wait_for(inbox.drain(max_n), 2.0))]
        sizes.append(len(await asyncio.wait_for(inbox.drain(max_n), 2.0)))
        return sizes

    assert asyncio.run(run(0.0, 10)) == [2, 1]  # no window: a batch per wake-up
    assert asyncio.run(run(0.3, 10))[0] == 3  # the third joined the first batch ...
    assert asyncio.run(run(0.3, 2)) == [2, 1]  # ... but a full batch does not wait


def test_rejected_packets_are_published_at_most_20_a_second_but_all_counted(tmp_path: Path) -> None:
    """docs/protocol.md: gw/diag/rejected is rate-limited (REJECTED_PER_S per second of the gateway clock)."""
    from gateway.app import compose
    from gateway.ingest.bus import MemoryBus
    from gateway.ingest.runner import REJECTED_PER_S
    from gateway.store import Store

    bus = MemoryBus()
    with Store(tmp_path / "gw.sqlite3") as store:
        service = compose(Settings(data_dir=tmp_path, zenoh_listen=[]), bus, store, blocking_thread=False)
        bad = [("rig/rod/rod-1/imu", b"{not json", time.monotonic())] * 50

        def published() -> list[dict[str, object]]:
            return [json.loads(p) for k, p, _ in bus.sent if k == schemas.DIAG_REJECTED_KEY]

        service.handle(bad[:30], now_wall_s=1000.1)
        service.handle(bad[30:], now_wall_s=1000.9)  # same second: nothing more goes out
        assert REJECTED_PER_S == 20 and len(published()) == REJECTED_PER_S
        assert service.counters.rejected["bad_json"] == 50, "every rejection is still counted"
        service.handle(bad[:5], now_wall_s=1001.0)  # a new second opens a new allowance
        assert len(published()) == REJECTED_PER_S + 5
        assert {p["reason"] for p in published()} == {"bad_json"}
        assert [p["wall_t_us"] for p in published()][-1] == 1_001_000_000
        assert all(block for k, _, block in bus.sent if k == schemas.DIAG_REJECTED_KEY), "BLOCK: a reader loses none"


async def _returns_within(coro: Coroutine[Any, Any, None], timeout_s: float) -> bool:
    try:
        await asyncio.wait_for(coro, timeout_s)
        return True
    except TimeoutError:
        return False


def test_ingest_waits_for_local_rest_requests_but_not_for_ones_awaiting_another_shard(tmp_path: Path) -> None:
    """With two shards the REST front's `/api/stats` waits for the other shard's answer; ingest held its next batch
    for it (the grace) at every probe, and the front's shard fell seconds behind at 1000 devices."""
    bus, store = MemoryBus(), Store(tmp_path / "gw.db")
    svc = compose(Settings(data_dir=tmp_path, zenoh_listen=[]), bus, store, blocking_thread=False)
    svc.rest_grace_s = 30.0
    try:
        svc.rest_inflight = 1  # one HTTP request running here
        assert not asyncio.run(_returns_within(svc._let_rest_finish(), 0.3))  # it is given the loop
        with svc.awaiting_remote():  # ... until it waits for another process
            assert asyncio.run(_returns_within(svc._let_rest_finish(), 0.3))
        assert svc.rest_remote == 0
    finally:
        svc.writer.close()
        store.close()


def test_config_view_holds_the_served_devices_and_is_not_rebuilt_per_batch(tmp_path: Path) -> None:
    """A shard's `gw/config` view holds only the devices it serves. It was rebuilt after every batch whenever another
    shard served some device (its size never matched the pipeline's): 6.6 % of a shard's ingest thread at 1000."""
    bus, store = MemoryBus(), Store(tmp_path / "gw.db")
    svc = compose(Settings(data_dir=tmp_path, zenoh_listen=[]), bus, store, blocking_thread=False)
    try:
        svc.accept = lambda device_id: device_id != "rod-2"  # another shard serves rod-2
        svc.pipeline.kinds.update({"rod-1": "rod", "rod-2": "rod"})
        svc.refresh_config_view()
        view = svc.config_view
        assert sorted(view.devices) == ["gw/config/rod/rod-1"]
        svc.refresh_config_view()  # nothing new: the same view
        assert svc.config_view is view
        svc.pipeline.kinds["hook-1"] = "hook"  # a device appears
        svc.refresh_config_view()
        assert sorted(svc.config_view.devices) == ["gw/config/hook/hook-1", "gw/config/rod/rod-1"]
        svc.accept = lambda device_id: True  # rod-2 moved here: the shard node calls config_changed
        svc.config_changed()
        assert "gw/config/rod/rod-2" in svc.config_view.devices
    finally:
        svc.writer.close()
        store.close()
