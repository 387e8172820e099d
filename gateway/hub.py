"""Fan-out of pipeline results: zenoh outputs, the store (alarm history, through the `StoreWriter` thread), and
in-process sinks (dashboard history and live stream, metrics, 3-D view), wired in `gateway.app`.

Alarms (raised, cleared and acknowledged), reel commands, hook swing (at most 20 Hz per hook) and (opt-in) attitude
blocks are published with CongestionControl.BLOCK, through the `BlockingPublisher` thread so a slow subscriber
never stalls ingest; attitude and height with DROP (a newer sample follows shortly), coalesced to the newest per
device per batch, and only while a subscriber takes their key (zenoh's matching status, `Bus.subscribed`): with
none, such a message is neither encoded nor put (at 1000 devices the heights nobody read were a put per packet).
Sinks get the typed outputs (`listeners`) and the decoded, accepted device packets (`packet_listeners`): nothing
downstream parses a payload again."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

from gateway import schemas
from gateway.alarm.engine import Alarm
from gateway.ingest.bus import Bus
from gateway.ingest.publisher import BlockingPublisher
from gateway.pipeline import AlarmOut, Output
from gateway.store import StoreWriter
from gateway.views import PlotBatch

log = logging.getLogger("gateway.hub")

Listener = Callable[[str, schemas.WireModel], None]
"""(topic, model): topic is `attitude`, `attitude_block`, `swing`, `height`, `alarm`, `spots` or `reel_cmd`."""
PlotListener = Callable[[PlotBatch], None]
"""The dashboard points (`gateway.views.plot_point`) of the attitudes and swings one `emit` published, computed once
for every such sink (history, live stream): a sequence of points, and their values in columns."""
PacketListener = Callable[[schemas.Packet], None]
"""A decoded device packet the ingest task accepted (after sequence and time checks), before the pipeline."""


_L = TypeVar("_L", bound=Callable[..., None])


def listens_to(*topics: str) -> Callable[[_L], _L]:
    """Mark a `Listener` (function or method) as wanting only these topics: the hub then skips the call for any
    other, decided once per batch and topic (the heights, a put per device per batch, go to no listener)."""

    def mark(fn: _L) -> _L:
        fn.topics = frozenset(topics)  # type: ignore[attr-defined]
        return fn

    return mark


def wants(listener: Listener, topic: str) -> bool:
    """Whether `listener` takes messages of `topic` (`listens_to`; unmarked listeners take every topic)."""
    topics: frozenset[str] | None = getattr(listener, "topics", None)
    return topics is None or topic in topics


_Dev = schemas.Attitude | schemas.AttitudeBlock | schemas.Swing | schemas.Height  # a device's own output message
MAX_KEYS = 100_000  # cached output keys (a few topics per device)
STATE_OF_CHANGE = {"raised": "raised", "updated": "raised", "cleared": "cleared", "acknowledged": "acknowledged"}


def alarm_event(out: AlarmOut, now_us: int) -> schemas.AlarmEvent:
    """Wire event of an engine change: raised/updated -> `raised` (with the current severity), cleared -> `cleared`,
    acknowledged -> `acknowledged` (the message names who acknowledged it).

    `alarm_id` and `severity` are the engine's (= the store's) own; `t_us` is device time, `wall_t_us` = `now_us`.
    """
    a: Alarm = out.change.alarm
    return schemas.AlarmEvent(
        alarm_id=a.id, device_id=a.device_id, kind=out.kind, alarm=a.type,  # type: ignore[arg-type]
        state=STATE_OF_CHANGE[out.change.kind], severity=a.severity.value,  # type: ignore[arg-type]
        t_us=out.t_us, wall_t_us=now_us, source_wall_us=out.source_wall_us, value=a.value, threshold=a.threshold,
        message=(a.message if out.change.kind != "acknowledged" else f"acknowledged by {a.acknowledged_by}")[:500],
    )  # fmt: skip


class Hub:
    """Publishes and persists one `Output` at a time; `listeners` get every published model too. BLOCK puts go
    through `publisher` (a thread) when given, else straight to the bus (tests on a MemoryBus)."""

    def __init__(
        self, bus: Bus, writer: StoreWriter, publisher: BlockingPublisher | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:  # fmt: skip
        self.bus = bus
        self.writer = writer
        self.publisher = publisher
        self.clock = clock
        self.listeners: list[Listener] = []
        self.plot_listeners: list[PlotListener] = []
        self.packet_listeners: list[PacketListener] = []
        self._cmd_ids = itertools.count(int(clock()) % 1_000_000 * 1000)
        self.published = 0
        self.unmatched = 0  # DROP messages no subscriber took, so neither encoded nor put (`_put`)
        self._subscribed = getattr(bus, "subscribed", None)  # a bus that cannot tell: every message is put
        self._keys: dict[tuple[str, str | None, str | None], str] = {}  # built and checked once per device and topic

    def put_diag(self, topic: schemas.Topic, model: schemas.WireModel) -> None:
        """Publish a gateway-wide diagnostics message with its topic's congestion control (BLOCK through the publisher
        thread), without the listeners (they take device outputs)."""
        self._send(topic.key(), model.to_json(), topic)

    def _send(self, key: str, payload: bytes, topic: schemas.Topic) -> None:
        if topic.block and self.publisher is not None:
            self.publisher.put(key, payload, topic.encoding, topic.express)
        else:
            self.bus.put(key, payload, encoding=topic.encoding, block=topic.block, express=topic.express)

    def listeners_of(self, topic: str) -> list[Listener]:
        """The listeners that take `topic` (`listens_to`), in registration order."""
        return [cb for cb in self.listeners if wants(cb, topic)]

    def _key(self, topic: schemas.Topic, kind: str | None, device_id: str | None) -> str:
        key = self._keys.get((topic.name, kind, device_id))
        if key is None:
            if len(self._keys) >= MAX_KEYS:  # devices come and go: start over rather than grow for good
                self._keys.clear()
            key = self._keys[(topic.name, kind, device_id)] = topic.key(kind, device_id)
        return key

    def taker(self, topic: schemas.Topic) -> Callable[[str, str], bool] | None:
        """`takes` of one topic with what does not depend on the device decided once: None when every message of
        it reaches someone (a BLOCK topic, a listener of it, a bus that cannot tell), else `(kind, device_id) ->
        bool` asking only the key's matching status. The pipeline asks it once per batch before making the
        messages only a subscriber reads (heights), so a gateway nobody reads them from does not make them."""
        subscribed = self._subscribed
        if topic.block or subscribed is None or any(wants(cb, topic.name) for cb in self.listeners):
            return None
        key, encoding, express = self._key, topic.encoding, topic.express
        return lambda kind, device_id: bool(subscribed(key(topic, kind, device_id), encoding=encoding,
                                                       express=express))  # fmt: skip

    def takes(self, topic: schemas.Topic, kind: str, device_id: str) -> bool:
        """Whether a message of `topic` from this device would reach anyone now: a listener of the topic, a
        subscriber of its key, or any BLOCK topic (always put)."""
        taker = self.taker(topic)
        return taker is None or taker(kind, device_id)

    def _put(self, topic: schemas.Topic, model: schemas.WireModel, kind: str | None = None,
             device_id: str | None = None, listeners: list[Listener] | None = None) -> None:  # fmt: skip
        """Publish on the topic's key with the row's encoding and congestion control (BLOCK or DROP); then hand the
        model to the listeners (`listeners`: those of the topic, when the caller already knows them)."""
        key = self._key(topic, kind, device_id)
        if topic.block or self._subscribed is None or self._subscribed(key, encoding=topic.encoding,
                                                                        express=topic.express):  # fmt: skip
            self._send(key, model.to_json(), topic)
            self.published += 1
        else:  # a DROP message nobody subscribes to (zenoh's matching status): not encoded, not put
            self.unmatched += 1
        for cb in self.listeners_of(topic.name) if listeners is None else listeners:
            try:
                cb(topic.name, model)
            except Exception:
                log.exception("listener failed on %s", topic.name)

    def _put_devices(self, topic: schemas.Topic, models: Sequence[_Dev]) -> None:
        """`_put` of each of a batch's device messages of one topic, in order."""
        if not models:
            return
        listeners = self.listeners_of(topic.name)
        for m in models:
            kind = "hook" if topic is schemas.T_SWING else m.kind  # type: ignore[union-attr]  # only hooks swing
            self._put(topic, m, kind, m.device_id, listeners)

    def _put_attitude_batch(self, newest: Sequence[schemas.Attitude], now_us: int) -> None:
        """The batch's attitudes on `gw/attitudes` too, at most `ATTITUDES_PER_MESSAGE` a message, while anyone
        subscribes: one put where the per-device keys take one per device (DROP, as they are)."""
        topic = schemas.T_ATTITUDES
        if not newest or self._subscribed is None:
            return
        key = topic.key()
        if not self._subscribed(key, encoding=topic.encoding, block=topic.block, express=topic.express):
            return
        step = schemas.ATTITUDES_PER_MESSAGE
        for i in range(0, len(newest), step):
            self._send(key, schemas.attitude_batch_json(now_us, newest[i:i + step]), topic)
            self.published += 1

    def emit(self, out: Output) -> None:
        """Alarms first (they matter most and are rare), then reel commands, attitude, attitude blocks (BLOCK: a
        scoring run or a full-rate recording must not lose samples), swing, height, spots. Attitude and height (DROP,
        "the latest" by protocol) are coalesced: one put per device per batch, its newest."""
        now_us = int(self.clock() * 1e6)
        for al in out.alarms:
            # Publish first, then hand the row to the writer thread: a failing disk must cost no alarm (it retries
            # the write from its journal) and the event loop never waits on SQLite. The store row is the engine's
            # record (the authority), acknowledgements included.
            try:
                self._put(schemas.T_ALARM, alarm_event(al, now_us), al.kind, al.change.alarm.device_id)
            except Exception:
                log.exception("alarm %s of %s not published", al.change.alarm.type, al.change.alarm.device_id)
            self.writer.upsert_alarm(al.change.alarm)
        for device_id, fields in out.reel_commands:
            self.send_reel(device_id, sender="auto", **fields)
        newest = _newest_per_device(out.attitudes)
        self._put_devices(schemas.T_ATTITUDE, newest)
        self._put_attitude_batch(newest, now_us)
        self._put_devices(schemas.T_ATTITUDE_BLOCK, out.attitude_blocks)
        self._put_devices(schemas.T_SWING, out.swings)  # BLOCK (its row): a crane app must not lose any
        if self.plot_listeners and (newest or out.swings):
            points = PlotBatch(newest, out.swings)
            for plot in self.plot_listeners:
                try:
                    plot(points)
                except Exception:
                    log.exception("plot listener failed")
        self._put_devices(schemas.T_HEIGHT, _newest_per_device(out.heights))
        if out.spots is not None:
            self._put(schemas.T_SPOTS, out.spots)
        for e in out.extra:  # a kind's own topics (docs/design.md, "Adding a device kind")
            self._put(e.topic, e.model, e.kind, e.device_id)

    def send_reel(
        self, device_id: str, action: str, speed_m_s: float | None = None, drag_n: float | None = None,
        sender: str = "api",
    ) -> schemas.ReelCommand:
        """Publish a ReelCommand to `rig/rod/{id}/reel/cmd` with BLOCK; returns it (with its cmd_id)."""
        cmd = schemas.ReelCommand(
            v=1, cmd_id=next(self._cmd_ids) % schemas.UINT32, action=action,  # type: ignore[arg-type]
            speed_m_s=speed_m_s, drag_n=drag_n, sent_wall_us=int(self.clock() * 1e6), sender=sender,
        )  # fmt: skip
        t = schemas.T_REEL_CMD
        self._send(t.key("rod", device_id), cmd.to_json(), t)
        for cb in self.listeners_of("reel_cmd"):
            cb("reel_cmd", cmd)
        return cmd

    def emit_packets(self, packets: list[schemas.Packet]) -> None:
        """Hand the batch's accepted packets to the packet sinks (live stream, 3-D view): decoded once, here."""
        for cb in self.packet_listeners:
            for p in packets:
                try:
                    cb(p)
                except Exception:
                    log.exception("packet listener failed on %s", type(p).__name__)


