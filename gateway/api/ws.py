"""Live stream for the dashboard: `/ws/stream` (WebSocket) with a bounded queue per client.

Producers never wait on a client. The hub calls `LiveStream.on_hub` on the ingest task; it only appends to
per-device buffers (attitude, swing) or, for alarms and reel commands, encodes one small frame and offers it to
every client. A `tick` frame (every `tick_s`) carries the device cards, the buffered series since the last tick,
the raw acceleration of each rod and the spot ranking. Each client owns a `ClientQueue` of encoded frames: when it
is full the OLDEST frame is dropped and counted, so a slow browser sees a gap, never a stall of ingest.

Raw IMU and environment readings come from the hub too, as the packets ingest decoded and accepted (`on_packet`,
wired in `gateway.app`): a short deque of packet references per known device, summarised at tick time only while
a client is connected; nothing here parses a payload. Frames are JSON objects with a `type`: `hello`, `tick`,
`alarm`, `reel_cmd`.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from fastapi import APIRouter, Request, WebSocket, WebSocketDisconnect

from gateway import schemas
from gateway.api.security import origin_allowed
from gateway.hub import HubSink, listens_to
from gateway.ingest.runner import GatewayService
from gateway.store import ApiToken
from gateway.views import PlotPoint, device_view

log = logging.getLogger("gateway.ws")
router = APIRouter()


class ClientQueue:
    """Bounded FIFO of encoded frames for one client. `put` never blocks: when full, the oldest frame is dropped
    (and counted in `dropped`). `get` waits for the next frame."""

    def __init__(self, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self.maxsize = maxsize
        self.dropped = 0
        self._items: collections.deque[str] = collections.deque()
        self._ready = asyncio.Event()

    def put(self, frame: str) -> None:
        if len(self._items) >= self.maxsize:
            self._items.popleft()
            self.dropped += 1
        self._items.append(frame)
        self._ready.set()

    async def get(self) -> str:
        while not self._items:
            self._ready.clear()
            await self._ready.wait()
        return self._items.popleft()

    def __len__(self) -> int:
        return len(self._items)


@dataclass(frozen=True)
class LiveSettings:
    """Stream rates and bounds. `tick_s`: period of tick frames; `series_max`: samples kept per device between
    ticks (older ones are dropped); `raw_packets`: raw packets kept per key between ticks; `cards_every`: ticks between
    full device cards (the other ticks carry only the new samples); `max_raw_keys`: devices with raw packets kept."""

    queue_size: int = 256
    tick_s: float = 0.1
    cards_every: int = 5  # full device cards and the spot ranking every this many ticks (2 Hz)
    series_max: int = 200
    raw_packets: int = 8
    max_raw_keys: int = 2048  # raw buffers (one per known device)


@dataclass
class _Series:
    """Samples of one device since the last tick (wall time in s)."""

    t_s: collections.deque[float]
    values: dict[str, collections.deque[float]] = field(default_factory=dict)

    def add(self, t_s: float, **vals: float) -> None:
        self.t_s.append(t_s)
        for k, v in vals.items():
            self.values.setdefault(k, collections.deque(maxlen=self.t_s.maxlen)).append(round(v, 5))

    def take(self) -> dict[str, list[float]]:
        out = {"t_s": [round(t, 3) for t in self.t_s], **{k: list(v) for k, v in self.values.items()}}
        self.t_s.clear()
        for v in self.values.values():
            v.clear()
        return out


def _finite(x: Any) -> float | None:
    return float(x) if isinstance(x, int | float) and math.isfinite(x) else None


def raw_imu_summary(packets: list[schemas.ImuPacket], now_s: float) -> dict[str, Any]:
    """One acceleration point per IMU packet (oldest first) plus the link fields of the newest.

    Point = mean of the packet's samples per axis (m/s²) and the PEAK |a| over its samples (so a short shock
    stays visible at packet rate), at the time of the packet's last sample: `wall_t0_us + (n-1)/rate_hz`, or
    `now_s - 1/rate_hz` when the packet carries no wall time. Non-finite rows are skipped."""
    t: list[float] = []
    ax: list[float] = []
    ay: list[float] = []
    az: list[float] = []
    peak: list[float] = []
    link: dict[str, Any] = {}
    for p in packets:
        acc = np.asarray(p.acc_m_s2, dtype=np.float64).reshape(-1, 3)
        n = acc.shape[0]
        acc = acc[np.all(np.isfinite(acc), axis=1)]
        if not len(acc):
            continue
        end = p.wall_t0_us / 1e6 + (n - 1) / p.rate_hz if p.wall_t0_us is not None else now_s - 1.0 / p.rate_hz
        mean = acc.mean(axis=0)
        t.append(round(end, 3))
        ax.append(round(float(mean[0]), 4))
        ay.append(round(float(mean[1]), 4))
        az.append(round(float(mean[2]), 4))
        peak.append(round(float(np.sqrt((acc * acc).sum(axis=1)).max()), 4))
        for k in ("battery_v", "rssi_dbm", "temp_c"):
            if _finite(getattr(p, k)) is not None:
                link[k] = getattr(p, k)
    return {"acc": {"t_s": t, "ax": ax, "ay": ay, "az": az, "norm": peak}, "link": link}


class Peers(Protocol):
    """The other shards' side of the stream (gateway/shard/live.py): they get this shard's tick frames while some
    other endpoint has clients (`wanted`), and this shard's clients get theirs (`merge`)."""

    def wanted(self) -> bool: ...

    def publish(self, frame: dict[str, Any]) -> None: ...

    def listening(self, has_clients: bool) -> None: ...

    def merge(self, frame: dict[str, Any]) -> None: ...


