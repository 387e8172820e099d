"""The message bus the gateway talks through: a `Bus` protocol, `ZenohBus` (real) and `MemoryBus` (tests).

Callbacks registered with `subscribe` / `watch_liveliness` run on the bus's own threads (zenoh's): they must
only hand off (see `gateway.ingest.runner.Inbox`), never block, never call back into the bus
(zenoh-python docs; NOTES-zenoh-viser §1 pitfall 2). `close()` must always run: a zenoh session left open
with live callback subscribers hangs interpreter exit (zenoh-python #434).
"""

from __future__ import annotations

import json
import logging
import queue
import threading
from collections.abc import Callable
from typing import Any, Protocol

import zenoh

from gateway.config import Settings

log = logging.getLogger("gateway.bus")

SampleCallback = Callable[[str, bytes], None]
"""(key, payload) of one sample, called on a bus thread."""
Unsubscribe = Callable[[], None]
"""Returned by `subscribe`: undeclares that subscriber (idempotent; not from a bus callback)."""
PresenceCallback = Callable[[str, bool], None]
"""(token key, alive) for a liveliness token appearing (True) or vanishing (False), called on a bus thread."""
QueryHandler = Callable[[str], list[tuple[str, bytes]]]
"""Selector asked for -> replies (key, payload). Runs on a bus thread: must only read, never block."""


class Bus(Protocol):
    """What the gateway needs from a pub/sub transport."""

    def subscribe(self, selector: str, callback: SampleCallback, *, direct: bool = False) -> Unsubscribe: ...

    def put(self, key: str, payload: bytes, *, encoding: str, block: bool = False, express: bool = False) -> None: ...

    def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
        """Whether a put on `key` would reach a subscriber now (a caller may then skip encoding a message nobody
        takes); a bus that cannot tell says True."""
        ...

    def watch_liveliness(self, selector: str, callback: PresenceCallback) -> None: ...

    def declare_token(self, key: str) -> None: ...

    def declare_queryable(self, selector: str, handler: QueryHandler, *, encoding: str) -> None: ...

    def close(self) -> None: ...


_SETTING_OF_KEY = {"mode": "zenoh_mode", "listen/endpoints": "zenoh_listen", "connect/endpoints": "zenoh_connect",
                   "scouting/multicast/enabled": "zenoh_multicast_scouting"}  # fmt: skip


def zenoh_config(settings: Settings) -> zenoh.Config:
    """zenoh Config from Settings (mode, listen/connect endpoints, multicast scouting).

    With `zenoh_config_file` (`--zenoh-config`) the file is the base, so TLS/mTLS, user/password authentication and
    access control can be deployed (docs/security.md); only the zenoh settings given explicitly (options or RIG_*
    variables) override its keys, the defaults do not."""
    path = settings.zenoh_config_file
    conf = zenoh.Config() if path is None else zenoh.Config.from_file(str(path))
    for key, value in settings.zenoh_config().items():
        if path is not None and _SETTING_OF_KEY[key] not in settings.model_fields_set:
            continue
        if key.endswith("/endpoints") and value == "[]":
            continue
        conf.insert_json5(key, value)
    if settings.zenoh_connect:
        # keep retrying a router/peer that is not up yet instead of failing at start-up
        conf.insert_json5("connect/exit_on_failure", "false")
        retry = '{"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2}'
        conf.insert_json5("connect/retry", retry)
    return conf


def _guarded(name: str, fn: Callable[..., None]) -> Callable[..., None]:
    """Wrap a callback so an exception is logged (zenoh would only print it) and never escapes."""

    def run(*args: object) -> None:
        try:
            fn(*args)
        except Exception:
            log.exception("callback %s failed", name)

    return run


ROUTE_KEYS_MAX = 20_000  # keys declared by `RouteKeys` per session (a hostile peer's key spray stops here)


