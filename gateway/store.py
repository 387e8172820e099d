"""SQLite persistence (stdlib sqlite3, WAL): threshold defaults, per-device settings, alarm history, event log;
plus the API bearer token file.

One connection shared by all threads, serialised by a lock; every write is one transaction. The schema is
versioned: `MIGRATIONS[i]` takes version i to i + 1 and runs once, so a new `Store` on an old file upgrades it.

Token: kept in `<data_dir>/api_token`, mode 0600, so the operator can read it to configure clients and a
restart keeps it. The file (not a hash in the DB) is the secret's only home: the DB can then be copied or
inspected without leaking it; anyone who can read the file already owns the gateway's account.
"""

from __future__ import annotations

import collections
import concurrent.futures
import hmac
import itertools
import json
import logging
import math
import os
import secrets
import sqlite3
import stat
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

from gateway.alarm.engine import Alarm, AlarmStatus, Severity
from gateway.alarm.rules import SPECS
from gateway.config import THRESHOLD_MODELS, DeviceSettings, ThresholdModel
from gateway.worker_thread import wait_until_idle

MIGRATIONS: tuple[str, ...] = (
    """
    CREATE TABLE defaults (
        kind TEXT PRIMARY KEY,
        thresholds TEXT NOT NULL,
        updated_at REAL NOT NULL
    );
    CREATE TABLE device_settings (
        device_id TEXT PRIMARY KEY,
        kind TEXT NOT NULL,
        settings TEXT NOT NULL,
        updated_at REAL NOT NULL
    );
    CREATE TABLE alarms (
        id TEXT PRIMARY KEY,
        device_id TEXT NOT NULL,
        kind TEXT NOT NULL,
        type TEXT NOT NULL,
        severity TEXT NOT NULL,
        status TEXT NOT NULL CHECK (status IN ('active', 'cleared')),
        acknowledged INTEGER NOT NULL DEFAULT 0,
        started_at REAL NOT NULL,
        updated_at REAL NOT NULL,
        cleared_at REAL,
        acknowledged_at REAL,
        acknowledged_by TEXT,
        value REAL NOT NULL,
        peak REAL NOT NULL,
        count INTEGER NOT NULL,
        threshold REAL NOT NULL,
        message TEXT NOT NULL,
        details TEXT NOT NULL DEFAULT '{}'
    );
    CREATE UNIQUE INDEX alarms_one_active ON alarms (device_id, type) WHERE status = 'active';
    CREATE INDEX alarms_started ON alarms (started_at);
    CREATE INDEX alarms_device ON alarms (device_id, started_at);
    CREATE TABLE events (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        t REAL NOT NULL,
        device_id TEXT,
        kind TEXT NOT NULL,
        payload TEXT NOT NULL DEFAULT '{}'
    );
    CREATE INDEX events_t ON events (t);
    """,
    # 2: the environment ball's kind is `ball` everywhere (it was `env` in config and these keys).
    """
    DELETE FROM defaults WHERE kind = 'env' AND EXISTS (SELECT 1 FROM defaults WHERE kind = 'ball');
    UPDATE defaults SET kind = 'ball' WHERE kind = 'env';
    UPDATE device_settings SET kind = 'ball' WHERE kind = 'env';
    UPDATE alarms SET kind = 'ball' WHERE kind = 'env';
    """,
)

_ALARM_COLUMNS = (
    "id", "device_id", "kind", "type", "severity", "status", "acknowledged", "started_at", "updated_at",
    "cleared_at", "acknowledged_at", "acknowledged_by", "value", "peak", "count", "threshold", "message", "details",
)  # fmt: skip


class StoreError(Exception):
    """A stored row could not be read back (corrupt JSON, unknown kind)."""


def _alarm_row(a: Alarm) -> tuple[Any, ...]:
    spec = SPECS.get(a.type)
    return (
        a.id, a.device_id, spec.kind if spec else "", a.type, a.severity.value, a.status.value, int(a.acknowledged),
        a.started_at, a.updated_at, a.cleared_at, a.acknowledged_at, a.acknowledged_by, a.value, a.peak, a.count,
        a.threshold, a.message, json.dumps(dict(a.details)),
    )  # fmt: skip


