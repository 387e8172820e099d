"""Disk full (issue 13, item 5): alarms are published whatever the store does, failed writes are retried from the
writer's bounded journal, /api/health says `degraded` with the reason, and afterwards the store agrees with the
engine (no alarm left active whose clear was lost). The disk is filled for real: SQLite's `max_page_count` capped
at the file's size gives SQLITE_FULL ("database or disk is full") on the gateway's own file."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway import schemas
from gateway.alarm.engine import Alarm, AlarmStatus, Severity
from gateway.store import Store, StoreWriter
from tests.gateway.conftest import Running, rod_messages, wait_for

BITE = [{"type": "bite", "t_s": 3.0, "depth_deg": 15.0, "duration_s": 1.5}]


def fill(store: Store) -> None:
    """Cap the database at its current size and fill its free space until even a small row does not fit."""
    with store._lock:
        n = store._conn.execute("PRAGMA page_count").fetchone()[0]
        store._conn.execute(f"PRAGMA max_page_count = {n}")
    k = 0
    for size in (4000, 1000, 300, 100, 30, 0):
        for _ in range(10_000):
            try:
                store.log_event(0.0, "filler", None, {"x": "y" * size})
            except Exception:
                break
    for size in (4000, 1000, 300, 100, 30, 0):  # each table has its own pages: fill device settings' too
        for _ in range(10_000):
            k += 1
            try:
                with store._tx():
                    row = (f"filler{k}", "y" * size)
                    store._conn.execute("INSERT INTO device_settings VALUES (?, 'rod', ?, 0)", row)
            except Exception:
                break
    for size in (4000, 1000, 300, 100, 30, 0):  # ... and the alarms'
        for _ in range(10_000):
            k += 1
            try:
                store.upsert_alarm(_alarm(k, AlarmStatus.CLEARED, device_id="filler", details={"x": "y" * size}))
            except Exception:
                break


def free(store: Store) -> None:
    with store._lock:
        store._conn.execute("PRAGMA max_page_count = 1073741823")


def test_alarms_survive_a_full_disk(running: Callable[[], Running]) -> None:
    """Old code wrote the alarm before publishing it: with the disk full the write raised, nothing was published
    (3 bites in 30 s: no alarm event), the clears were lost too and /api/health said ok."""
    app = running()
    svc = app.client.app.state.service  # type: ignore[attr-defined]
    fill(svc.store)
    app.feed(rod_messages(9.0, BITE))
    wait_for(lambda: bool(app.bus.sent_json(schemas.alarm_key("rod", "rod-1"))))
    published = app.bus.sent_json(schemas.alarm_key("rod", "rod-1"))
    assert published[0]["alarm"] == "bite" and published[0]["state"] == "raised"
    wait_for(lambda: app.client.get("/api/health").json()["status"] == "degraded")
    health = app.client.get("/api/health").json()
    assert "database or disk is full" in health["reasons"][0] and health["store"]["pending"] >= 1
    assert app.client.get("/api/devices/rod-1").json()["attitude"]  # ingest went on meanwhile
    # A REST write either fits (stored and applied) or gets a clear 503 and is not applied; never a 500.
    r = app.client.put("/api/devices/rod-1/settings", json={"thresholds": {"sensitivity": 2}}, headers=app.auth)
    assert r.status_code == 503 and "database or disk is full" in r.json()["detail"]
    assert app.client.get("/api/devices/rod-1/settings").json()["settings"]["thresholds"] == {}

    free(svc.store)
    wait_for(lambda: app.client.get("/api/health").json()["status"] == "ok")
    stored = {a["id"]: a for a in app.client.get("/api/alarms?device_id=rod-1").json()["items"]}
    for event in published:  # every published alarm is stored, in its last published state
        assert event["alarm_id"] in stored
    last = {e["alarm_id"]: e["state"] for e in published}
    for alarm_id, state in last.items():
        assert stored[alarm_id]["status"] == ("cleared" if state == "cleared" else "active")
    engine_active = {a.id for a in svc.pipeline.engine.active()}
    assert {i for i, a in stored.items() if a["status"] == "active"} == engine_active


def _alarm(i: int, status: AlarmStatus = AlarmStatus.ACTIVE, device_id: str = "rod-1", **kw: Any) -> Alarm:
    return Alarm(id=f"a{i}", device_id=device_id, type="bite", severity=Severity.MAJOR, status=status,
                 started_at=1.0, updated_at=1.0, value=1.0, threshold=1.0, message="", **kw)  # fmt: skip


def test_writer_keeps_order_coalesces_and_bounds_its_journal(tmp_path: Path) -> None:
    with Store(tmp_path / "gw.db") as store:
        fill(store)
        writer = StoreWriter(store, max_pending=5, retry_s=0.05)
        try:
            writer.upsert_alarm(_alarm(0))
            writer.upsert_alarm(_alarm(0, AlarmStatus.CLEARED))  # replaces the pending raise of the same alarm
            for i in range(1, 8):
                writer.log_event(float(i), "x", "rod-1", {"big": "z" * 2000})
            wait_for(lambda: writer.status()["failures"] >= 2)
            status = writer.status()
            assert not status["ok"] and status["pending"] == 5 and status["dropped"] == 3
            free(store)
            assert writer.flush(10.0)
            assert writer.status()["ok"]
        finally:
            writer.close()
        assert store.get_alarm("a0") is None  # dropped as the oldest entry: counted, never half-written
        assert [e["t"] for e in store.events(limit=10) if e["kind"] == "x"] == [7.0, 6.0, 5.0, 4.0, 3.0]


def test_config_writes_go_through_the_writer_and_are_not_held_by_a_failing_journal(tmp_path: Path) -> None:
    """REST config writes run on the one writer thread (`StoreWriter.call`) ahead of the journal: while alarm rows
    fail and are retried, a config write still runs at once and its error (disk full) reaches the caller; after
    the disk is freed it succeeds, also from another thread, and the journal drains."""
    with Store(tmp_path / "gw.db") as store:
        fill(store)
        writer = StoreWriter(store, retry_s=60.0)  # a long retry: a call waiting behind it would time out below
        try:
            writer.upsert_alarm(_alarm(0))
            wait_for(lambda: writer.status()["failures"] >= 1)
            threads: list[str] = []

            def save(s: Store) -> None:  # a settings-sized write, as PUT /api/devices/{id}/settings makes
                threads.append(threading.current_thread().name)
                s.log_event(9.0, "settings_changed", "rod-1", {"x": "y" * 4000})

            fut = writer.call(save)
            err = fut.exception(timeout=5.0)
            assert err is not None and "full" in str(err), err
            assert threads == ["store-writer"]
            free(store)
            assert writer.call(lambda s: s.events(limit=1)).result(timeout=5.0) is not None
            assert writer.flush(65.0)
        finally:
            writer.close()
        assert store.get_alarm("a0") is not None
