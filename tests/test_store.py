"""SQLite store: settings round trips, one active alarm per (device, type), filters, restart persistence, token."""

from __future__ import annotations

import itertools
import os
import stat
import threading
from dataclasses import replace

import pytest

from gateway.alarm.engine import AlarmEngine, AlarmStatus, Condition, Severity
from gateway.config import DeviceSettings, HookThresholds, RodThresholds, SpotPreferences
from gateway.store import MIGRATIONS, ApiToken, Store, ensure_token


@pytest.fixture
def store(tmp_path):
    with Store(tmp_path / "db" / "gw.sqlite3") as s:
        yield s


def engine() -> AlarmEngine:
    n = itertools.count()
    return AlarmEngine(id_factory=lambda: f"al{next(n)}")


def persist(store, eng, *conds):
    return [store.upsert_alarm(c.alarm) for c in eng.evaluate(conds)]


def test_fresh_db_is_wal_and_at_latest_schema(store):
    assert store.schema_version == len(MIGRATIONS)
    with store._lock:
        assert store._conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_defaults_and_device_settings_round_trip(store):
    rod = RodThresholds(bite_deviation_deg=8.0, sensitivity=4)
    store.save_defaults("rod", rod, t=1.0)
    store.save_defaults("hook", HookThresholds(swing_warn_deg=3.0), t=1.0)
    store.save_defaults("rod", replace_rod := rod.model_copy(update={"rearm_quiet_s": 9.0}), t=2.0)
    loaded = store.load_defaults()
    assert loaded["rod"] == replace_rod and loaded["hook"].swing_warn_deg == 3.0 and "ball" not in loaded
    ds = DeviceSettings(filter_name="ekf", thresholds={"sensitivity": 5})
    store.save_device_settings("rod-7", "rod", ds)
    store.save_device_settings("ball-1", "ball", DeviceSettings(thresholds={"species": ["pike"]}, auto_reel=False))
    assert store.load_device_settings() == {
        "rod-7": ("rod", ds),
        "ball-1": ("ball", DeviceSettings(thresholds={"species": ["pike"]})),
    }
    assert store.delete_device_settings("rod-7") and not store.delete_device_settings("rod-7")
    assert SpotPreferences(species=("pike",)).species == ("pike",)


def test_upsert_keeps_one_row_per_active_device_type(store):
    eng = engine()
    persist(store, eng, Condition("d1", "hook_swing", Severity.WARNING, 1.0, 6.0, 5.0, "swing"))
    persist(store, eng, Condition("d1", "hook_swing", Severity.CRITICAL, 2.0, 11.0, 10.0, "swing"))
    rows, total = store.list_alarms()
    assert total == 1 and rows[0].severity is Severity.CRITICAL and rows[0].count == 2 and rows[0].peak == 11.0
    # A second engine that did not resume would raise a new id: the store folds it into the existing row.
    other = engine().evaluate([Condition("d1", "hook_swing", Severity.WARNING, 3.0, 7.0, 5.0, "swing")])[0].alarm
    stored = store.upsert_alarm(replace(other, id="zzz"))
    assert stored.id == rows[0].id and stored.started_at == 1.0
    assert store.list_alarms()[1] == 1
    persist(store, eng, Condition("d1", "hook_swing", None, 4.0))
    persist(store, eng, Condition("d1", "hook_swing", Severity.WARNING, 5.0, 6.0, 5.0, "swing"))
    rows, total = store.list_alarms(device_id="d1")
    assert total == 2 and [r.status for r in rows] == [AlarmStatus.ACTIVE, AlarmStatus.CLEARED]


def test_list_filters_and_paging(store):
    eng = engine()
    for i in range(12):
        persist(store, eng, Condition(f"d{i % 3}", "bite", Severity.MAJOR, float(i), -12.0, -10.0, "bite"))
        persist(store, eng, Condition(f"d{i % 3}", "bite", None, i + 0.5))
    persist(store, eng, Condition("d0", "hook_swing", Severity.WARNING, 20.0, 6.0, 5.0, "swing"))
    assert store.list_alarms(device_id="d0")[1] == 5
    assert store.list_alarms(type="bite", status="cleared")[1] == 12
    assert store.list_alarms(status=AlarmStatus.ACTIVE)[1] == 1
    assert store.list_alarms(severity=Severity.MAJOR, since=6.0)[1] == 6
    page, total = store.list_alarms(type="bite", limit=5, offset=10)
    assert total == 12 and [a.started_at for a in page] == [1.0, 0.0]
    assert store.list_alarms(acknowledged=False)[1] == 13