class LiveStream(HubSink):
    """Fans pipeline results and sampled device state out to dashboard clients (see module docstring)."""

    wants_plot = True
    wants_packets = True

    def __init__(self, service: GatewayService, settings: LiveSettings | None = None) -> None:
        self.service = service
        self.settings = settings or LiveSettings()
        self.clients: set[ClientQueue] = set()
        self.alarm_seq = 0
        self.ticks = 0
        self._series: dict[str, _Series] = {}
        self._imu: dict[str, collections.deque[schemas.ImuPacket]] = {}
        self._env: dict[str, schemas.EnvPacket] = {}
        self.entry_failures = 0
        self._entry_fail_logged_s = -math.inf
        self.peers: Peers | None = None  # set by a shard (gateway/shard): devices served by other shards
        self.remote = False  # another endpoint's clients want this shard's frames (from `peers`, every tick)

    def _served(self, device_id: str) -> bool:
        accept = self.service.accept
        return accept is None or accept(device_id)

    # -- producers --------------------------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        """Someone reads the stream (a client here, or another shard's): else nothing is buffered at all, so a
        gateway without a dashboard open pays nothing per output or packet here."""
        return bool(self.clients) or self.remote

    @listens_to("alarm", "reel_cmd")
    def on_hub(self, topic: str, model: schemas.WireModel) -> None:
        """Hub listener (ingest task): broadcast alarms and reel commands at once (attitude and swing come as
        points, `on_plot`; another shard's mirrored ones are its own stream's)."""
        if topic == "alarm":
            self.alarm_seq += 1
            self.broadcast({"type": "alarm", "alarm_seq": self.alarm_seq, "event": model.model_dump()})
        elif topic == "reel_cmd":
            self.broadcast({"type": "reel_cmd", "command": model.model_dump()})

    def on_plot(self, points: Sequence[PlotPoint]) -> None:
        """Hub plot listener (ingest task): buffer a batch's attitude/swing points while someone reads."""
        if not self.active:
            return
        for device_id, t_s, values in points:
            if self._served(device_id):  # other shards' devices come with their tick frames (`peers`)
                self._buf(device_id).add(t_s, **values)

    def _buf(self, device_id: str) -> _Series:
        s = self._series.get(device_id)
        if s is None:
            s = self._series[device_id] = _Series(collections.deque(maxlen=self.settings.series_max))
        return s

    def on_packet(self, packet: schemas.Packet) -> None:
        """Hub packet sink (ingest task): keep a reference to the newest IMU packets / environment reading of the
        device (already decoded and accepted: a device ingest knows); at most `max_raw_keys` devices. Nothing while
        nobody reads the stream."""
        if not self.active:
            return
        if isinstance(packet, schemas.ImuPacket):
            q = self._imu.get(packet.device_id)
            if q is None:
                if len(self._imu) >= self.settings.max_raw_keys:
                    return
                q = self._imu[packet.device_id] = collections.deque(maxlen=self.settings.raw_packets)
            q.append(packet)
        elif isinstance(packet, schemas.EnvPacket):
            if packet.device_id in self._env or len(self._env) < self.settings.max_raw_keys:
                self._env[packet.device_id] = packet

    def prune_raw(self) -> None:
        """Drop the raw buffers of devices the pipeline no longer knows (event loop, every tick)."""
        kinds = self.service.pipeline.kinds
        for buffers in (self._imu, self._env, self._series):
            for device_id in [d for d in buffers if d not in kinds or not self._served(d)]:
                del buffers[device_id]

    def _take_imu(self, device_id: str) -> list[schemas.ImuPacket]:
        q = self._imu.get(device_id)
        if not q:
            return []
        out = list(q)
        q.clear()
        return out

    # -- frames -----------------------------------------------------------------------------------------------

    def broadcast(self, frame: dict[str, Any]) -> None:
        """Encode once, offer to every client (never blocks)."""
        if not self.clients:
            return
        text = json.dumps(frame, separators=(",", ":"), allow_nan=False, default=str)
        for c in self.clients:
            c.put(text)

    def tick_frame(self, now_s: float, full: bool = True) -> dict[str, Any]:
        """New samples of every device this shard serves since the last tick; with `full`, also the device cards
        (presence, age, loss, attitude, readings, reel, alarms: `device_view`) and the spot ranking."""
        svc = self.service
        devices = []
        for device_id, kind in sorted(svc.pipeline.kinds.items()):
            if not self._served(device_id):
                continue
            try:  # one device's card must never stop the stream for all
                devices.append(self._device_entry(device_id, kind, now_s, full))
            except Exception:
                self.entry_failures += 1
                if now_s - self._entry_fail_logged_s >= 10.0:
                    self._entry_fail_logged_s = now_s
                    log.exception("tick: device %r skipped (%d skipped so far)", device_id[:80], self.entry_failures)
        frame = {"type": "tick", "wall_s": round(now_s, 3), "alarm_seq": self.alarm_seq, "full": full,
                 "devices": devices}  # fmt: skip
        if full:
            frame["spots"] = svc.pipeline.rank_spots(now_s).model_dump()["spots"]
        return frame

    def _device_entry(self, device_id: str, kind: str, now_s: float, full: bool) -> dict[str, Any]:
        svc = self.service
        entry: dict[str, Any] = {"device_id": device_id, "kind": kind}
        if full:
            try:
                entry = device_view(svc, device_id, detail=False)
            except Exception:  # a device half-registered mid-batch: skip its card this tick
                pass
        s = self._series.get(device_id)
        entry["series"] = s.take() if s is not None else {"t_s": []}
        if kind in schemas.IMU_KINDS:
            raw = raw_imu_summary(self._take_imu(device_id), now_s)
            entry["acc"] = raw["acc"]
            if raw["link"]:
                entry["link"] = raw["link"]
        elif kind == "ball" and full:
            env = self._env.pop(device_id, None)
            if env is not None:
                entry["link"] = {k: getattr(env, k) for k in ("battery_v", "rssi_dbm")
                                 if _finite(getattr(env, k)) is not None}  # fmt: skip
        return entry

    async def run(self) -> None:
        """Tick loop; work is skipped while nobody listens, here or on another shard's endpoint (buffers are still
        bounded). With `peers`, the frame of this shard's devices also goes to the other shards, and this shard's
        clients get the other shards' devices merged in."""
        while True:
            await asyncio.sleep(self.settings.tick_s)
            self.prune_raw()
            peers = self.peers
            remote = self.remote = peers is not None and peers.wanted()
            if peers is not None:
                peers.listening(bool(self.clients))  # asks the others for their frames while clients are here
            if not self.clients and not remote:
                continue
            try:
                frame = self.tick_frame(time.time(), full=self.ticks % self.settings.cards_every == 0)
                self.ticks += 1
                if remote:
                    assert peers is not None
                    peers.publish(frame)
                if not self.clients:
                    continue
                if peers is not None:
                    peers.merge(frame)
                text = json.dumps(frame, separators=(",", ":"), default=str)
                for c in self.clients:
                    c.put(text)
            except Exception:
                log.exception("tick failed")

    def start(self) -> None:
        """Register with the hub and start ticking (call on the event loop after the service started)."""
        self.start_sink(self.service.hub)