class RouteKeys:
    """Declares each key a wildcard subscriber receives as a zenoh key expression (`Session.declare_keyexpr`), once,
    from a thread of its own (never on zenoh's callback thread), so zenoh caches the key's route.

    Why: a session that watches many liveliness tokens (the gateway's device presence: one token a device) holds
    each as a resource, and zenoh 1.x routes a sample whose key is not a declared resource by matching the key
    against all of them, on every sample, on the receive thread. A client session watching 1000 device tokens
    spent 0.053 ms of CPU a sample that way, 0.008 ms once the keys were declared (`python -m
    bench.zenoh_subscribers`, cases `catch-all+tokens` and `catch-all+tokens+keys`); in a shard beside another (a
    client of the router) it was a third of the gateway's CPU at 1000 devices (`bench.fleet --threads`, the child's
    `rx` thread: 0.072 -> 0.002 ms per packet)."""

    def __init__(self, session: zenoh.Session, max_keys: int = ROUTE_KEYS_MAX) -> None:
        self.session = session
        self.max_keys = max_keys
        self.seen: set[str] = set()
        self.declared: list[zenoh.KeyExpr] = []
        self.failed = 0
        self._todo: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="route-keys", daemon=True)
        self._thread.start()

    def note(self, key: str) -> None:
        """A sample arrived on `key` (bus thread; a set lookup unless the key is new)."""
        if key not in self.seen and len(self.seen) < self.max_keys:
            self.seen.add(key)
            self._todo.put(key)

    def _run(self) -> None:
        while (key := self._todo.get()) is not None:
            try:
                self.declared.append(self.session.declare_keyexpr(key))
            except Exception:  # the session is closing, or zenoh refused the key: it is only routed slower
                self.failed += 1

    def close(self) -> None:
        self._todo.put(None)
        self._thread.join(timeout=2.0)