def _alarm_from(row: sqlite3.Row) -> Alarm:
    return Alarm(
        id=row["id"], device_id=row["device_id"], type=row["type"], severity=Severity(row["severity"]),
        status=AlarmStatus(row["status"]), started_at=row["started_at"], updated_at=row["updated_at"],
        value=row["value"], threshold=row["threshold"], message=row["message"], peak=row["peak"],
        count=row["count"], acknowledged=bool(row["acknowledged"]), acknowledged_at=row["acknowledged_at"],
        acknowledged_by=row["acknowledged_by"], cleared_at=row["cleared_at"], details=json.loads(row["details"]),
    )  # fmt: skip


class Store:
    """The gateway database. Thread-safe; use as a context manager or call `close()`."""

    def __init__(self, db_path: Path) -> None:
        private_dir(db_path.parent)
        fd = os.open(db_path, os.O_RDWR | os.O_CREAT, 0o600)  # SQLite gives its -wal/-shm files the same mode
        os.close(fd)
        if stat.S_IMODE(db_path.stat().st_mode) & 0o077:
            db_path.chmod(0o600)
        self.path = db_path
        self._lock = threading.Lock()
        self._conn = sqlite3.connect(db_path, check_same_thread=False, isolation_level=None, timeout=10.0)
        self._conn.row_factory = sqlite3.Row
        self._conn.execute("PRAGMA journal_mode=WAL")
        self._conn.execute("PRAGMA synchronous=NORMAL")
        self._migrate()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    @contextmanager
    def _tx(self) -> Iterator[None]:
        """Lock, BEGIN IMMEDIATE, then COMMIT (or ROLLBACK on error): each write is one atomic transaction."""
        with self._lock:
            self._conn.execute("BEGIN IMMEDIATE")
            try:
                yield
                self._conn.execute("COMMIT")
            except BaseException:
                # A failed COMMIT (disk full) may or may not have ended the transaction: roll back only if it is
                # still open, so the original error is raised and the next write can BEGIN again.
                if self._conn.in_transaction:
                    self._conn.execute("ROLLBACK")
                raise

    def _migrate(self) -> None:
        with self._lock:
            self._conn.execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
            version = self._conn.execute("SELECT COALESCE(MAX(version), 0) FROM schema_version").fetchone()[0]
            for v, script in enumerate(MIGRATIONS[version:], start=version + 1):
                # executescript commits first; wrap each step so it is all-or-nothing.
                self._conn.executescript(f"BEGIN;\n{script}\nINSERT INTO schema_version VALUES ({v});\nCOMMIT;")

    @property
    def schema_version(self) -> int:
        with self._lock:
            return int(self._conn.execute("SELECT MAX(version) FROM schema_version").fetchone()[0])

    # -- thresholds and device settings -------------------------------------------------------------------------

    def save_defaults(self, kind: str, thresholds: ThresholdModel, t: float | None = None) -> None:
        """Store the default thresholds of a device kind."""
        with self._tx():
            self._conn.execute(
                "INSERT INTO defaults VALUES (?, ?, ?) ON CONFLICT(kind) DO UPDATE SET "
                "thresholds = excluded.thresholds, updated_at = excluded.updated_at",
                (kind, thresholds.model_dump_json(), time.time() if t is None else t),
            )

    def load_defaults(self) -> dict[str, ThresholdModel]:
        """Stored defaults by kind, validated; kinds never saved are absent (callers fall back to model defaults)."""
        with self._lock:
            rows = self._conn.execute("SELECT kind, thresholds FROM defaults").fetchall()
        out: dict[str, ThresholdModel] = {}
        for row in rows:
            model = THRESHOLD_MODELS.get(row["kind"])
            if model is None:
                raise StoreError(f"defaults: unknown device kind {row['kind']!r}")
            out[row["kind"]] = model.model_validate_json(row["thresholds"])
        return out

    def save_device_settings(self, device_id: str, kind: str, settings: DeviceSettings, t: float | None = None) -> None:
        """Store (replace) one device's settings."""
        with self._tx():
            self._conn.execute(
                "INSERT INTO device_settings VALUES (?, ?, ?, ?) ON CONFLICT(device_id) DO UPDATE SET "
                "kind = excluded.kind, settings = excluded.settings, updated_at = excluded.updated_at",
                (device_id, kind, settings.model_dump_json(), time.time() if t is None else t),
            )

    def load_device_settings(self) -> dict[str, tuple[str, DeviceSettings]]:
        """device_id -> (kind, settings) for every configured device."""
        with self._lock:
            rows = self._conn.execute("SELECT device_id, kind, settings FROM device_settings").fetchall()
        return {r["device_id"]: (r["kind"], DeviceSettings.model_validate_json(r["settings"])) for r in rows}

    def delete_device_settings(self, device_id: str) -> bool:
        """Forget a device's overrides; True if there were any."""
        with self._tx():
            cur = self._conn.execute("DELETE FROM device_settings WHERE device_id = ?", (device_id,))
        return cur.rowcount > 0

    # -- alarms ---------------------------------------------------------------------------------------------------

    def upsert_alarm(self, alarm: Alarm) -> Alarm:
        """Insert or update by id, keeping ONE active row per (device, type).

        If another active row exists for the same (device, type) under a different id (e.g. an engine that
        started without resuming), that row is updated in place and keeps its id and start time. Returns the
        alarm as stored.
        """
        with self._tx():
            if alarm.active:
                row = self._conn.execute(
                    "SELECT id, started_at FROM alarms WHERE device_id = ? AND type = ? AND status = 'active'",
                    (alarm.device_id, alarm.type),
                ).fetchone()
                if row is not None and row["id"] != alarm.id:
                    alarm = replace(alarm, id=row["id"], started_at=min(row["started_at"], alarm.started_at))
            placeholders = ", ".join("?" * len(_ALARM_COLUMNS))
            updates = ", ".join(f"{c} = excluded.{c}" for c in _ALARM_COLUMNS[1:])
            self._conn.execute(
                f"INSERT INTO alarms ({', '.join(_ALARM_COLUMNS)}) VALUES ({placeholders}) "
                f"ON CONFLICT(id) DO UPDATE SET {updates}",
                _alarm_row(alarm),
            )
        return alarm

    def get_alarm(self, alarm_id: str) -> Alarm | None:
        with self._lock:
            row = self._conn.execute("SELECT * FROM alarms WHERE id = ?", (alarm_id,)).fetchone()
        return None if row is None else _alarm_from(row)

    def list_alarms(
        self,
        device_id: str | None = None,
        type: str | None = None,
        status: AlarmStatus | str | None = None,
        severity: Severity | str | None = None,
        acknowledged: bool | None = None,
        since: float | None = None,
        limit: int = 100,
        offset: int = 0,
    ) -> tuple[list[Alarm], int]:
        """Alarms matching every given filter (since = updated at/after), newest start first; and the total count."""
        where, args = [], []
        for col, val in (("device_id", device_id), ("type", type), ("status", status), ("severity", severity)):
            if val is not None:
                where.append(f"{col} = ?")
                args.append(str(val))
        if acknowledged is not None:
            where.append("acknowledged = ?")
            args.append(str(int(acknowledged)))
        if since is not None:
            where.append("updated_at >= ?")
            args.append(str(since))
        clause = f" WHERE {' AND '.join(where)}" if where else ""
        with self._lock:
            total = int(self._conn.execute(f"SELECT COUNT(*) FROM alarms{clause}", args).fetchone()[0])
            rows = self._conn.execute(
                f"SELECT * FROM alarms{clause} ORDER BY started_at DESC, id LIMIT ? OFFSET ?",
                [*args, max(limit, 0), max(offset, 0)],
            ).fetchall()
        return [_alarm_from(r) for r in rows], total

    def active_alarms(self) -> list[Alarm]:
        """Every active alarm (no paging): what `AlarmEngine(active=...)` resumes from after a restart."""
        with self._lock:
            rows = self._conn.execute("SELECT * FROM alarms WHERE status = 'active' ORDER BY started_at").fetchall()
        return [_alarm_from(r) for r in rows]

    def acknowledge(self, alarm_id: str, by: str, t: float) -> Alarm | None:
        """Acknowledge (does not clear). None if unknown; an already acknowledged alarm is returned unchanged."""
        with self._tx():
            self._conn.execute(
                "UPDATE alarms SET acknowledged = 1, acknowledged_at = ?, acknowledged_by = ?, updated_at = ? "
                "WHERE id = ? AND acknowledged = 0",
                (t, by, t, alarm_id),
            )
            row = self._conn.execute("SELECT * FROM alarms WHERE id = ?", (alarm_id,)).fetchone()
        return None if row is None else _alarm_from(row)

    def counts(self, device_id: str | None = None) -> dict[str, int]:
        """Active alarm counts: total, unacknowledged, and per severity (keys are Severity values)."""
        clause, args = ("AND device_id = ?", (device_id,)) if device_id is not None else ("", ())
        with self._lock:
            rows = self._conn.execute(
                "SELECT severity, COUNT(*) AS n, SUM(acknowledged = 0) AS unack FROM alarms "
                f"WHERE status = 'active' {clause} GROUP BY severity",
                args,
            ).fetchall()
        out = {"active": 0, "unacknowledged": 0} | {s.value: 0 for s in Severity}
        for r in rows:
            out[r["severity"]] = r["n"]
            out["active"] += r["n"]
            out["unacknowledged"] += r["unack"]
        return out

    # -- event log ------------------------------------------------------------------------------------------------

    def log_event(
        self, t: float, kind: str, device_id: str | None = None, payload: Mapping[str, Any] | None = None
    ) -> None:
        """Append to the event log (device online/offline, threshold changes, ...)."""
        with self._tx():
            self._conn.execute(
                "INSERT INTO events (t, device_id, kind, payload) VALUES (?, ?, ?, ?)",
                (t, device_id, kind, json.dumps(dict(payload or {}))),
            )

    def events(self, since: float | None = None, limit: int = 100) -> list[dict[str, Any]]:
        """Newest events first."""
        with self._lock:
            rows = self._conn.execute(
                "SELECT * FROM events WHERE t >= ? ORDER BY t DESC, id DESC LIMIT ?",
                (-1e300 if since is None else since, limit),
            ).fetchall()
        return [dict(r) | {"payload": json.loads(r["payload"])} for r in rows]


