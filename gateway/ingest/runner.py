"""The running gateway: bus callbacks -> bounded inbox -> one asyncio task that decodes, sequence-checks, runs the
pipeline on whole batches and hands results to the hub; plus presence, diagnostics and the config queryable.

That ingest task is the ONE owner of the live state (pipeline, alarm engine, counters): everything else sends it
commands (`gateway.ingest.owner.Commands`, run between batches) or reads what it publishes (`config_view` for the
zenoh queryable, which runs on a zenoh thread). A batch is bounded in work (`batch_budget_s` of CPU, by adapting
the number of packets taken) and HTTP requests in flight finish before the next batch, so REST requests and
commands wait about one batch even under overload.

Hand-off (the only work done on zenoh's threads): `Inbox.offer` appends `(key, bytes, arrival_s)` to a deque
and, if no wake-up is pending, schedules one with `loop.call_soon_threadsafe`; a full inbox counts a queue
drop. One wake-up per burst instead of one per packet keeps the event loop's overhead flat under load.
The ingest task drains up to `max_batch` packets at a time, so fusion steps all devices with pending samples
together. A packet that fails to decode is counted by reason, logged (rate-limited) and published on
`gw/diag/rejected` (at most `REJECTED_PER_S` a second); nothing stops the loop.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import gc
import logging
import math
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from gateway import schemas
from gateway.alarm.engine import Alarm, AlarmChange, ChangeKind, Condition, Severity, presence_condition
from gateway.config import Settings
from gateway.hub import Hub
from gateway.ingest.bus import Bus, key_matches
from gateway.ingest.owner import Commands
from gateway.ingest.presence import Presence
from gateway.ingest.stats import IngestCounters
from gateway.ingest.timecheck import ACCEPTED, wall_time_plausible
from gateway.pipeline import AlarmOut, Output, Pipeline, PipelineSettings
from gateway.store import Store

log = logging.getLogger("gateway.ingest")

REJECTED_PER_S = 20
BATCH_FAIL_LOG_S = 10.0
CONFLICT_CLEAR_S = 10.0  # a device_conflict alarm clears this long after the last packet of a second publisher
BATCH_BUDGET_S = 0.25  # CPU seconds of work a batch takes at most (sized on the recent CPU per packet): a request
# that arrives during a batch waits for its end. Smaller batches cost more per packet (per-device work per batch):
# bench.rest_overload at 300 rods on a machine at load ~10, CPU per packet 0.335 / 0.277 / 0.201 / 0.178 ms and
# /api/stats p50 0.46 / 0.80 / 1.29 / 1.06 s at 0.1 / 0.25 / 0.5 / 1.0 s (5.9 s before). 0.25: REST within ~1 s.
MIN_BATCH = 200  # never fewer packets a batch: the cost is paid mostly per device per batch, so small batches
# under overload would process fewer packets, not answer faster
REST_GRACE_S = 0.25  # after a batch, wait up to this long for HTTP requests in flight to finish (gateway.api.priority)
YIELDS_PER_BATCH = 8  # event-loop turns between two batches: a REST request needs several (accept, read, handler,
# write), so one turn per batch made it wait for several batches
Received = tuple[str, bytes, float]
T = TypeVar("T")
GC_GEN0_THRESHOLD = 500_000  # net new container objects before a young collection runs inside a batch (CPython's
# default: 700): never in a batch of the usual sizes, whose live sample tuples are tens of thousands
GC_YOUNG_BETWEEN = 2_000  # net new container objects left after a batch that make `collect_between_batches` run
_gc_tuned = False


def tune_gc() -> None:
    """Make the cyclic garbage collector cheap for ingest; once per process, after the kernels are loaded.

    A batch allocates tens of thousands of short-lived objects (decoded samples are tuples of floats), which with
    CPython's defaults triggered ~20 young and, every few seconds, a full collection that walked the whole heap
    (numba, pydantic and FastAPI included): 30 % of the ingest thread's CPU at 300 devices (bench.pipeline_cost
    --stage ingest). `gc.freeze()` moves what exists after start-up (modules, compiled kernels, schemas) out of
    the collector's walks for good. The young threshold is then set so high that a batch never triggers a
    collection itself (one triggered mid-batch walks every sample tuple still alive in it: 0.7 ms each at a
    threshold of 20,000); the ingest loop collects after each batch instead (`collect_between_batches`), when
    reference counting has freed the batch. That cut the CPU per packet by 6-15 % for batches of 500-1000 devices,
    as a lagging gateway runs them, and changed nothing measurable at 50-300 (`bench.pipeline_cost --stage ingest
    --compare`)."""
    global _gc_tuned
    if _gc_tuned:
        return
    _gc_tuned = True
    gc.collect()
    gc.freeze()
    _, gen1, gen2 = gc.get_threshold()
    gc.set_threshold(GC_GEN0_THRESHOLD, gen1, gen2)


def collect_between_batches() -> None:
    """The young (and, by CPython's own counts, older) collections the default thresholds would have made, at a
    moment the young generation is small: after a batch, once `GC_YOUNG_BETWEEN` new objects outlived batches.
    Garbage cycles are freed as before, so memory stays bounded (tests/gateway/test_runner_gc.py)."""
    young, gen1_count, gen2_count = gc.get_count()
    if young < GC_YOUNG_BETWEEN:
        return
    _, gen1, gen2 = gc.get_threshold()
    generation = 2 if gen2_count >= gen2 and gen1_count >= gen1 else 1 if gen1_count >= gen1 else 0
    gc.collect(generation)


class Inbox:
    """Bounded, thread-safe hand-off from bus threads to the event loop."""

    def __init__(
        self, loop: asyncio.AbstractEventLoop, maxsize: int, accept: Callable[[str], bool] | None = None,
        coalesce_s: float = 0.0,
    ) -> None:  # fmt: skip
        self.loop = loop
        self.maxsize = maxsize
        self.coalesce_s = coalesce_s  # a short batch waits this long after its oldest packet for more (`drain`)
        self.accept = accept  # device id -> served here? (gateway.shard: other shards' devices are not queued)
        self.drops = 0
        self.offered = 0
        self.ignored = 0
        self._items: collections.deque[Received] = collections.deque()
        self._ready = asyncio.Event()
        self._wake_pending = False

    def offer(self, key: str, payload: bytes) -> None:
        """Called on a bus thread: enqueue or count a drop; never blocks."""
        self.offered += 1
        if self.accept is not None:
            parts = key.split("/", 3)  # rig/{kind}/{id}/...
            if len(parts) > 2 and not self.accept(parts[2]):
                self.ignored += 1
                return
        if len(self._items) >= self.maxsize:
            self.drops += 1
            return
        self._items.append((key, payload, time.monotonic()))
        if not self._wake_pending:
            self._wake_pending = True
            self.loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        self._wake_pending = False
        self._ready.set()

    def wake(self) -> None:
        """Make `drain` return (with what is there, maybe nothing): a command is waiting (event loop thread)."""
        self._ready.set()

    async def drain(self, max_n: int) -> list[Received]:
        """Wait for packets (or `wake`), then take up to `max_n` of them (oldest first); fewer than `max_n` wait
        until the oldest is `coalesce_s` old, so a lightly loaded gateway runs a batch per window, not per packet."""
        await self._ready.wait()
        self._ready.clear()
        items = self._items
        if self.coalesce_s > 0.0 and 0 < len(items) < max_n:
            wait_s = items[0][2] + self.coalesce_s - time.monotonic()
            if wait_s > 0.0:
                await asyncio.sleep(wait_s)
        out = [items.popleft() for _ in range(min(max_n, len(items)))]
        if items:
            self._ready.set()
        return out

    def __len__(self) -> int:
        return len(self._items)


def pipeline_settings_from(settings: Settings) -> PipelineSettings:
    """The pipeline options that `Settings` (and so the command line) sets."""
    return PipelineSettings(default_filter=settings.default_filter, attitude_interval_s=settings.attitude_interval_s,
                            attitude_blocks=settings.attitude_blocks, warmup_bias_seed=settings.warmup_bias_seed)


@dataclass(frozen=True)
class ConfigView:
    """What the `gw/config/...` queryable answers from, published by the owner task and never changed afterwards:
    `devices` config key -> DeviceConfig JSON of each known device; `defaults` kind -> its defaults."""

    devices: Mapping[str, bytes]
    defaults: Mapping[str, schemas.DeviceConfig]


def build_pipeline(settings: Settings, store: Store, pipeline_settings: PipelineSettings | None = None) -> Pipeline:
    """The pipeline with what the store holds: kind defaults, device settings, alarms still active."""
    active, _ = store.list_alarms(status="active", limit=1_000_000)
    stored = store.load_device_settings()
    for bad in [d for d in stored if not schemas.valid_device_id(d)]:  # stored by an older gateway's REST
        log.warning("ignoring stored settings of invalid device id %r", bad[:80])
        del stored[bad]
    return Pipeline(
        pipeline_settings or pipeline_settings_from(settings),
        store.load_defaults(), stored, [a for a in active if schemas.valid_device_id(a.device_id)],
    )  # fmt: skip


class GatewayService:
    """Runs ingest: bus subscriptions, presence, counters and the owner task of the pipeline and alarm engine it is
    given (built by `gateway.app.compose`). `start()` on the event loop, `stop()` before closing the bus."""

    def __init__(
        self, settings: Settings, bus: Bus, store: Store, pipeline: Pipeline, hub: Hub,
        max_batch: int = 2000, diag_period_s: float = 1.0, batch_budget_s: float = BATCH_BUDGET_S,
    ) -> None:  # fmt: skip
        self.settings = settings
        self.bus = bus
        self.store = store
        self.max_batch = max_batch
        self.diag_period_s = diag_period_s
        self.batch_budget_s = batch_budget_s
        self.rest_inflight = 0  # HTTP requests running (gateway.api.priority); ingest lets them finish first
        self.rest_remote = 0  # ... of which awaiting another process (`awaiting_remote`): ingest need not wait
        self.rest_grace_s = REST_GRACE_S
        self.pipeline = pipeline
        self.hub = hub
        self.writer = hub.writer
        self.commands = Commands()
        self._s_per_packet = 0.0  # running mean of a batch's CPU time per packet (sizes the next batch)
        self.config_view = ConfigView({}, {})  # what the config queryable answers from (see `refresh_config_view`)
        self._config_dirty = True
        self._config_kinds_seen = -1  # len(pipeline.kinds) at the last refresh (the view lacks other shards' devices)
        self.counters = IngestCounters()
        self.presence = Presence()
        self.started_s = time.time()
        self.batches = 0
        self.batch_delay_s: collections.deque[float] = collections.deque(maxlen=2000)  # oldest arrival -> emitted
        self.config_lock = asyncio.Lock()  # orders REST config writes: store and live state change in one order
        self.inbox: Inbox | None = None
        self._tasks: list[asyncio.Task[Any]] = []
        self._rejected_window = (0, 0)  # (second, published in it)
        self.batch_failures = 0
        self._batch_fail_logged_s = -math.inf
        self.warming_since_s: float | None = None  # set while the fusion kernels are being prepared
        # Sharding hooks (gateway.shard, set before start): does this process serve a device id (None: all), and
        # the key expressions of device data it subscribes to.
        self.accept: Callable[[str], bool] | None = None
        self.data_selectors: tuple[str, ...] = schemas.SEL_DEVICE_DATA
        # given the inbox's `offer` at start, subscribes the device data itself (gateway.shard: per device beside
        # other shards); None: the catch-all `data_selectors`
        self.subscribe_data: Callable[[Callable[[str, bytes], None]], None] | None = None

    async def start(self, warm_up: bool = False) -> None:
        """Subscribe, watch presence, serve the config queryable and start the tasks. With `warm_up` the ingest
        task first compiles the fusion kernels (`Pipeline.warm_up`, in a thread): REST and presence work at once,
        packets wait in the inbox meanwhile (a restart answers in seconds; a cold first compile shows in /health)."""
        self.warming_since_s = time.time() if warm_up else None
        loop = asyncio.get_running_loop()
        self.inbox = Inbox(loop, self.settings.ingest_queue_size, self.accept, self.settings.ingest_coalesce_s)
        self.commands.on_post = self.inbox.wake
        if self.subscribe_data is not None:
            self.subscribe_data(self.inbox.offer)
        else:
            for sel in self.data_selectors:
                self.bus.subscribe(sel, self.inbox.offer)

        def on_token(key: str, alive: bool) -> None:  # bus thread: hand off only (a command for the owner)
            loop.call_soon_threadsafe(self.commands.post, lambda: self._on_presence(key, alive))

        self.bus.watch_liveliness(schemas.SEL_DEVICE_TOKENS, on_token)
        self.refresh_config_view()  # answers at once, also while the kernels warm up
        self.bus.declare_queryable(schemas.SEL_GW_CONFIG, self.config_replies, encoding=schemas.ENCODING_GW)
        self.bus.declare_token(schemas.GW_ALIVE_KEY)
        self._tasks = [asyncio.create_task(self._ingest_loop()), asyncio.create_task(self._diag_loop()),
                       asyncio.create_task(self._reel_loop())]  # fmt: skip

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            try:
                await t
            except (asyncio.CancelledError, Exception):
                pass
        self._tasks = []
        self.commands.cancel_pending()
        if self.hub.publisher is not None:
            await asyncio.to_thread(self.hub.publisher.close)  # make the queued BLOCK puts (bounded wait)
        await asyncio.to_thread(self.writer.close)  # store what is pending (bounded wait), stop the thread

    # -- ingest ---------------------------------------------------------------------------------------------

    async def call(self, fn: Callable[[], T]) -> T:
        """Run `fn` on the owner (ingest) task between batches and return its result: how REST handlers and timers
        change the pipeline, the alarm engine or the counters."""
        return await self.commands.call(fn)

    async def store_write(self, op: Callable[[Store], T]) -> T:
        """Run a store write on the one writer thread (`StoreWriter.call`) and await its result; raises its error."""
        return await asyncio.wrap_future(self.writer.call(op))

    def acknowledge_alarm(self, alarm_id: str, by: str, now_s: float) -> Alarm | None:
        """Owner command: acknowledge an alarm the engine holds, publish it (`state: acknowledged`) and project it
        to the store; None if the engine holds no unacknowledged alarm with this id."""
        change = self.pipeline.engine.acknowledge(alarm_id, by, now_s)
        if change is None:
            return None
        self._emit_alarm(change, now_s)
        return change.alarm

    def clear_alarm(self, alarm_id: str, by: str, now_s: float) -> Alarm | None:
        """Owner command: clear an active alarm by hand through the engine, publish and store it; None if the engine
        holds no active alarm with this id."""
        change = self.pipeline.engine.clear(alarm_id, by, now_s)
        if change is None:
            return None
        self._emit_alarm(change, now_s)
        return change.alarm

    def publish_stored_alarm(self, kind: ChangeKind, alarm: Alarm, now_s: float) -> None:
        """Owner command for an alarm only the store still has (cleared, or active from before a restart and never
        resumed by a rule): publish its change and store the row, as for an engine change."""
        self._emit_alarm(AlarmChange(kind, alarm), now_s)

    def _emit_alarm(self, change: AlarmChange, now_s: float) -> None:
        kind = self.pipeline.kinds.get(change.alarm.device_id, "rod")
        self.hub.emit(Output(alarms=[AlarmOut(kind, change, int(now_s * 1e6), None)]))

    async def _ingest_loop(self) -> None:
        assert self.inbox is not None
        self.commands.owner = asyncio.current_task()
        if self.warming_since_s is not None:
            log.info("preparing fusion kernels (the first start after install compiles them: up to a minute)")
            t0 = time.perf_counter()
            warm = asyncio.ensure_future(asyncio.to_thread(self.pipeline.warm_up))
            while not warm.done():  # commands (REST writes, presence) run meanwhile; packets wait in the inbox
                waiter = asyncio.ensure_future(self.commands.pending.wait())
                await asyncio.wait({warm, waiter}, return_when=asyncio.FIRST_COMPLETED)
                waiter.cancel()
                self.commands.run_pending()
                self.refresh_config_view()
            try:
                warm.result()
                log.info("fusion kernels ready in %.1f s", time.perf_counter() - t0)
            except Exception:  # the first packets will compile what is missing
                log.exception("fusion kernel warm-up failed")
            self.warming_since_s = None
        tune_gc()
        while True:
            items = await self.inbox.drain(self.batch_limit())
            self.commands.run_pending()
            if items:
                t0 = time.thread_time()  # CPU of this thread: the batch's work, not the machine's other load
                try:
                    self.handle(items)
                except Exception:  # a pipeline bug must not stop ingest; one traceback per BATCH_FAIL_LOG_S
                    self.batch_failures += 1
                    now = time.monotonic()
                    if now - self._batch_fail_logged_s >= BATCH_FAIL_LOG_S:
                        self._batch_fail_logged_s = now
                        log.exception("batch of %d packets failed (%d batches failed so far)", len(items),
                                      self.batch_failures)  # fmt: skip
                collect_between_batches()
                per_packet = (time.thread_time() - t0) / len(items)
                mean = self._s_per_packet
                self._s_per_packet = per_packet if not mean else 0.8 * mean + 0.2 * per_packet
            self.refresh_config_view()
            for _ in range(YIELDS_PER_BATCH if items else 1):  # let REST handlers in between batches
                await asyncio.sleep(0)
            if self.rest_inflight > self.rest_remote:
                await self._let_rest_finish()

    async def _let_rest_finish(self) -> None:
        """HTTP requests are running: run their commands and give them the loop until they are done (at most
        `rest_grace_s`), so a request waits for about one batch, not several. Requests awaiting another process
        (`awaiting_remote`) are not waited for: the loop cannot speed them up."""
        deadline = time.monotonic() + self.rest_grace_s
        while self.rest_inflight > self.rest_remote and time.monotonic() < deadline:
            self.commands.run_pending()
            await asyncio.sleep(0.001)
        self.commands.run_pending()

    @contextlib.contextmanager
    def awaiting_remote(self) -> Iterator[None]:
        """Around an HTTP request's wait for another process (a shard's zenoh answer): ingest goes on meanwhile.

        Why: with two shards, the REST front's `/api/stats` waits for the other shard's answer, which comes between
        that shard's batches (up to ~0.5 s under load). Ingest held its next batch for it (`rest_grace_s`, 0.25 s)
        at every probe: at 1000 devices the front's shard idled a third of the time and fell seconds behind."""
        self.rest_remote += 1
        try:
            yield
        finally:
            self.rest_remote -= 1

    def batch_limit(self) -> int:
        """Packets to take next: what fits in `batch_budget_s` at the recent cost per packet, within
        [MIN_BATCH, max_batch] (bigger batches are cheaper per packet, but REST waits for the batch to end)."""
        if self._s_per_packet <= 0.0:  # no estimate yet: a small first batch
            return min(MIN_BATCH, self.max_batch)
        return max(min(MIN_BATCH, self.max_batch), min(self.max_batch, int(self.batch_budget_s / self._s_per_packet)))

    def handle(self, items: list[Received], now_wall_s: float | None = None) -> None:
        """Decode, sequence-check and process one batch; publish what it produced."""
        now = time.time() if now_wall_s is None else now_wall_s
        c = self.counters
        c.received += len(items)
        if self.inbox is not None:
            c.queue_drops = self.inbox.drops
        packets: list[schemas.Packet] = []
        decoded = schemas.decode_many([(key, payload) for key, payload, _ in items])  # binary IMU: batched
        max_devices = self.settings.max_devices
        for (key, payload, arrival), p in zip(items, decoded, strict=True):
            if isinstance(p, schemas.DecodeError):
                c.reject(key, p, arrival)
                self._publish_rejected(key, p, len(payload), now)
                continue
            if p.device_id not in c.devices and len(c.devices) >= max_devices:  # type: ignore[union-attr]
                self._device_limit(p.device_id, arrival)  # type: ignore[union-attr]
                continue
            topic = key.rsplit("/", 1)[-1]
            if not c.accept(p.kind, p.device_id, topic, p.boot_id, p.seq, arrival):  # type: ignore[union-attr]
                continue
            if isinstance(p, schemas.ImuPacket):
                checked = self._check_time(p, now, arrival)
                if checked is None:
                    continue
                p = checked
            elif isinstance(p, schemas.CraneMotion) and not wall_time_plausible(p.wall_t0_us, now):
                # a crane feed is put beside the hook's samples by wall time: without a sane one it is nothing
                c.drop(p.kind, p.device_id, "crane_wall_time", f"wall_t0_us {p.wall_t0_us} is far from the gateway's "
                       "clock; the crane feed is aligned by it, so the packet is dropped", arrival)  # fmt: skip
                continue
            elif isinstance(p, schemas.EnvPacket | schemas.ReelStatus) and p.wall_t_us is not None \
                    and not wall_time_plausible(p.wall_t_us, now):  # fmt: skip
                # e.g. 2**63 - 1 would stay the spot's "newest" reading for good
                c.drop(p.kind, p.device_id, "wall_time_ignored", f"wall_t_us {p.wall_t_us} is far from the gateway's "
                       "clock; the packet is used without it", arrival)  # fmt: skip
                p = p.model_copy(update={"wall_t_us": None})
            packets.append(p)
        if c.conflicts_seen:
            self._raise_conflicts(now)
        if packets:
            self.batches += 1
            out = self.pipeline.process(packets, now)
            for f in out.filter_failures:
                c.filter_failed(f.kind, f.device_id, f.reason, f.detail, items[-1][2])
            for kind, device_id, gap_s in out.time_gaps:
                c.drop(kind, device_id, "time_gap_bridged", f"seq follows on but t0_us is {1e3 * gap_s:.0f} ms of "
                       "samples late: taken as samples lost in the device and bridged (see docs/protocol.md 3.1)",
                       items[-1][2])  # fmt: skip
            self.hub.emit(out)
            self.hub.emit_packets(packets)
            self.batch_delay_s.append(time.monotonic() - items[0][2])

    def _check_time(self, p: schemas.ImuPacket, now: float, arrival: float) -> schemas.ImuPacket | None:
        """Device-time sanity (`gateway.ingest.timecheck`): None drops the packet; counted by reason either way. A
        packet kept gets the sample rate its device's `t0_us` show when the declared one is off
        (`ingest.samplerate`)."""
        c = self.counters
        stream = c.devices.get(p.device_id) or c.stream(p.kind, p.device_id)  # (known: `accept` saw the packet)
        n = p.n
        end_us = p.t0_us + round((n - 1) * 1e6 / p.rate_hz)
        verdict = stream.clock.check(p.boot_id, p.t0_us, end_us)
        if verdict is not ACCEPTED:  # nearly every packet is on its device's timeline
            if not verdict.accept:
                c.drop(p.kind, p.device_id, verdict.reason or "", f"t0_us {p.t0_us} (boot {p.boot_id}, seq {p.seq})",
                       arrival)  # fmt: skip
                return None
            if verdict.restart:
                c.drop(p.kind, p.device_id, "time_resync", f"device clock moved to t0_us {p.t0_us}; fusion restarts",
                       arrival)  # fmt: skip
                self.pipeline.restart(p.device_id)
        if p.wall_t0_us is not None and not wall_time_plausible(p.wall_t0_us, now):
            c.drop(p.kind, p.device_id, "wall_time_ignored", f"wall_t0_us {p.wall_t0_us} is far from the gateway's "
                   "clock; the packet is used without it", arrival)  # fmt: skip
            p = p.model_copy(update={"wall_t0_us": None})
        meter, used_before = stream.rate, stream.rate.used_hz
        rate_hz = meter.update(p.boot_id, p.seq, p.t0_us, n, p.rate_hz)
        if meter.used_hz != used_before:
            if used_before is None:
                c.drop(p.kind, p.device_id, "rate_hz_measured", f"declares rate_hz {p.rate_hz:g} but its t0_us advance "
                       f"at {rate_hz:.4f} samples/s over {meter.evidence_s:.0f} s; fused at the measured rate", arrival)
            else:
                c.log.warning(f"rate:{p.device_id}", f"device {p.device_id}: sample rate now "
                              f"{rate_hz:.4f} Hz (declared {p.rate_hz:g})", arrival)  # fmt: skip
        if rate_hz != p.rate_hz:
            p = p.model_copy(update={"rate_hz": rate_hz})
        return p

    def _raise_conflicts(self, now: float) -> None:
        """A `device_conflict` alarm for each device that just showed a second publisher (it clears in
        `_clear_conflicts` once `CONFLICT_CLEAR_S` pass without one)."""
        out = Output()
        for device_id in sorted(self.counters.conflicts_seen):
            kind = self.counters.devices[device_id].kind
            cond = Condition(device_id, "device_conflict", Severity.CRITICAL, now, value=1.0, message=(
                f"two publishers on {kind} {device_id}'s keys: spoofing or a duplicated device id; its data may "
                "be mixed (see docs/security.md)"))  # fmt: skip
            t_us = self._device_t_us(device_id)
            out.alarms += [AlarmOut(kind, ch, t_us, None) for ch in self.pipeline.engine.evaluate([cond])]
        self.counters.conflicts_seen.clear()
        if out.alarms:
            self.hub.emit(out)

    def _clear_conflicts(self, now: float, mono: float) -> None:
        out = Output()
        for a in self.pipeline.engine.active():
            if a.type != "device_conflict":
                continue
            dev = self.counters.devices.get(a.device_id)
            last = None if dev is None else dev.conflict_last_s
            if last is None or mono - last >= CONFLICT_CLEAR_S:
                kind = dev.kind if dev is not None else self.pipeline.kinds.get(a.device_id, "rod")
                cond = Condition(a.device_id, "device_conflict", None, now)
                out.alarms += [AlarmOut(kind, ch, self._device_t_us(a.device_id), None)
                               for ch in self.pipeline.engine.evaluate([cond])]  # fmt: skip
        if out.alarms:
            self.hub.emit(out)

    def _device_t_us(self, device_id: str) -> int:
        dev = self.pipeline.devices.get(device_id)
        return dev.t_us if dev is not None else 0

    def _publish_rejected(self, key: str, err: schemas.DecodeError, size: int, now: float) -> None:
        second, n = self._rejected_window
        if int(now) != second:
            second, n = int(now), 0
        if n < REJECTED_PER_S:
            msg = schemas.RejectedPacket(wall_t_us=int(now * 1e6), key=key[:300], reason=err.reason,
                                         detail=err.detail[:500], size_bytes=size)  # fmt: skip
            self.hub.put_diag(schemas.T_DIAG_REJECTED, msg)  # BLOCK: rate-bounded, so a reader loses none
        self._rejected_window = (second, n + 1)

    def _diag_tick(self) -> bytes:
        """Owner command of the diagnostics timer: clear stale conflicts, snapshot the counters."""
        if self.inbox is not None:
            self.counters.queue_drops = self.inbox.drops
        self._clear_conflicts(time.time(), time.monotonic())
        return self.counters.snapshot(int(time.time() * 1e6)).to_json()

    async def _diag_loop(self) -> None:
        while True:
            await asyncio.sleep(self.diag_period_s)
            try:
                stats = await self.call(self._diag_tick)
                self.bus.put(schemas.DIAG_INGEST_KEY, stats, encoding=schemas.ENCODING_GW)
            except Exception:
                log.exception("diagnostics publish failed")

    async def _reel_loop(self) -> None:
        """Reel watchdog: tick the auto-reel controllers every `reel_watchdog_s` on the gateway's wall clock (the one
        `handle` gives the pipeline), so a rod whose packets stop gets a stop (`Pipeline.tick_reel`)."""
        while True:
            await asyncio.sleep(self.pipeline.settings.reel_watchdog_s)
            try:
                await self.call(lambda: self._emit_reel(self.pipeline.tick_reel(time.time())))
            except Exception:
                log.exception("reel watchdog tick failed")

    def _emit_reel(self, out: Output) -> None:
        """Publish reel safety stops (BLOCK, via the hub) and record their events in the store's event log (only for
        rods this shard serves: every shard holds every rod's auto-reel setting)."""
        if self.accept is not None:
            ok = self.accept
            out.reel_commands = [c for c in out.reel_commands if ok(c[0])]
            out.reel_events = [e for e in out.reel_events if ok(e.device_id)]
        if out.reel_commands:
            self.hub.emit(out)
        for e in out.reel_events:
            log.warning("rod %s: %s, reel stop sent", e.device_id, e.kind)
            self.writer.log_event(e.t_s, e.kind, e.device_id, e.details)

    # -- presence and config --------------------------------------------------------------------------------

    def _device_limit(self, device_id: str, now_s: float) -> None:
        """A new device id beyond `max_devices`: counted and logged (rate-limited), never given state."""
        self.counters.rejected["device_limit"] += 1
        self.counters.log.warning("device_limit", f"new device {device_id[:64]!r} ignored: already "
                                  f"{self.settings.max_devices} devices (--max-devices)", now_s)  # fmt: skip

    def _on_presence(self, key: str, alive: bool) -> None:
        parts = key.split("/")
        if (len(parts) == 3 and parts[2] not in self.presence.devices
                and len(self.presence.devices) >= self.settings.max_devices):  # fmt: skip
            self._device_limit(parts[2], time.monotonic())
            return
        change = self.presence.update(key, alive, time.time())
        if change is None:
            return
        self.pipeline.kinds.setdefault(change.device_id, change.kind)
        if self.accept is not None and not self.accept(change.device_id):  # its shard logs it and raises offline
            return
        log.info("device %s %s", change.device_id, "online" if alive else "offline")
        self.writer.log_event(change.since_s, "online" if alive else "offline", change.device_id, {"kind": change.kind})
        if not alive:
            self._emit_reel(self.pipeline.reel_offline(change.device_id, change.since_s))
        # device-offline alarm: raised when the token goes, cleared when it is back (one row per outage)
        cond = presence_condition(change.device_id, alive, change.since_s)
        t_us = int(change.since_s * 1e6)
        alarms = [AlarmOut(change.kind, c, t_us, None) for c in self.pipeline.engine.evaluate([cond])]
        if alarms:
            try:
                self.hub.emit(Output(alarms=alarms))
            except Exception:
                log.exception("offline alarm publish failed")

    def device_config(self, kind: str, device_id: str) -> schemas.DeviceConfig:
        """Current thresholds of a device (the kind defaults when it has no override)."""
        _, th = self.pipeline.effective(kind, device_id)
        values = {k: float(v) for k, v in th.model_dump().items() if isinstance(v, int | float)}
        return schemas.DeviceConfig(device_id=device_id, kind=kind, thresholds=values)  # type: ignore[arg-type]

    def config_changed(self) -> None:
        """Owner: settings or defaults changed; `config_view` is rebuilt now, so a REST write that returned is already
        what the queryable answers (the owner may run commands and yield to REST before its next batch)."""
        self._config_dirty = True
        self.refresh_config_view()

    def refresh_config_view(self) -> None:
        """Owner, after each batch: publish a new `config_view` if devices appeared or settings changed (a new dict
        each time, so the queryable's thread always reads a whole one)."""
        view, kinds = self.config_view, self.pipeline.kinds
        if not self._config_dirty and len(kinds) == self._config_kinds_seen:
            return
        devices = {} if self._config_dirty else dict(view.devices)
        for device_id, kind in list(kinds.items()):
            if self.accept is not None and not self.accept(device_id):  # its own shard answers
                continue
            key = schemas.config_key(kind, device_id)
            if key not in devices:
                devices[key] = self.device_config(kind, device_id).to_json()
        defaults = view.defaults if view.defaults and not self._config_dirty else {
            kind: self.device_config(kind, "defaults") for kind in schemas.KINDS}  # fmt: skip
        self._config_dirty = False
        self._config_kinds_seen = len(kinds)
        self.config_view = ConfigView(devices, defaults)

    def config_replies(self, selector: str) -> list[tuple[str, bytes]]:
        """Replies of the `gw/config/{kind}/{id}` queryable (a zenoh thread: reads the owner's `config_view` only):
        one per known device matching the selector; an unknown concrete device gets its kind's defaults."""
        parts = selector.split("/")
        view = self.config_view
        out = [(key, payload) for key, payload in view.devices.items() if key_matches(selector, key)]
        if not out and len(parts) == 4 and parts[2] in view.defaults and "*" not in selector:
            if schemas.valid_device_id(parts[3]):
                config = view.defaults[parts[2]].model_copy(update={"device_id": parts[3]})
                out.append((selector, config.to_json()))
        return out
