"""One gateway shard on zenoh: who is alive, which devices are mine, and what the shards share.

A `ShardNode` is attached to a `GatewayService` (gateway/app.py) and, over the service's bus:

- declares the liveliness token `gw/shard/{id}/{patterns}` and watches the others' (history included), so every
  shard holds the same live set; `Ownership` (rendezvous hashing) then says which devices are this shard's.
  It subscribes to every device's data and its inbox drops the other shards' packets before decoding; with
  `--shard-subscribe own`, beside other shards, to its own devices' data keys only (`DataSubscriptions`,
  gateway/shard/subscriptions.py: from the device tokens, tokenless devices from periodic probes), so the router
  does not send it the others' packets. Presence, offline
  alarms, reel watchdog stops and config replies only for its own devices.
- on a live-set change (on the event loop): devices that moved away lose their fusion and rules state here and their
  active alarms are released; devices that moved here start from a fresh warm-up (as after a restart) and resume
  the active alarms the store holds for them, so a condition still present updates that alarm instead of raising
  a second one.
- mirrors every alarm row it stores on `gw/shard/{id}/alarm_row` and stores the other shards' rows, so the alarm
  history answers from any shard's REST endpoint.
- publishes the whole configuration (kind defaults and device settings) on `gw/shard/{id}/config` after each REST
  change, applies (and persists) the others', and answers the same snapshot as a queryable: a starting shard
  adopts the configuration of the longest-running live shard that started before it.
- hands the other shards' alarm events to this shard's hub listeners (the dashboard's alarm frames), and, only
  while `mirror_demand()` says someone looks (a 3-D view client on this endpoint) and another shard is live, their
  attitude and swing messages at most `shard_mirror_hz` per device: subscribed to those outputs, each shard
  received every other shard's attitude (about one per packet) through the router and dropped most of them. The
  live stream and the history keep only this shard's devices and get the others' from their owners (`LivePeers`,
  gateway/shard/live.py; history queries).
- answers `gw/shard/{id}/devices`, `gw/shard/{id}/device/{device_id}`, `gw/shard/{id}/stats`,
  `gw/shard/{id}/history/{device_id}/{s}/{n}`, `gw/shard/{id}/history_all/{s}/{n}` for the REST front
  (gateway/shard/routes.py), and runs the writes other endpoints forward for its devices
  (`gw/shard/{id}/call/{hex JSON}`: reel, ack, clear; `run_call`).

Callbacks only hand off to the event loop (NOTES-zenoh-viser §1), except the read-only queryables, which wait for
the loop to build their answer (bounded by `ANSWER_TIMEOUT_S`).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import math
import time
from collections.abc import Callable, Coroutine
from functools import partial
from typing import Any

import zenoh

from gateway import schemas
from gateway.alarm.engine import Alarm, AlarmStatus, Severity
from gateway.api.routes.history import History
from gateway.config import THRESHOLD_MODELS, DeviceSettings, Settings
from gateway.errors import BadSettings
from gateway.ingest.bus import Bus, MemoryBus, ZenohBus
from gateway.ingest.runner import GatewayService
from gateway.shard import STARTED_S
from gateway.shard.live import LivePeers
from gateway.shard.ownership import SEL_SHARD_TOKENS, Ownership, ShardInfo, glob_to_key_chunk, owner_of
from gateway.shard.subscriptions import DataSubscriptions, may_overlap
from gateway.store import Store, StoreWriter

log = logging.getLogger("gateway.shard")
MIRRORED = ("gw/*/*/alarm", "gw/*/*/attitude", "gw/hook/*/swing")
MIRRORED_ON_DEMAND = MIRRORED[1:]  # subscribed only while `mirror_demand()` (the alarms always)
MIRROR_CHECK_S = 1.0
MIRROR_MODELS: dict[str, type[schemas.WireModel]] = {"alarm": schemas.AlarmEvent, "attitude": schemas.Attitude,
                                                     "swing": schemas.Swing}  # fmt: skip

ANSWER_TIMEOUT_S = 2.0
CALL_TIMEOUT_S = 3.0  # a forwarded write waits for the owner task (between two batches) and a store write
QUERY_TIMEOUT_S = 1.0
ADOPT_WAIT_S = 10.0  # a local shard waits this long for its parent's configuration


def alarm_to_json(a: Alarm) -> bytes:
    d = {f: getattr(a, f) for f in Alarm.__dataclass_fields__}
    d["severity"], d["status"], d["details"] = a.severity.value, a.status.value, dict(a.details)
    return json.dumps(d).encode()


def alarm_from_json(payload: bytes) -> Alarm:
    d = json.loads(payload)
    d["severity"], d["status"] = Severity(d["severity"]), AlarmStatus(d["status"])
    return Alarm(**d)


class MirroringWriter(StoreWriter):
    """The store writer of a shard: every alarm row it stores is also handed to `mirror` (published to the other
    shards); rows from the other shards are stored with `store_only`."""

    def __init__(self, store: Store, mirror: Callable[[Alarm], None]) -> None:
        super().__init__(store)
        self._mirror = mirror

    def upsert_alarm(self, alarm: Alarm) -> None:
        super().upsert_alarm(alarm)
        try:
            self._mirror(alarm)
        except Exception:
            log.exception("alarm row %s not mirrored", alarm.id)

    def store_only(self, alarm: Alarm) -> None:
        super().upsert_alarm(alarm)


def config_snapshot(service: GatewayService) -> dict[str, Any]:
    """Every setting a REST write can change: the kind defaults and each device's settings."""
    pl = service.pipeline
    return {
        "defaults": {k: m.model_dump() for k, m in pl.defaults.items()},
        "devices": {d: {"kind": k, "settings": ds.model_dump()} for d, (k, ds) in pl.device_settings.items()},
    }