def private_dir(path: Path) -> None:
    """Create `path` (mode 0700), or tighten it to 0700 if it is ours and not a shared sticky directory such as /tmp:
    the database, its WAL and the token file are nobody else's business."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.stat()
    if stat.S_IMODE(st.st_mode) & 0o077 and st.st_uid == os.geteuid() and not st.st_mode & stat.S_ISVTX:
        path.chmod(0o700)


# -- API bearer token ---------------------------------------------------------------------------------------------

TOKEN_FILE = "api_token"


def ensure_token(data_dir: Path) -> tuple[str, bool]:
    """The API token from `<data_dir>/api_token`, creating it (random, 256 bits, mode 0600) on first start.

    Returns (token, created). A file readable by group/others is tightened to 0600.
    """
    private_dir(data_dir)
    path = data_dir / TOKEN_FILE
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        if stat.S_IMODE(path.stat().st_mode) & 0o077:
            path.chmod(0o600)
        token = path.read_text().strip()
        if not token:
            raise StoreError(f"{path} is empty; delete it to make a new token") from None
        return token, False
    token = secrets.token_urlsafe(32)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return token, True


@dataclass(frozen=True)
class ApiToken:
    """The gateway's bearer token; `verify_token` compares in constant time."""

    value: str

    def verify_token(self, candidate: str | None) -> bool:
        return candidate is not None and hmac.compare_digest(candidate.encode(), self.value.encode())

    def __repr__(self) -> str:
        return "ApiToken(***)"


