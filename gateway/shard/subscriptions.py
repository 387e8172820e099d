"""What device data a shard's zenoh session subscribes to, so the router sends a shard only its own devices' packets.

Alone (no other live shard could serve any device this one serves) a shard keeps the catch-all data selectors
(`rig/*/*/imu`, ...: one subscriber per kind, no per-device cost). Beside other shards it subscribes to the exact
data keys of each device it serves instead (`rig/rod/{id}/imu` and `rig/rod/{id}/reel`, ...: no wildcard, so never a
command key), for the devices it knows of:

- devices with a liveliness token `rig/{kind}/{id}` (protocol §6; every shard watches them all), and
- tokenless devices (a device that skipped §6, or whose token went while it keeps sending): found by a **probe**,
  the catch-all selectors subscribed for `PROBE_WINDOW_S` every `PROBE_EVERY_S` and at once after each live-set
  change, which only notes the ids it sees (it hands no packet to the inbox). Every shard probes; only the owner
  subscribes, so such a device is served exactly once, from the first packet after the probe that saw it. One
  that sends nothing for `IDLE_S` is forgotten.

Subscribers are not free: a zenoh 1.x session matches each received sample against every subscriber it holds
(`python -m bench.zenoh_subscribers`: 500 exact-key subscribers receiving 5,000 samples/s cost a client session
more CPU than one wildcard subscriber receiving all 10,000/s; 150 receiving 1,500/s a little less than one receiving
3,000/s). Past `MAX_DEVICE_SUBSCRIBERS` the shard therefore holds the catch-all again (its inbox drops the others'
packets, counted as `ignored`). docs/gateway.md, Shards.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Literal

from gateway import schemas
from gateway.ingest.bus import Bus, SampleCallback, Unsubscribe
from gateway.ingest.presence import token_device
from gateway.shard.ownership import ShardInfo

log = logging.getLogger("gateway.shard")
PROBE_EVERY_S = 10.0
PROBE_WINDOW_S = 0.5
IDLE_S = 30.0
MAX_DEVICE_SUBSCRIBERS = 400  # about where matching costs what the others' packets cost (bench.zenoh_subscribers)
Mode = Literal["all", "devices"]


def device_keys(kind: str, device_id: str) -> tuple[str, ...]:
    """The exact keys a device of `kind` publishes its data on (protocol §2; truth and commands excluded)."""
    return tuple(t.key(kind, device_id) for t in schemas.TOPICS if t.direction == "device" and kind in t.kinds)


def _literal_prefix(pattern: str) -> tuple[str, bool] | None:
    """`site1-*` -> ("site1-", True), `rod-7` -> ("rod-7", False); None for any other glob."""
    if any(c in pattern for c in "?[]") or "*" in pattern[:-1]:
        return None
    return (pattern[:-1], True) if pattern.endswith("*") else (pattern, False)


def _patterns_overlap(p: str, q: str) -> bool:
    a, b = _literal_prefix(p), _literal_prefix(q)
    if a is None or b is None:
        return True  # not decided here: assume some id matches both
    (pa, sa), (pb, sb) = a, b
    if sa and sb:
        return pa.startswith(pb) or pb.startswith(pa)
    if sa:
        return pb.startswith(pa)
    if sb:
        return pa.startswith(pb)
    return pa == pb


def may_overlap(a: ShardInfo, b: ShardInfo) -> bool:
    """Could some device id be served by both shards (conservative: True unless their globs are literal prefixes
    that exclude each other, e.g. `site1-*` and `site2-*`)?"""
    if not a.patterns or not b.patterns:
        return True
    return any(_patterns_overlap(p, q) for p in a.patterns for q in b.patterns)


def wanted_selectors(
    mode: Mode, catch_all: Iterable[str], devices: Mapping[str, str], owns: Callable[[str], bool]
) -> set[str]:
    """The selectors to hold: the catch-all ones, or the data keys of the devices (id -> kind) this shard owns."""
    if mode == "all":
        return set(catch_all)
    return {k for d, kind in devices.items() if owns(d) for k in device_keys(kind, d)}


class DataSubscriptions:
    """The device-data subscribers of one shard (event loop), handing packets to `offer` (the inbox).

    `sync()` computes the selectors to hold from the mode, the known devices and ownership, and applies the
    difference (new subscribers first, then the old ones go: a packet may arrive twice while both are held, and the
    sequence check drops the second copy; none is missed), in a worker thread (zenoh calls are not made on the event
    loop), one change set at a time. The subscribers are `direct` (their callbacks run on zenoh's receive thread):
    zenoh-python's default gives each callback subscriber a Python thread of its own."""

    def __init__(
        self, bus: Bus, catch_all: tuple[str, ...], owns: Callable[[str], bool], max_devices: int,
        last_packet_s: Callable[[str], float | None] = lambda d: None, clock: Callable[[], float] = time.monotonic,
    ) -> None:  # fmt: skip
        self.bus = bus
        self.catch_all = catch_all
        self.owns = owns
        self.max_devices = max_devices
        self.last_packet_s = last_packet_s  # monotonic arrival of a device's newest packet here (ingest counters)
        self.clock = clock
        self.mode: Mode = "all"
        self.offer: SampleCallback | None = None
        self.tokens: dict[str, str] = {}  # device -> kind, token alive (every shard's devices)
        self.tokenless: dict[str, tuple[str, float]] = {}  # device -> (kind, last seen: probe or packet, monotonic)
        self.held: dict[str, Unsubscribe] = {}  # selector -> its subscriber
        self.probes = 0
        self.per_device = False  # what `held` is: the devices' keys (True) or the catch-all
        self._wanted_ids: frozenset[str] = frozenset()  # devices subscribed one by one (read by the probe callback)
        self._probe_seen: set[str] = set()
        self._lock = asyncio.Lock()
        self._dirty = False
        self._task: asyncio.Task[None] | None = None
        self._probe_task: asyncio.Task[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    # -- inputs (event loop) -----------------------------------------------------------------------------------

    def start(self, offer: SampleCallback) -> None:
        """Begin subscribing for the inbox (called when the service starts) and run the probe timer."""
        self.offer = offer
        self._loop = asyncio.get_running_loop()
        self._task = self._loop.create_task(self._timer())
        if self.mode == "all":  # as a single gateway: subscribed when `start` returns, as before sharding
            self.held = {s: self.bus.subscribe(s, offer) for s in self.catch_all}
        self.changed()
        if self.mode == "devices":
            self.probe_soon()

    def set_mode(self, alone: bool) -> None:
        """The live set changed: catch-all when alone, per device otherwise; probe at once (devices may have moved
        here whose owner knew them only from its probes)."""
        self.mode = "all" if alone else "devices"
        self.changed()
        if self.mode == "devices":
            self.probe_soon()

    def token(self, key: str, alive: bool) -> None:
        """A device token appeared or vanished. A device whose token goes is kept as tokenless for `IDLE_S`, so one
        that keeps sending stays subscribed."""
        dev = token_device(key)
        if dev is None or not schemas.valid_device_id(dev[1]):
            return
        kind, device_id = dev
        if alive:
            if device_id not in self.tokens and len(self.tokens) >= self.max_devices:
                return
            self.tokens[device_id] = kind
            self.tokenless.pop(device_id, None)
        elif self.tokens.pop(device_id, None) is not None:
            self.tokenless[device_id] = (kind, self.clock())
        self.changed()

    def found(self, kind: str, device_id: str) -> None:
        """A probe saw data of a device this shard does not subscribe to."""
        if device_id in self.tokens or kind not in schemas.KINDS or not schemas.valid_device_id(device_id):
            return
        if device_id not in self.tokenless and len(self.tokenless) >= self.max_devices:
            return
        self.tokenless[device_id] = (kind, self.clock())
        self.changed()

    def expire(self) -> None:
        """Forget tokenless devices not seen (by a probe, or a packet here) for `IDLE_S`."""
        now = self.clock()
        gone = [d for d, (_, seen) in self.tokenless.items() if now - max(seen, self.last_packet_s(d) or -1.0) > IDLE_S]
        for d in gone:
            del self.tokenless[d]
        if gone:
            self.changed()

    # -- applying ----------------------------------------------------------------------------------------------

    def devices(self) -> dict[str, str]:
        """Every device known here, id -> kind (tokens and tokenless)."""
        out = {d: kind for d, (kind, _) in self.tokenless.items()}
        out.update(self.tokens)
        return out

    def wanted(self) -> set[str]:
        if self.mode == "devices":
            wanted = wanted_selectors("devices", self.catch_all, self.devices(), self.owns)
            if len(wanted) <= MAX_DEVICE_SUBSCRIBERS:
                return wanted
        return set(self.catch_all)

    def changed(self) -> None:
        """Re-apply soon (coalesced: one change set at a time, the newest state)."""
        if self.offer is None or self._loop is None:
            return
        if not self._dirty:
            self._dirty = True
            self._loop.create_task(self.sync())

    async def sync(self) -> None:
        async with self._lock:
            self._dirty = False
            offer = self.offer
            assert offer is not None
            wanted = self.wanted()
            per_device = wanted.isdisjoint(self.catch_all)
            add = sorted(wanted - self.held.keys())
            drop = [self.held[s] for s in self.held.keys() - wanted]
            if per_device:  # the probe callback skips these from now on
                self._wanted_ids = frozenset(k.split("/")[2] for k in wanted)
            if add or drop:

                def apply() -> dict[str, Unsubscribe]:
                    new = {s: self.bus.subscribe(s, offer, direct=per_device) for s in add}
                    for unsubscribe in drop:
                        unsubscribe()
                    return new

                new = await asyncio.to_thread(apply)
                self.held = {s: u for s, u in self.held.items() if s in wanted} | new
                log.info("data subscriptions: %d (%s; +%d -%d)", len(self.held), "per device" if per_device
                         else "catch-all", len(add), len(drop))  # fmt: skip
            self.per_device = per_device
            if not per_device:
                self._wanted_ids = frozenset()

    # -- probes ------------------------------------------------------------------------------------------------

    def probe_soon(self) -> None:
        if self._loop is None or self.offer is None or (self._probe_task is not None and not self._probe_task.done()):
            return
        self._probe_task = self._loop.create_task(self.probe())

    async def probe(self, window_s: float | None = None) -> None:
        """Subscribe the catch-all selectors for `window_s` (`PROBE_WINDOW_S`) and note the devices seen that are not
        subscribed."""
        loop = asyncio.get_running_loop()
        self._probe_seen = set()

        def on_sample(key: str, payload: bytes) -> None:  # bus thread: note a new id once, hand off
            parts = key.split("/", 3)
            if len(parts) < 4 or parts[2] in self._wanted_ids or parts[2] in self._probe_seen:
                return
            self._probe_seen.add(parts[2])
            loop.call_soon_threadsafe(self.found, parts[1], parts[2])

        catch_all = self.catch_all
        unsubs = await asyncio.to_thread(lambda: [self.bus.subscribe(s, on_sample, direct=True) for s in catch_all])
        self.probes += 1
        try:
            await asyncio.sleep(PROBE_WINDOW_S if window_s is None else window_s)
        finally:
            await asyncio.to_thread(lambda: [u() for u in unsubs])

    async def _timer(self) -> None:
        while True:
            await asyncio.sleep(PROBE_EVERY_S)
            try:
                self.expire()
                if self.mode == "devices":
                    self.probe_soon()
            except Exception:
                log.exception("data subscription upkeep failed")

    async def stop(self) -> None:
        """Stop the timer and any probe, and drop every subscriber (before the bus closes)."""
        for task in (self._task, self._probe_task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
        self._task = self._probe_task = None
        async with self._lock:
            for unsubscribe in self.held.values():
                unsubscribe()
            self.held = {}
        self.offer = None

    def stats(self) -> dict[str, object]:
        return {"data_subscriptions": len(self.held), "data_mode": "devices" if self.per_device else "all",
                "tokenless": len(self.tokenless), "probes": self.probes}  # fmt: skip
