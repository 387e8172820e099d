"""One owner of the live state: REST handlers that change the pipeline or the alarm engine run on the event loop,
the thread that runs ingest (issue 12). Plain `def` routes ran in FastAPI's worker threads, beside ingest."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any

from fastapi.testclient import TestClient

from gateway.app import create_app
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.ingest.publisher import BlockingPublisher
from tests.gateway.conftest import Running, rod_messages


def _record_threads(obj: Any, names: list[str], seen: dict[str, set[int]]) -> None:
    for name in names:
        orig = getattr(obj, name)

        def wrapped(*args: Any, _orig: Any = orig, _name: str = name, **kwargs: Any) -> Any:
            seen.setdefault(_name, set()).add(threading.get_ident())
            return _orig(*args, **kwargs)

        setattr(obj, name, wrapped)


def test_state_changes_from_rest_run_on_the_ingest_thread(running: Callable[[], Running]) -> None:
    r = running()
    service = r.client.app.state.service  # type: ignore[attr-defined]
    seen: dict[str, set[int]] = {}
    _record_threads(service.pipeline, ["process", "set_device_settings", "set_defaults", "set_auto_reel"], seen)
    _record_threads(service.pipeline.engine, ["acknowledge"], seen)
    r.feed(rod_messages(8.0, script=[{"type": "bite", "t_s": 5.0, "depth_deg": 25, "duration_s": 2.0}]))
    assert "process" in seen, "ingest processed the packets"
    (ingest_thread,) = seen["process"]

    body = {"kind": "rod", "thresholds": {"bite_deviation_deg": 12.0}}
    assert r.client.put("/api/devices/rod-1/settings", json=body, headers=r.auth).status_code == 200
    assert r.client.put("/api/thresholds/hook", json={}, headers=r.auth).status_code == 200
    assert r.client.post("/api/rods/rod-1/reel", json={"action": "auto"}, headers=r.auth).status_code == 200
    alarms = r.client.get("/api/alarms").json()["items"]
    assert alarms, "the scripted bite raised an alarm to acknowledge"
    assert r.client.post(f"/api/alarms/{alarms[0]['id']}/ack", headers=r.auth).status_code == 200
    r.feed(rod_messages(0.2))  # ingest again after the writes: still the same thread

    for name in ("set_device_settings", "set_defaults", "set_auto_reel", "acknowledge", "process"):
        assert seen.get(name) == {ingest_thread}, (name, seen.get(name), ingest_thread)


def test_concurrent_settings_puts_leave_store_and_live_state_equal(running: Callable[[], Running]) -> None:
    """Many PUTs at once (worker threads of the client): whatever order they land in, the stored settings and the
    ones in force are the same afterwards, and survive a restart."""
    r = running()
    r.feed(rod_messages(0.5))
    results: list[int] = []

    def put(deg: float) -> None:
        body = {"kind": "rod", "thresholds": {"bite_deviation_deg": deg}}
        results.append(r.client.put("/api/devices/rod-1/settings", json=body, headers=r.auth).status_code)

    threads = [threading.Thread(target=put, args=(10.0 + 0.5 * i,)) for i in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == [200] * 12
    live = r.client.get("/api/devices/rod-1/settings").json()["effective"]["thresholds"]["bite_deviation_deg"]
    r2 = running()  # restart on the same data dir: the stored value comes back
    r2.feed(rod_messages(0.2))
    stored = r2.client.get("/api/devices/rod-1/settings").json()["effective"]["thresholds"]["bite_deviation_deg"]
    assert stored == live


def _record_tasks(obj: Any, names: list[str], seen: dict[str, set[int]], in_batch: list[bool],
                  mid_batch: list[str]) -> None:  # fmt: skip
    """Wrap methods to record the asyncio task they run in (id; 0 outside any task) and whether a batch
    (`process`) was running at that moment."""
    for name in names:
        orig = getattr(obj, name)

        def wrapped(*args: Any, _orig: Any = orig, _name: str = name, **kwargs: Any) -> Any:
            try:
                task = asyncio.current_task()
            except RuntimeError:  # no running loop: a thread
                task = None
            seen.setdefault(_name, set()).add(id(task) if task is not None else 0)
            if in_batch[0] and _name != "evaluate":  # the engine evaluates inside a batch, by design
                mid_batch.append(_name)
            if _name == "process":
                in_batch[0] = True
                try:
                    return _orig(*args, **kwargs)
                finally:
                    in_batch[0] = False
            return _orig(*args, **kwargs)

        setattr(obj, name, wrapped)


def test_every_state_change_runs_in_the_ingest_task_never_mid_batch(running: Callable[[], Running]) -> None:
    """Issue 12 item 1: the ingest task is the one owner. Old code: REST handlers changed the pipeline and the
    alarm engine from their own request tasks (and liveliness changes from a loop callback, no task at all), so the
    ingest task was one writer among several. Now each change is a command the ingest task runs between batches,
    also while a burst of packets is being processed and settings PUTs arrive from many clients at once."""
    r = running()
    service = r.client.app.state.service  # type: ignore[attr-defined]
    seen: dict[str, set[int]] = {}
    in_batch, mid_batch = [False], []
    pipeline_names = ["process", "set_device_settings", "set_defaults", "set_auto_reel", "tick_reel", "reel_offline"]
    _record_tasks(service.pipeline, pipeline_names, seen, in_batch, mid_batch)
    _record_tasks(service.pipeline.engine, ["acknowledge", "clear", "evaluate"], seen, in_batch, mid_batch)
    r.feed(rod_messages(8.0, script=[{"type": "bite", "t_s": 5.0, "depth_deg": 25, "duration_s": 2.0}]))
    (ingest_task,) = seen["process"]

    burst = rod_messages(4.0, seed=2)
    statuses: list[int] = []

    def put(deg: float) -> None:
        body = {"kind": "rod", "thresholds": {"bite_deviation_deg": deg}}
        statuses.append(r.client.put("/api/devices/rod-1/settings", json=body, headers=r.auth).status_code)

    writers = [threading.Thread(target=put, args=(10.0 + 0.5 * i,)) for i in range(8)]
    for t in writers:
        t.start()
    for key, payload in burst:  # a burst while the PUTs land
        r.bus.put(key, payload, encoding="application/json")
    for t in writers:
        t.join()
    assert statuses == [200] * 8
    assert r.client.put("/api/thresholds/hook", json={}, headers=r.auth).status_code == 200
    assert r.client.post("/api/rods/rod-1/reel", json={"action": "auto"}, headers=r.auth).status_code == 200
    alarms = r.client.get("/api/alarms").json()["items"]
    assert alarms, "the scripted bite raised an alarm to acknowledge"
    assert r.client.post(f"/api/alarms/{alarms[0]['id']}/ack", headers=r.auth).status_code == 200
    assert r.client.post(f"/api/alarms/{alarms[0]['id']}/clear", headers=r.auth).status_code == 200
    r.bus.set_alive("rig/rod/rod-1", True)  # presence: a liveliness callback on a bus thread
    r.bus.set_alive("rig/rod/rod-1", False)
    r.feed(rod_messages(0.2, seed=3))
    deadline = time.monotonic() + 10.0
    while "reel_offline" not in seen or "tick_reel" not in seen:  # the offline command and a reel watchdog tick
        assert time.monotonic() < deadline, sorted(seen)
        time.sleep(0.02)

    for name in ("set_device_settings", "set_defaults", "set_auto_reel", "acknowledge", "clear", "evaluate",
                 "reel_offline", "tick_reel", "process"):  # fmt: skip
        assert seen.get(name) == {ingest_task}, (name, seen.get(name), ingest_task)
    assert mid_batch == [], f"changed inside a batch: {mid_batch}"


class StallingBus(MemoryBus):
    """A MemoryBus whose BLOCK puts wait until `release` is set (at most `stall_s`): a subscriber that stopped
    reading. `returned` counts the blocked puts that have returned."""

    def __init__(self, stall_s: float = 20.0) -> None:
        super().__init__()
        self.release = threading.Event()
        self.stall_s = stall_s
        self.blocked = 0
        self.returned = 0

    def put(self, key: str, payload: bytes, *, encoding: str, block: bool = False, express: bool = False) -> None:
        if block:
            self.blocked += 1
            self.release.wait(self.stall_s)
            self.returned += 1
        super().put(key, payload, encoding=encoding, block=block)


def test_a_stalled_alarm_subscriber_never_stalls_ingest_or_rest(settings: Settings) -> None:
    """Old code: the hub made BLOCK puts (alarms, swing, reel commands) on the event loop; a subscriber that stopped
    reading stalled ingest and REST with it. Now they wait on the publisher thread: packets keep flowing, REST
    answers, and the alarm goes out once the subscriber reads again."""
    bus = StallingBus()
    with TestClient(create_app(settings, lambda _: bus, warm_up=False)) as client:
        def received() -> int:
            return int(client.get("/api/stats").json()["received"])

        script = [{"type": "bite", "t_s": 3.0, "depth_deg": 25, "duration_s": 2.0}]
        msgs = rod_messages(6.0, script=script)
        for key, payload in msgs:
            bus.put(key, payload, encoding="application/json")
        deadline = time.monotonic() + 30.0
        while received() < len(msgs):
            assert time.monotonic() < deadline, "ingest stalled behind a blocking put"
            time.sleep(0.05)
        while bus.blocked < 1:  # the publisher thread reaches the alarm's put after the batch is processed
            assert time.monotonic() < deadline, "the bite alarm's put never reached the stalled subscriber"
            time.sleep(0.05)
        stats = client.get("/api/stats").json()
        assert stats["blocking_puts"]["queued"] >= 0 and client.get("/api/health").status_code == 200
        more = rod_messages(1.0, seed=5)
        for key, payload in more:  # still ingesting while the put waits
            bus.put(key, payload, encoding="application/json")
        while received() < len(msgs) + len(more):
            assert time.monotonic() < deadline, "ingest stalled behind a blocking put"
            time.sleep(0.05)
        # all of that happened while the alarm's put was still waiting (old code: only after it gave up, 20 s)
        assert bus.returned == 0, "ingest waited for the stalled subscriber"
        bus.release.set()
        service = client.app.state.service  # type: ignore[attr-defined]
        assert service.hub.publisher.flush(10.0)
        assert [a["alarm"] for a in bus.sent_json("gw/rod/rod-1/alarm")] == ["bite"]


def test_blocking_publisher_drops_the_oldest_when_full_and_counts_it() -> None:
    bus = StallingBus()
    pub = BlockingPublisher(bus, maxsize=3)
    try:
        pub.put("k/0", b"x", "application/json")
        deadline = time.monotonic() + 5.0
        while bus.blocked < 1:  # the thread holds k/0, waiting for the subscriber
            assert time.monotonic() < deadline
            time.sleep(0.005)
        for i in range(1, 10):
            pub.put(f"k/{i}", b"x", "application/json")
        assert pub.dropped == 10 - 1 - 3 and len(pub) == 3
        bus.release.set()
        assert pub.flush(5.0)
        assert [k for k, _, _ in bus.sent] == ["k/0", "k/7", "k/8", "k/9"]  # in order, the newest kept
    finally:
        bus.release.set()
        pub.close()