class ZenohBus:
    """A zenoh session with publishers cached per key; BLOCK congestion control for commands and alarms; the keys
    its wildcard subscribers receive declared (`RouteKeys`)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._pubs: dict[tuple[str, bool, bool], zenoh.Publisher] = {}
        self._handles: list[object] = []
        self._lock = threading.Lock()
        self.route_keys = RouteKeys(session)

    @classmethod
    def open(cls, settings: Settings) -> ZenohBus:
        """Open a session from Settings (the gateway listens on tcp/127.0.0.1:7447 by default)."""
        return cls(zenoh.open(zenoh_config(settings)))

    def subscribe(self, selector: str, callback: SampleCallback, *, direct: bool = False) -> Unsubscribe:
        """A callback subscriber. zenoh-python runs each callback subscriber's calls in a Python thread of its own
        (`Callback(indirect=True)`, its default); `direct` runs them on zenoh's receive thread instead, for the many
        per-device subscribers of a shard (gateway/shard/subscriptions.py): no thread each (creating one made a
        declaration take ~1-2 ms), no hand-over. The callback must then be as short as `Inbox.offer`."""

        note = self.route_keys.note if "*" in selector else None  # an exact key is declared by its subscriber

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            if note is not None:
                note(key)
            callback(key, sample.payload.to_bytes())

        handler = _guarded(selector, on_sample)
        sub = self.session.declare_subscriber(selector, zenoh.handlers.Callback(handler, indirect=False)
                                              if direct else handler)  # fmt: skip
        with self._lock:
            self._handles.append(sub)

        def unsubscribe() -> None:
            with self._lock:
                if not any(h is sub for h in self._handles):
                    return
                self._handles = [h for h in self._handles if h is not sub]
            try:
                sub.undeclare()  # type: ignore[no-untyped-call]
            except Exception:  # the session is closing
                pass

        return unsubscribe

    def put(self, key: str, payload: bytes, *, encoding: str, block: bool = False, express: bool = False) -> None:
        """One put with the topic's QoS (schemas.Topic): `express` sends it at once; otherwise zenoh batches it with
        the puts around it. A DROP stream must not be express: zenoh queues a few batches per priority, one message
        each when express, so a batch's burst of express DROP puts overflowed that queue and lost messages
        (`bench.zenoh_burst`); batched, the same burst fits."""
        self._publisher(key, encoding, block, express).put(payload)

    def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
        """zenoh's matching status of the key's publisher: True while a subscriber anywhere the routing reaches
        (this session, a client of this router, another router's) takes `key`; about a microsecond a call. A
        subscriber declared later matches within milliseconds (tests/gateway/test_bus.py)."""
        status: Any = self._publisher(key, encoding, block, express).matching_status  # a MatchingStatus (stub: bool)
        return bool(status.matching)

    def _publisher(self, key: str, encoding: str, block: bool, express: bool) -> zenoh.Publisher:
        """The key's publisher with that QoS, declared on first use and kept."""
        pub = self._pubs.get((key, block, express))
        if pub is None:
            with self._lock:
                pub = self._pubs.get((key, block, express))
                if pub is None:
                    pub = self.session.declare_publisher(
                        key, encoding=zenoh.Encoding(encoding), express=express,
                        congestion_control=zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP,
                    )  # fmt: skip
                    self._pubs[(key, block, express)] = pub
        return pub

    def watch_liveliness(self, selector: str, callback: PresenceCallback) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        sub = self.session.liveliness().declare_subscriber(selector, _guarded(selector, on_sample), history=True)
        self._handles.append(sub)

    def declare_token(self, key: str) -> None:
        self._handles.append(self.session.liveliness().declare_token(key))

    def declare_queryable(self, selector: str, handler: QueryHandler, *, encoding: str) -> None:
        enc = zenoh.Encoding(encoding)

        def on_query(query: zenoh.Query) -> None:
            for key, payload in handler(str(query.key_expr)):
                query.reply(key, payload, encoding=enc)

        self._handles.append(self.session.declare_queryable(selector, _guarded(selector, on_query)))

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        for h in reversed(self._handles):
            try:
                h.undeclare()  # type: ignore[attr-defined]
            except Exception:  # already closed
                pass
        self._handles.clear()
        for p in self._pubs.values():
            try:
                p.undeclare()  # type: ignore[no-untyped-call]
            except Exception:
                pass
        self._pubs.clear()
        self.route_keys.close()
        self.session.close()  # type: ignore[no-untyped-call]


def key_matches(selector: str, key: str) -> bool:
    """Key-expression match for `*` (one chunk) and `**` (any number of chunks)."""
    sel, parts = selector.split("/"), key.split("/")

    def go(i: int, j: int) -> bool:
        if i == len(sel):
            return j == len(parts)
        if sel[i] == "**":
            return any(go(i + 1, k) for k in range(j, len(parts) + 1))
        return j < len(parts) and (sel[i] == "*" or sel[i] == parts[j]) and go(i + 1, j + 1)

    return go(0, 0)


class MemoryBus:
    """In-process twin of ZenohBus: puts are delivered synchronously to matching subscribers and recorded."""

    def __init__(self) -> None:
        self.subs: list[tuple[str, SampleCallback]] = []
        self.watchers: list[tuple[str, PresenceCallback]] = []
        self.queryables: list[tuple[str, QueryHandler]] = []
        self.tokens: set[str] = set()
        self.sent: list[tuple[str, bytes, bool]] = []
        self.closed = False

    def subscribe(self, selector: str, callback: SampleCallback, *, direct: bool = False) -> Unsubscribe:
        entry = (selector, callback)
        self.subs.append(entry)
        return lambda: self.subs.remove(entry) if entry in self.subs else None

    def put(self, key: str, payload: bytes, *, encoding: str, block: bool = False, express: bool = False) -> None:
        self.sent.append((key, payload, block))
        for sel, cb in self.subs:
            if key_matches(sel, key):
                cb(key, payload)

    def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
        """True: a MemoryBus keeps every put in `sent` for the tests to read."""
        return True

    def watch_liveliness(self, selector: str, callback: PresenceCallback) -> None:
        self.watchers.append((selector, callback))
        for t in self.tokens:
            if key_matches(selector, t):
                callback(t, True)

    def declare_token(self, key: str) -> None:
        self.set_alive(key, True)

    def set_alive(self, key: str, alive: bool) -> None:
        """Simulate a device token appearing or vanishing."""
        (self.tokens.add if alive else self.tokens.discard)(key)
        for sel, cb in self.watchers:
            if key_matches(sel, key):
                cb(key, alive)

    def declare_queryable(self, selector: str, handler: QueryHandler, *, encoding: str) -> None:
        self.queryables.append((selector, handler))

    def get(self, selector: str) -> list[tuple[str, bytes]]:
        """Ask every queryable (the MemoryBus twin of `session.get`; handlers filter by the selector)."""
        return [r for _, h in self.queryables for r in h(selector)]

    def sent_json(self, prefix: str) -> list[dict[str, object]]:
        """Decoded payloads of everything put on keys starting with `prefix`."""
        return [json.loads(p) for k, p, _ in self.sent if k.startswith(prefix)]

    def close(self) -> None:
        self.closed = True
