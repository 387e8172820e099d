"""One owner of the live state: REST handlers that change the pipeline or the alarm engine run on the event loop,
the thread that runs ingest (issue 12). Plain `def` routes ran in FastAPI's worker threads, beside ingest."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

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