# -- the ingest side's writer ---------------------------------------------------------------------------------------

log = logging.getLogger("gateway.store")
T = TypeVar("T")


class StoreWriter:
    """One thread applies the ingest side's writes (alarm upserts, event log) in order, so the event loop never waits
    on SQLite, and a failing disk costs no alarm: the hub publishes first and hands the write here.

    A write that fails (disk full, I/O error, database locked) stays at the head of a bounded journal and is retried
    every `retry_s` until it succeeds; later writes wait behind it, so order is kept (a raise is never stored after
    its clear). Upserts of one alarm replace each other in the journal (the newest row is the one to store), so an
    outage keeps one entry per alarm, not one per update; past `max_pending` the oldest entry is dropped and counted.
    `status()` is what /api/health reports. REST configuration writes go through `call` on the same thread (once,
    ahead of the journal, their result or error back to the caller): SQLite has one writer.
    """

    def __init__(self, store: Store, max_pending: int = 10_000, retry_s: float = 1.0) -> None:
        self.store = store
        self.max_pending = max_pending
        self.retry_s = retry_s
        self.written = 0
        self.failures = 0
        self.dropped = 0
        self.last_error: str | None = None
        self._ops: OrderedDict[Hashable, Callable[[Store], object]] = OrderedDict()
        self._seq = itertools.count()
        self._calls: collections.deque[tuple[Callable[[Store], Any], concurrent.futures.Future[Any]]] = (
            collections.deque())  # fmt: skip
        self._cond = threading.Condition()
        self._stop = False
        self._busy = False
        self._last_log_s = -math.inf
        self._thread = threading.Thread(target=self._run, name="store-writer", daemon=True)
        self._thread.start()

    def upsert_alarm(self, alarm: Alarm) -> None:
        self._put(("alarm", alarm.id), lambda s: s.upsert_alarm(alarm))

    def log_event(
        self, t: float, kind: str, device_id: str | None = None, payload: Mapping[str, Any] | None = None
    ) -> None:
        payload = dict(payload or {})
        self._put(("event", next(self._seq)), lambda s: s.log_event(t, kind, device_id, payload))

    def call(self, op: Callable[[Store], T]) -> concurrent.futures.Future[T]:
        """Run `op(store)` once on the writer thread, before the journal's pending writes (a retried failing write
        must not hold a REST request); its result or exception lands in the future (`asyncio.wrap_future` it)."""
        fut: concurrent.futures.Future[T] = concurrent.futures.Future()
        with self._cond:
            if self._stop:
                fut.set_exception(RuntimeError("store writer stopped"))
                return fut
            self._calls.append((op, fut))
            self._cond.notify_all()
        return fut

    def _run_call(self) -> None:
        with self._cond:
            op, fut = self._calls.popleft()
            self._busy = True
        try:
            if fut.set_running_or_notify_cancel():
                try:
                    fut.set_result(op(self.store))
                except Exception as exc:
                    fut.set_exception(exc)
        finally:
            with self._cond:
                self._busy = False
                self._cond.notify_all()

    def _put(self, key: Hashable, op: Callable[[Store], object]) -> None:
        with self._cond:
            self._ops[key] = op  # an alarm already pending keeps its place and gets the newest row
            while len(self._ops) > self.max_pending:
                self._ops.popitem(last=False)
                self.dropped += 1
            self._cond.notify_all()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._ops and not self._calls and not self._stop:
                    self._cond.wait()
                if self._calls:
                    run_call = True
                elif not self._ops:
                    return
                else:
                    run_call = False
            if run_call:
                self._run_call()
                continue
            with self._cond:
                if not self._ops:
                    continue
                key, op = next(iter(self._ops.items()))
                self._busy = True
            try:
                op(self.store)
            except Exception as exc:
                with self._cond:
                    self._busy = False
                    self.failures += 1
                    self.last_error = f"{type(exc).__name__}: {exc}"[:300]
                    now = time.monotonic()
                    if now - self._last_log_s >= 10.0:
                        self._last_log_s = now
                        log.error("store write failed (%d pending, retrying every %.1f s): %s", len(self._ops),
                                  self.retry_s, self.last_error)  # fmt: skip
                    if self._stop:
                        return
                    self._cond.wait_for(lambda: bool(self._calls) or self._stop, self.retry_s)
                continue
            with self._cond:
                self._busy = False
                if self._ops.get(key) is op:  # not replaced by a newer row meanwhile
                    del self._ops[key]
                self.written += 1
                if self.last_error is not None:
                    log.warning("store writes succeed again (%d pending)", len(self._ops))
                self.last_error = None
                self._cond.notify_all()

    def flush(self, timeout_s: float = 2.0) -> bool:
        """Wait until every pending write is stored; False on timeout (the store is failing)."""
        return wait_until_idle(self._cond, lambda: bool(self._ops or self._calls) or self._busy, self._thread,
                               timeout_s)  # fmt: skip

    def close(self, timeout_s: float = 2.0) -> None:
        """Store what is pending (up to `timeout_s`), then stop the thread."""
        self.flush(timeout_s)
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout_s)
        with self._cond:
            while self._calls:  # not run: the caller must not wait for ever
                self._calls.popleft()[1].set_exception(RuntimeError("store writer stopped"))

    def status(self) -> dict[str, Any]:
        """Health of the write path: `ok` False while writes fail or wait; `reason` says why."""
        with self._cond:
            pending = len(self._ops)
            failing = self.last_error is not None
            reason = None
            if failing:
                reason = (f"store writes failing ({pending} pending, retried every {self.retry_s:g} s): "
                          f"{self.last_error}")  # fmt: skip
            return {"ok": not failing, "reason": reason, "pending": pending, "written": self.written,
                    "failures": self.failures, "dropped": self.dropped}  # fmt: skip