def test_acknowledge_and_counts(store):
    eng = engine()
    [a] = persist(store, eng, Condition("d1", "bite", Severity.MAJOR, 1.0, -12.0, -10.0, "bite"))
    persist(store, eng, Condition("d2", "line_tension", Severity.CRITICAL, 1.0, 33.0, 31.5, "line"))
    acked = store.acknowledge(a.id, "alice", 2.0)
    assert acked is not None and acked.acknowledged and acked.acknowledged_by == "alice"
    assert acked.status is AlarmStatus.ACTIVE  # acknowledging does not clear
    assert store.acknowledge(a.id, "bob", 3.0).acknowledged_by == "alice"  # first ack wins
    assert store.acknowledge("nope", "bob", 3.0) is None
    c = store.counts()
    assert (c["active"], c["unacknowledged"], c["major"], c["critical"], c["minor"]) == (2, 1, 1, 1, 0)
    assert store.counts("d1")["active"] == 1


def test_restart_keeps_everything(tmp_path):
    path = tmp_path / "gw.sqlite3"
    eng = engine()
    with Store(path) as s1:
        s1.save_defaults("rod", RodThresholds(sensitivity=2))
        s1.save_device_settings("rod-1", "rod", DeviceSettings(filter_name="mahony"))
        [a] = persist(s1, eng, Condition("rod-1", "bite", Severity.MAJOR, 1.0, -12.0, -10.0, "bite", {"cue": "accel"}))
        s1.acknowledge(a.id, "ops", 2.0)
        s1.log_event(3.0, "online", "rod-1", {"addr": "tcp/1.2.3.4"})
    with Store(path) as s2:
        assert s2.schema_version == len(MIGRATIONS)
        assert s2.load_defaults()["rod"].sensitivity == 2
        assert s2.load_device_settings()["rod-1"][1].filter_name == "mahony"
        [b], _ = s2.list_alarms()
        assert (b.id, b.acknowledged, b.details["cue"]) == (a.id, True, "accel")
        assert s2.events()[0]["payload"] == {"addr": "tcp/1.2.3.4"}
        # the engine resumes from the stored active rows: an update hits the same alarm
        assert [x.id for x in s2.active_alarms()] == [a.id]
        resumed = AlarmEngine(active=s2.active_alarms())
        [ch] = resumed.evaluate([Condition("rod-1", "bite", Severity.MAJOR, 5.0, -14.0, -10.0, "bite")])
        assert ch.kind == "updated" and s2.upsert_alarm(ch.alarm).id == a.id


def test_concurrent_writers_from_threads(store):
    def work(k):
        eng = engine()
        for i in range(50):
            for c in eng.evaluate([Condition(f"t{k}", "bite", Severity.MAJOR if i % 2 == 0 else None, float(i))]):
                store.upsert_alarm(replace(c.alarm, id=f"{k}-{c.alarm.id}"))

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert store.list_alarms()[1] == 4 * 25 and store.counts()["active"] == 0


def test_token_created_once_with_owner_only_permissions(tmp_path):
    token, created = ensure_token(tmp_path / "data")
    assert created and len(token) >= 40
    path = tmp_path / "data" / "api_token"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    again, created2 = ensure_token(tmp_path / "data")
    assert (again, created2) == (token, False)
    os.chmod(path, 0o644)
    ensure_token(tmp_path / "data")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600  # tightened
    auth = ApiToken(token)
    assert auth.verify_token(token)
    assert not auth.verify_token(token[:-1] + ("A" if token[-1] != "A" else "B"))
    assert not auth.verify_token("") and not auth.verify_token(None)
    assert token not in repr(auth)


def test_migration_renames_the_env_kind_to_ball_and_keeps_the_rows(tmp_path):
    """A database written before migration 2 (ball kind stored as `env`) opens with `ball` keys, values intact."""
    import sqlite3

    path = tmp_path / "old.sqlite3"
    conn = sqlite3.connect(path, isolation_level=None)
    v1 = "CREATE TABLE schema_version (version INTEGER NOT NULL);" + MIGRATIONS[0]
    conn.executescript(v1 + "INSERT INTO schema_version VALUES (1);")
    prefs = SpotPreferences(species=("pike", "perch"))
    conn.execute("INSERT INTO defaults VALUES ('env', ?, 1.0)", (prefs.model_dump_json(),))
    conn.execute("INSERT INTO device_settings VALUES ('ball-1', 'env', ?, 1.0)",
                 (DeviceSettings(thresholds={"species": ["trout"]}).model_dump_json(),))
    conn.execute("INSERT INTO device_settings VALUES ('rod-1', 'rod', ?, 1.0)",
                 ('{"filter_name": "ekf", "thresholds": {}}',))  # written before DeviceSettings had auto_reel
    conn.close()
    with Store(path) as s:
        assert s.schema_version == len(MIGRATIONS) >= 2
        assert s.load_defaults() == {"ball": prefs}
        loaded = s.load_device_settings()
        assert loaded["ball-1"] == ("ball", DeviceSettings(thresholds={"species": ["trout"]}))
        assert loaded["rod-1"] == ("rod", DeviceSettings(filter_name="ekf", auto_reel=False))


def test_auto_reel_round_trips(store):
    store.save_device_settings("rod-2", "rod", DeviceSettings(auto_reel=True))
    assert store.load_device_settings()["rod-2"][1].auto_reel is True