_M = TypeVar("_M", schemas.Attitude, schemas.Height)


def _newest_per_device(models: list[_M]) -> list[_M]:
    """The last model of each device, in the order of those last ones (outputs come oldest first)."""
    if len(models) < 2 or len({m.device_id for m in models}) == len(models):  # the common case: one per device
        return models
    newest: dict[str, _M] = {}
    for m in models:
        newest.pop(m.device_id, None)
        newest[m.device_id] = m
    return list(newest.values())


class HubSink:
    """An in-process consumer of the hub's typed outputs with a periodic task of its own (the dashboard's history
    and live stream): `on_hub` is called on the ingest task for every output, `on_plot` once per batch with the
    plotted points of its attitudes and swings, `run` is the task. `start_sink` and `stop` register/unregister and
    start/cancel them, on the event loop."""

    _task: asyncio.Task[None] | None = None
    wants_messages = True  # True: `on_hub` gets every published model (and other shards' mirrored ones)
    wants_plot = False  # True: `on_plot` gets each batch's plot points
    wants_packets = False  # True: `on_packet` gets every accepted device packet too

    def on_hub(self, topic: str, model: schemas.WireModel) -> None:
        raise NotImplementedError

    def on_plot(self, points: PlotBatch) -> None:
        raise NotImplementedError

    def on_packet(self, packet: schemas.Packet) -> None:
        raise NotImplementedError

    async def run(self) -> None:
        raise NotImplementedError

    def start_sink(self, hub: Hub) -> None:
        self._hub = hub
        if self.wants_messages:
            hub.listeners.append(self.on_hub)
        if self.wants_plot:
            hub.plot_listeners.append(self.on_plot)
        if self.wants_packets:
            hub.packet_listeners.append(self.on_packet)
        self._task = asyncio.get_running_loop().create_task(self.run())

    async def stop(self) -> None:
        hub: Hub | None = getattr(self, "_hub", None)
        if hub is not None and self.on_hub in hub.listeners:
            hub.listeners.remove(self.on_hub)
        if hub is not None and self.wants_plot and self.on_plot in hub.plot_listeners:
            hub.plot_listeners.remove(self.on_plot)
        if hub is not None and self.wants_packets and self.on_packet in hub.packet_listeners:
            hub.packet_listeners.remove(self.on_packet)
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