def stream_allowed(ws: WebSocket) -> bool:
    """A browser page may open the stream only from the gateway's own origin (or `Settings.allowed_origins`),
    else it needs the API token (`?token=` or `Authorization: Bearer`): any site the operator visits could
    otherwise read the live data. Clients that send no Origin are not browsers and read as REST does."""
    origin = ws.headers.get("origin")
    settings = ws.app.state.service.settings
    if origin is None or origin_allowed(origin, ws.headers.get("host"), settings.allowed_origins):
        return True
    auth = ws.headers.get("authorization", "")
    given = ws.query_params.get("token") or (auth[7:] if auth.lower().startswith("bearer ") else None)
    token: ApiToken = ws.app.state.token
    return token.verify_token(given)


@router.websocket("/ws/stream")
async def stream(ws: WebSocket) -> None:
    """Live frames (see module docstring); read-only: same origin, or the token from another origin."""
    live: LiveStream = ws.app.state.live
    if not stream_allowed(ws):
        log.warning("refused /ws/stream from origin %r", (ws.headers.get("origin") or "")[:100])
        await ws.close(code=1008)  # before accept: the handshake gets a 403
        return
    await ws.accept()
    q = ClientQueue(live.settings.queue_size)
    live.clients.add(q)
    hello = {"type": "hello", "queue_size": q.maxsize, "tick_s": live.settings.tick_s, "alarm_seq": live.alarm_seq}
    await ws.send_text(json.dumps(hello))

    async def pump() -> None:
        while True:
            frame = await q.get()
            if q.dropped and frame.startswith('{"type":"tick"'):
                frame = frame[:-1] + f',"client_dropped":{q.dropped}}}'
            await ws.send_text(frame)

    sender = asyncio.create_task(pump())
    try:
        while True:  # the client only sends pings; a disconnect ends the loop
            await ws.receive_text()
    except WebSocketDisconnect:
        pass
    finally:
        live.clients.discard(q)
        sender.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await sender


@router.get("/api/live", tags=["health"])
async def live_stats(request: Request) -> dict[str, Any]:
    """Dashboard stream: connected clients, frames dropped for slow clients, ticks sent (read on the event loop,
    which owns the stream's state)."""
    live: LiveStream = request.app.state.live
    return {"clients": len(live.clients), "dropped": sum(c.dropped for c in live.clients), "ticks": live.ticks,
            "alarm_seq": live.alarm_seq, "queue_size": live.settings.queue_size}  # fmt: skip


def start_live(app: Any, service: GatewayService) -> LiveStream:
    """Lifespan hook: create the stream (queue size from Settings.ws_queue_size), start it, keep it on app.state."""
    live = LiveStream(service, LiveSettings(queue_size=service.settings.ws_queue_size))
    live.start()
    app.state.live = live
    return live


async def stop_live(app: Any) -> None:
    """Lifespan hook: stop the stream if it was started."""
    live: LiveStream | None = getattr(app.state, "live", None)
    if live is not None:
        await live.stop()