class ShardNode:
    """This process's shard: ownership from the live set, and the shared alarm history and configuration."""

    def __init__(self, settings: Settings, bus: Bus, shard_id: str) -> None:
        self.settings = settings
        self.bus = bus
        self.info = ShardInfo(shard_id, tuple(settings.shard_devices))
        self.ownership = Ownership(self.info)
        self.started_s = STARTED_S
        self.service: GatewayService | None = None
        self.writer: MirroringWriter | None = None
        self.config_version_us = 0
        self._reconciled_live = dict(self.ownership.live)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._reconcile_pending = False
        self._mirrored: collections.deque[tuple[str, bytes]] = collections.deque(maxlen=100_000)
        self._mirror_wake = False
        self._mirror_last: dict[str, float] = {}
        self.takeovers: list[tuple[float, str]] = []  # (wall s, device) of devices moved here, newest last (≤ 1000)
        self.history: History | None = None  # this endpoint's dashboard history (set when it starts)
        self.peers: LivePeers | None = None  # the other shards' side of the dashboard stream (set in `start`)
        self.mirror_demand: Callable[[], bool] = lambda: False  # does anyone here look at other shards' attitudes?
        self._mirror_unsubs: list[Callable[[], None]] = []
        self._mirror_task: asyncio.Task[None] | None = None
        self.data: DataSubscriptions | None = None  # this shard's device-data subscribers (set in `attach`)

    @property
    def shard_id(self) -> str:
        return self.info.shard_id

    def key(self, leaf: str) -> str:
        return f"gw/shard/{self.shard_id}/{leaf}"

    # -- wiring (before the service starts) -------------------------------------------------------------------

    def writer_factory(self, store: Store) -> StoreWriter:
        self.writer = MirroringWriter(store, self._publish_row)
        return self.writer

    def attach(self, service: GatewayService) -> None:
        """Hook the service: the device filter, its data subscriptions (`DataSubscriptions`) and, for site
        partitions, narrower catch-all selectors."""
        self.service = service
        service.accept = self.ownership.owns
        service.counters.shard = self.shard_id
        chunks = [glob_to_key_chunk(p) for p in self.info.patterns]
        if chunks and all(c is not None for c in chunks):
            service.data_selectors = tuple(
                sel.replace("rig/*/*/", f"rig/*/{c}/").replace("rig/ball/*/", f"rig/ball/{c}/")
                .replace("rig/rod/*/", f"rig/rod/{c}/")
                for sel in schemas.SEL_DEVICE_DATA for c in chunks
            )  # fmt: skip

        def last_packet_s(device_id: str) -> float | None:
            dev = service.counters.devices.get(device_id)
            return None if dev is None else dev.last_arrival_s

        if self.settings.shard_subscribe == "own":  # else the catch-all `data_selectors`, as a single gateway
            self.data = DataSubscriptions(self.bus, service.data_selectors, self.ownership.owns,
                                          self.settings.max_devices, last_packet_s)  # fmt: skip
            service.subscribe_data = self.data.start

    async def start(self, adopt_config: bool = False) -> None:
        """Join: watch the shard tokens, serve the queryables, take the running shards' configuration, then declare
        this shard's token (so others move devices here only once it is ready to serve them)."""
        assert self.service is not None
        self._loop = loop = asyncio.get_running_loop()
        self.bus.subscribe("gw/shard/*/alarm_row", self._on_row)
        self.bus.subscribe("gw/shard/*/config", self._on_config)
        for sel in MIRRORED:
            if sel not in MIRRORED_ON_DEMAND:
                self.bus.subscribe(sel, self._on_output)
        self._mirror_task = loop.create_task(self._mirror_loop())
        self.bus.declare_queryable(self.key("**"), self._answer, encoding=schemas.ENCODING_GW)
        self.peers = LivePeers(self.bus, self.ownership, self.shard_id, loop.call_soon_threadsafe)
        self.peers.subscribe()
        await self._adopt_config(wait_s=ADOPT_WAIT_S if adopt_config else 0.0)

        def on_token(key: str, alive: bool) -> None:  # bus thread: swap the ownership view at once, then hand off
            info = ShardInfo.from_token_key(key)
            if info is not None and self.ownership.update(info, alive):
                log.info("shard %s %s; live: %s", info.shard_id, "joined" if alive else "left",
                         sorted(self.ownership.live))  # fmt: skip
                loop.call_soon_threadsafe(self._schedule_reconcile)

        self.bus.watch_liveliness(SEL_SHARD_TOKENS, on_token)
        data = self.data
        if data is not None:  # which devices have tokens: a shard beside others subscribes to its own ones' data

            def on_device_token(key: str, alive: bool) -> None:  # bus thread: hand off
                loop.call_soon_threadsafe(data.token, key, alive)

            self.bus.watch_liveliness(schemas.SEL_DEVICE_TOKENS, on_device_token)
        self.bus.declare_token(self.info.token_key)
        await self.reconcile()

    # -- ownership changes ------------------------------------------------------------------------------------

    def _schedule_reconcile(self) -> None:
        if not self._reconcile_pending:
            self._reconcile_pending = True
            asyncio.get_running_loop().create_task(self.reconcile())

    async def reconcile(self) -> None:
        """Bring the service's state in line with the current ownership (on the event loop): the devices whose owner
        changed since the last call (between the live set then and now) move."""
        self._reconcile_pending = False
        sv = self.service
        assert sv is not None
        pl, me = sv.pipeline, self.shard_id
        before, now_live = self._reconciled_live, self.ownership.live
        self._reconciled_live = now_live
        moved = [d for d in pl.kinds if owner_of(d, before.values()) != owner_of(d, now_live.values())]
        lost = [d for d in moved if owner_of(d, before.values()) == me]
        gained = {d for d in moved if owner_of(d, now_live.values()) == me}

        def hand_over() -> None:  # an owner command: the ingest task alone changes the pipeline and the engine
            if moved:
                sv.config_changed()  # gw/config answers for the devices served here only
            for d in lost:
                pl.restart(d)  # if it comes back, it starts from a fresh warm-up
                pl.engine.release(d)
            for a in pl.engine.active():  # e.g. loaded from the store at start, raised by another shard
                if not self.ownership.owns(a.device_id):
                    pl.engine.release(a.device_id)

        await sv.call(hand_over)
        if self.data is not None:
            self.data.set_mode(alone=self.alone())
        if gained:
            t = time.time()
            self.takeovers = (self.takeovers + [(t, d) for d in sorted(gained)])[-1000:]
            rows = await asyncio.to_thread(sv.store.active_alarms)  # a read: the writer thread is for writes
            await sv.call(lambda: pl.engine.resume(
                a for a in rows if a.device_id in gained and self.ownership.owns(a.device_id)))

    def alone(self) -> bool:
        """No other live shard could serve a device this one serves (then the catch-all subscriptions carry
        only this shard's devices' data)."""
        return not any(may_overlap(self.info, s) for sid, s in self.ownership.live.items() if sid != self.shard_id)

    # -- alarm history ----------------------------------------------------------------------------------------

    def _put_block(self, key: str, payload: bytes) -> None:
        """A BLOCK put through the hub's publisher thread when it has one: never on the event loop (a stalled
        subscriber must not stall ingest)."""
        publisher = self.service.hub.publisher if self.service is not None else None
        if publisher is not None:
            publisher.put(key, payload, schemas.ENCODING_GW)
        else:
            self.bus.put(key, payload, encoding=schemas.ENCODING_GW, block=True, express=True)

    def _publish_row(self, alarm: Alarm) -> None:
        self._put_block(self.key("alarm_row"), alarm_to_json(alarm))

    def _on_row(self, key: str, payload: bytes) -> None:  # bus thread
        if key == self.key("alarm_row") or self._loop is None or self.writer is None:
            return
        alarm = alarm_from_json(payload)
        self._loop.call_soon_threadsafe(self.writer.store_only, alarm)

    # -- the other shards' outputs for this shard's listeners (dashboard) -------------------------------------

    def _on_output(self, key: str, payload: bytes) -> None:  # bus thread: filter, throttle, hand off
        parts = key.split("/")
        if len(parts) != 4 or self._loop is None or self.ownership.owns(parts[2]):
            return  # this shard's own outputs reach its listeners through its hub
        if parts[3] != "alarm":
            hz = self.settings.shard_mirror_hz
            now = time.monotonic()
            if hz <= 0.0 or now - self._mirror_last.get(key, -math.inf) < 1.0 / hz:
                return
            self._mirror_last[key] = now
        self._mirrored.append((parts[3], payload))
        if not self._mirror_wake:
            self._mirror_wake = True
            self._loop.call_soon_threadsafe(self._feed_listeners)

    def update_mirror(self) -> bool:
        """Subscribe to the other shards' attitude and swing outputs while `mirror_demand()` holds and another shard
        is live, unsubscribe otherwise (event loop); True while subscribed."""
        want = len(self.ownership.live) > 1 and self.mirror_demand()
        if want and not self._mirror_unsubs:
            self._mirror_unsubs = [self.bus.subscribe(sel, self._on_output) for sel in MIRRORED_ON_DEMAND]
            log.info("mirroring the other shards' attitude and swing (a 3-D view client is connected)")
        elif not want and self._mirror_unsubs:
            self._drop_mirror()
        return bool(self._mirror_unsubs)

    def _drop_mirror(self) -> None:
        for unsubscribe in self._mirror_unsubs:
            unsubscribe()
        self._mirror_unsubs = []
        self._mirror_last.clear()

    async def _mirror_loop(self) -> None:
        while True:
            try:
                self.update_mirror()
            except Exception:
                log.exception("mirror subscription update failed")
            await asyncio.sleep(MIRROR_CHECK_S)

    async def stop(self) -> None:
        """Stop the mirror task and drop the mirror subscriptions (before the bus closes)."""
        if self._mirror_task is not None:
            self._mirror_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._mirror_task
            self._mirror_task = None
        self._drop_mirror()
        if self.data is not None:
            await self.data.stop()

    def _feed_listeners(self) -> None:
        self._mirror_wake = False
        assert self.service is not None
        hub = self.service.hub
        while self._mirrored:
            topic, payload = self._mirrored.popleft()
            try:
                model = MIRROR_MODELS[topic].model_validate_json(payload)
            except ValueError:
                continue
            for cb in hub.listeners_of(topic):
                try:
                    cb(topic, model)
                except Exception:
                    log.exception("listener failed on a mirrored %s", topic)

    # -- configuration ----------------------------------------------------------------------------------------

    def _config_message(self) -> bytes:
        assert self.service is not None
        return json.dumps({"origin": self.shard_id, "started_s": self.started_s, "version_us": self.config_version_us,
                           "config": config_snapshot(self.service)}).encode()  # fmt: skip

    def publish_config(self) -> None:
        """After a REST change on this shard (on the event loop): send the whole configuration to the others."""
        self.config_version_us = time.time_ns() // 1000
        self._put_block(self.key("config"), self._config_message())

    def _on_config(self, key: str, payload: bytes) -> None:  # bus thread
        if key == self.key("config") or self._loop is None:
            return
        msg = json.loads(payload)
        asyncio.run_coroutine_threadsafe(self.apply_config(msg), self._loop)

    async def _adopt_config(self, wait_s: float) -> None:
        """Apply the configuration of the longest-running live shard that started before this one, if any; with
        `wait_s`, keep asking that long until one answers (a local shard waits for its parent)."""
        deadline = time.monotonic() + wait_s
        while True:
            replies = await asyncio.to_thread(query, self.bus, "gw/shard/*/config", QUERY_TIMEOUT_S)
            older = [m for _, p in replies if (m := json.loads(p))["origin"] != self.shard_id
                     and m["started_s"] < self.started_s]  # fmt: skip
            if older:
                await self.apply_config(min(older, key=lambda m: m["started_s"]))
                return
            if time.monotonic() >= deadline:
                return
            await asyncio.sleep(0.2)

    async def apply_config(self, msg: dict[str, Any]) -> None:
        """Apply and persist another shard's configuration snapshot (what differs only)."""
        sv = self.service
        assert sv is not None
        snap, pl = msg["config"], sv.pipeline
        async with sv.config_lock:
            for kind, values in snap["defaults"].items():
                model = THRESHOLD_MODELS[kind].model_validate(values)
                if pl.defaults.get(kind) != model:
                    try:
                        await sv.call(partial(pl.set_defaults, kind, model))
                    except BadSettings as exc:  # a device override here is stale; the device settings follow
                        log.warning("config from %s: %s defaults not applied: %s", msg["origin"], kind, exc.errors)
                        continue
                    await sv.store_write(partial(Store.save_defaults, kind=kind, thresholds=model))
            for device_id, entry in snap["devices"].items():
                ds = DeviceSettings.model_validate(entry["settings"])
                cur = pl.device_settings.get(device_id)
                if cur is None or cur[1] != ds:
                    await sv.store_write(partial(Store.save_device_settings, device_id=device_id,
                                                 kind=entry["kind"], settings=ds))  # fmt: skip
                    await sv.call(partial(pl.set_device_settings, device_id, entry["kind"], ds))
            for device_id in sorted(set(pl.device_settings) - set(snap["devices"])):
                kind = pl.device_settings[device_id][0]
                await sv.store_write(partial(Store.delete_device_settings, device_id=device_id))

                def forget(device_id: str = device_id, kind: str = kind) -> None:
                    pl.set_device_settings(device_id, kind, DeviceSettings())
                    pl.device_settings.pop(device_id, None)

                await sv.call(forget)
            self.config_version_us = max(self.config_version_us, int(msg["version_us"]))
            await sv.call(sv.config_changed)  # the gw/config queryable's view
        log.info("configuration from shard %s applied", msg["origin"])

    # -- queryables for the REST front ------------------------------------------------------------------------

    def _answer(self, selector: str) -> list[tuple[str, bytes]]:  # bus thread: the loop builds the answer
        parts = selector.split("/")
        if len(parts) < 4 or parts[2] not in (self.shard_id, "*") or self._loop is None:
            return []
        leaf = parts[3:]
        coro: Coroutine[Any, Any, Any]
        if leaf == ["devices"]:
            coro = self._devices()
        elif len(leaf) == 2 and leaf[0] == "device":
            coro = self._device(leaf[1])
        elif leaf == ["stats"]:  # answered here: counters must come back even when the loop is overloaded
            return [(self.key("stats"), json.dumps(self.stats()).encode())]
        elif leaf == ["config"]:
            coro = self._config()
        elif len(leaf) == 4 and leaf[0] == "history":
            coro = self._history(leaf[1], float(leaf[2]), int(leaf[3]))
        elif len(leaf) == 3 and leaf[0] == "history_all":
            coro = self._history_all(float(leaf[1]), int(leaf[2]))
        elif len(leaf) == 2 and leaf[0] == "call" and parts[2] == self.shard_id:  # never on a wildcard
            coro = self.run_call(json.loads(bytes.fromhex(leaf[1])))
            return [(self.key("/".join(leaf)), json.dumps(asyncio.run_coroutine_threadsafe(coro, self._loop)
                                                  .result(CALL_TIMEOUT_S)).encode())]  # fmt: skip
        else:
            return []
        result = asyncio.run_coroutine_threadsafe(coro, self._loop).result(ANSWER_TIMEOUT_S)
        return [] if result is None else [(self.key("/".join(leaf)), json.dumps(result).encode())]

    async def _devices(self) -> list[dict[str, Any]]:
        return self.device_list()

    def device_list(self) -> list[dict[str, Any]]:
        """Views of the devices this shard serves (routes/devices.py's `device_view`)."""
        from gateway.views import device_view

        sv = self.service
        assert sv is not None
        return [{**device_view(sv, d, detail=False), "shard": self.shard_id}
                for d in sorted(sv.pipeline.kinds) if self.ownership.owns(d)]  # fmt: skip

    async def _device(self, device_id: str) -> dict[str, Any] | None:
        from gateway.views import device_view

        sv = self.service
        assert sv is not None
        if device_id not in sv.pipeline.kinds or not self.ownership.owns(device_id):
            return None
        return {**device_view(sv, device_id, detail=True), "shard": self.shard_id}

    async def _history(self, device_id: str, seconds: float, max_points: int) -> dict[str, Any] | None:
        hist = self.history.devices.get(device_id) if self.history is not None else None
        if hist is None or not self.ownership.owns(device_id):
            return None
        return {"device_id": device_id, "bucket_s": hist.bucket_s,
                "series": hist.columns(time.time() - seconds, max_points)}  # fmt: skip

    async def _history_all(self, seconds: float, max_points: int) -> dict[str, Any] | None:
        if self.history is None:
            return None
        since = time.time() - seconds
        return {"devices": {d: h.columns(since, max_points) for d, h in self.history.devices.items()
                            if self.ownership.owns(d)}}  # fmt: skip

    async def run_call(self, req: dict[str, Any]) -> dict[str, Any]:
        """A write another endpoint forwards to the shard that serves the device (gateway/shard/routes.py): a reel
        command, an acknowledgement or a manual clear, run as that endpoint's REST route would run it here, by
        the owner task (`service.call`). The caller checked the token; `who` is its caller's name."""
        from fastapi import HTTPException

        from gateway.api.routes import alarm_clear, alarms, reel

        sv = self.service
        assert sv is not None
        op, who = req.get("op"), str(req.get("who", "api"))[:64]
        try:
            if op == "reel":
                body = await reel.reel(str(req["device_id"]), reel.ReelRequest.model_validate(req["body"]), sv, who)
                async with sv.config_lock:  # the reel mode is configuration: this shard's goes to the others
                    self.publish_config()
            elif op == "ack":
                body = await alarms.ack_alarm(str(req["alarm_id"]), sv, who)
            elif op == "clear":
                body = await alarm_clear.clear_alarm(str(req["alarm_id"]), sv, who)
            else:
                return {"status": 400, "detail": f"unknown call {op!r}"[:200]}
        except HTTPException as exc:
            return {"status": exc.status_code, "detail": exc.detail}
        except (KeyError, ValueError) as exc:
            return {"status": 422, "detail": f"bad forwarded call: {exc}"[:300]}
        return {"status": 200, "body": body}

    async def _config(self) -> dict[str, Any]:
        return json.loads(self._config_message())  # type: ignore[no-any-return]

    def stats(self) -> dict[str, Any]:
        """This shard's ingest counters (as /api/stats) with what its inbox ignored (other shards' devices). Read
        without the event loop (a bus thread may ask): a dict that grew meanwhile is read again."""
        sv = self.service
        assert sv is not None
        for _ in range(10):
            try:
                snap = sv.counters.snapshot(int(time.time() * 1e6)).model_dump()
                break
            except RuntimeError:  # "dictionary changed size during iteration": a new device just arrived
                continue
        else:
            snap = {}
        if sv.inbox is not None:
            snap.update(queue_drops=sv.inbox.drops, offered=sv.inbox.offered, ignored=sv.inbox.ignored,
                        queue_depth=len(sv.inbox))  # fmt: skip
        owned = sum(map(self.ownership.owns, sv.pipeline.kinds))
        snap.update(shard=self.shard_id, patterns=list(self.info.patterns), owned=owned, batches=sv.batches,
                    published=sv.hub.published, unmatched=sv.hub.unmatched, live=sorted(self.ownership.live),
                    takeovers=self.takeovers[-20:])  # fmt: skip
        if self.data is not None:
            snap.update(self.data.stats())
        return snap


def query(bus: Bus, selector: str, timeout_s: float) -> list[tuple[str, bytes]]:
    """Blocking get on the bus (run it in a thread): (key, payload) of every ok reply."""
    if isinstance(bus, ZenohBus):
        out = []
        for r in bus.session.get(selector, timeout=timeout_s):
            if r.ok is not None:
                out.append((str(r.ok.key_expr), r.ok.payload.to_bytes()))
        return out
    if isinstance(bus, MemoryBus):
        return bus.get(selector)
    return []


def zenoh_overrides(settings: Settings) -> dict[str, str]:
    """zenoh config keys a shard sets: a short lease, so a shard whose machine dies (no TCP close) is dropped from
    the live set within `shard_lease_s` (the default lease is 10 s)."""
    lease_ms = int(settings.shard_lease_s * 1000)
    return {"transport/link/tx/lease": str(lease_ms), "transport/link/tx/keep_alive": "4"}


def open_bus(settings: Settings) -> ZenohBus:
    """`ZenohBus.open` with the shard's lease."""
    from gateway.ingest.bus import zenoh_config

    conf = zenoh_config(settings)
    for k, v in zenoh_overrides(settings).items():
        conf.insert_json5(k, v)
    return ZenohBus(zenoh.open(conf))
