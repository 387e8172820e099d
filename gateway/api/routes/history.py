"""Per-device history for the dashboard's plots: bounded and decimated, so a reload shows the last hour, not the
last few seconds.

Samples are folded into buckets of `bucket_s` (0.5 s): angles and readings keep the bucket mean, except the
swing direction (an angle that wraps at ±180°: its last value, a mean across the wrap would be wrong) and peaks
such as |a| and line tension (the bucket maximum, so a short spike stays visible). Each device keeps at most
`keep_s / bucket_s` buckets (7200 for an hour) in fixed numpy columns: ~200 kB per rod-hour, allocated when
a field first arrives, so memory is flat after a device's first seconds.

Owner: the event loop. Attitude and swing arrive through the hub listener (ingest task); reel tension and water
readings are sampled from the pipeline once per `poll_s` by a task on the same loop; the routes are `async def`,
so they read on that loop too and never see a half-written bucket. With several shards each keeps the history of
the devices it serves (`GatewayService.accept`); the REST front asks the owner for the others' (gateway/shard).
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from numpy.typing import NDArray

from gateway import schemas
from gateway.api.deps import DeviceIdPath
from gateway.hub import HubSink
from gateway.ingest.runner import GatewayService
from gateway.views import PlotPoint

router = APIRouter(prefix="/history", tags=["history"])
Agg = Literal["mean", "max", "last"]
FIELDS: dict[str, Agg] = {
    "roll_deg": "mean", "pitch_deg": "mean", "yaw_deg": "mean",  # yaw is unwrapped: a mean is fine
    "swing_deg": "max", "direction_deg": "last", "torsion_deg": "mean",
    "tension_n": "max", "line_out_m": "last",
    "water_temp_c": "mean", "air_temp_c": "mean", "oxygen_mg_l": "mean",
}  # fmt: skip
"""Every field a history can hold (units in the names) and how a bucket aggregates it."""


@dataclass(frozen=True)
class HistorySettings:
    """`bucket_s`: decimation step; `keep_s`: history length per device; `poll_s`: reel/env sampling period."""

    bucket_s: float = 0.5
    keep_s: float = 3600.0
    poll_s: float = 1.0


@dataclass
class _Bucket:
    t0_s: float
    t_s: float = 0.0
    n: dict[str, int] = field(default_factory=dict)
    value: dict[str, float] = field(default_factory=dict)

    def add(self, t_s: float, vals: dict[str, float]) -> None:
        if t_s > self.t_s:
            self.t_s = t_s
        count, value = self.n, self.value
        for k, v in vals.items():
            if not math.isfinite(v):
                continue
            n = count.get(k, 0)
            if n == 0:
                value[k] = v
            else:
                agg = FIELDS.get(k, "mean")
                if agg == "last":
                    value[k] = v
                elif agg == "max":
                    value[k] = max(value[k], v)
                else:
                    value[k] += (v - value[k]) / (n + 1)
            count[k] = n + 1


class DeviceHistory:
    """Closed buckets in a fixed ring (wall time float64, one float32 column per field the device has sent, NaN
    where a bucket lacks it) plus the open bucket. A column is allocated whole when its field first arrives, so
    memory stops growing within a device's first seconds: 8 + 4 bytes per field per bucket, ~200 kB for a rod-hour
    (a deque of dicts took 2.8 MB and grew for the whole hour)."""

    def __init__(self, bucket_s: float, maxlen: int) -> None:
        self.bucket_s = bucket_s
        self.maxlen = maxlen
        self.t_s = np.full(maxlen, np.nan)
        self.cols: dict[str, NDArray[np.float32]] = {}
        self.written = 0  # closed buckets so far; bucket i lives in row i % maxlen
        self._open: _Bucket | None = None

    def add(self, t_s: float, **vals: float) -> None:
        self.add_values(t_s, vals)

    def add_values(self, t_s: float, vals: dict[str, float]) -> None:
        """`add` with the values as one dict (the hub's plot points carry one)."""
        b = self._open
        if b is not None and t_s < b.t0_s:  # late sample of a closed bucket: dropped (histories are monotonic)
            return
        if b is None or t_s >= b.t0_s + self.bucket_s:
            if b is not None and b.value:
                self._close(b)
            b = self._open = _Bucket(t0_s=math.floor(t_s / self.bucket_s) * self.bucket_s)
        b.add(t_s, vals)

    def _close(self, b: _Bucket) -> None:
        row = self.written % self.maxlen
        self.t_s[row] = round(b.t_s, 3)
        for col in self.cols.values():
            col[row] = np.nan
        for k, v in b.value.items():
            if k not in self.cols:
                self.cols[k] = np.full(self.maxlen, np.nan, dtype=np.float32)
            self.cols[k][row] = v
        self.written += 1

    def columns(self, since_s: float, max_points: int) -> dict[str, list[float | None]]:
        """Columnar `{"t_s": [...], field: [...]}` from `since_s`, at most `max_points` rows (every k-th bucket
        when there are more, the newest kept; fields a bucket lacks are null; values to 4 decimals)."""
        n = min(self.written, self.maxlen)
        rows = np.arange(self.written - n, self.written) % self.maxlen  # oldest first
        rows = rows[self.t_s[rows] >= since_s]
        t = self.t_s[rows]
        vals = {k: col[rows].astype(np.float64) for k, col in self.cols.items()}
        b = self._open
        if b is not None and b.value and b.t_s >= since_s:
            t = np.append(t, round(b.t_s, 3))
            for k in b.value.keys() - vals.keys():
                vals[k] = np.full(len(rows), np.nan)
            vals = {k: np.append(v, b.value.get(k, np.nan)) for k, v in vals.items()}
        if len(t) > max_points:
            step = math.ceil(len(t) / max_points)
            pick = np.arange((len(t) - 1) % step, len(t), step)  # ends on the newest row
            t, vals = t[pick], {k: v[pick] for k, v in vals.items()}
        out: dict[str, list[float | None]] = {"t_s": t.tolist()}
        for k in sorted(vals):
            v = np.round(vals[k], 4)
            if np.isfinite(v).any():
                out[k] = [None if math.isnan(x) else x for x in v.tolist()]
        return out


class History(HubSink):
    """Histories of every device, fed by the hub and a poll of the pipeline (see the module docstring)."""

    def __init__(self, service: GatewayService, settings: HistorySettings | None = None) -> None:
        self.service = service
        self.settings = settings or HistorySettings()
        self.devices: dict[str, DeviceHistory] = {}
        self._seen: dict[tuple[str, str], tuple[Any, Any]] = {}

    def device(self, device_id: str) -> DeviceHistory:
        h = self.devices.get(device_id)
        if h is None:
            s = self.settings
            h = self.devices[device_id] = DeviceHistory(s.bucket_s, int(s.keep_s / s.bucket_s))
        return h

    wants_messages = False
    wants_plot = True

    def on_plot(self, points: list[PlotPoint]) -> None:
        """Hub plot listener (ingest task): fold a batch's attitude and swing points in."""
        accept, devices = self.service.accept, self.devices
        for device_id, t_s, values in points:
            if accept is None or accept(device_id):  # other shards keep their devices' own
                h = devices.get(device_id)
                (h if h is not None else self.device(device_id)).add_values(t_s, values)

    def poll(self, now_s: float) -> None:
        """Sample reel tension and environment readings from the pipeline (event loop); only packets that are new
        since the last poll, so an offline device's last values are not repeated into its history."""
        pl = self.service.pipeline
        latest: list[tuple[str, schemas.WireModel, tuple[str, ...]]] = [
            (d, st, ("tension_n", "line_out_m")) for d, (st, _) in pl.reel.items()
        ]
        latest += [(d, env, ("water_temp_c", "air_temp_c", "oxygen_mg_l")) for d, env in pl.env.items()]
        for device_id, packet, names in latest:
            key = (device_id, type(packet).__name__)
            mark = (getattr(packet, "boot_id", None), getattr(packet, "seq", None))
            if self._seen.get(key) == mark:
                continue
            self._seen[key] = mark
            vals = {k: float(v) for k in names if isinstance(v := getattr(packet, k, None), float | int)}
            if vals:
                self.device(device_id).add(now_s, **vals)

    async def run(self) -> None:
        while True:
            await asyncio.sleep(self.settings.poll_s)
            try:
                self.poll(time.time())
            except Exception:  # a half-registered device must not end the history
                continue

    def start(self) -> None:
        self.start_sink(self.service.hub)


def start_history(app: Any, service: GatewayService) -> History:
    """Lifespan hook (on the event loop, after the service started)."""
    h = History(service)
    h.start()
    app.state.history = h
    return h


async def stop_history(app: Any) -> None:
    h: History | None = getattr(app.state, "history", None)
    if h is not None:
        await h.stop()


def _history(request: Request) -> History:
    h: History | None = getattr(request.app.state, "history", None)
    if h is None:
        raise HTTPException(503, "history not started yet (gateway warming up)")
    return h


Seconds = Annotated[float, Query(gt=0.0, le=86400.0, description="how far back, s")]
MaxPoints = Annotated[int, Query(ge=2, le=20000, description="at most this many rows (decimated by stride)")]


@router.get("")
async def all_history(request: Request, seconds: Seconds = 300.0, max_points: MaxPoints = 60) -> dict[str, Any]:
    """Every device's history (small `max_points` by default: the fleet overview's sparklines)."""
    h = _history(request)
    since = time.time() - seconds
    return {"bucket_s": h.settings.bucket_s,
            "devices": {d: hist.columns(since, max_points) for d, hist in sorted(h.devices.items())}}  # fmt: skip


@router.get("/{device_id}")
async def device_history(
    device_id: DeviceIdPath, request: Request, seconds: Seconds = 600.0, max_points: MaxPoints = 4000
) -> dict[str, Any]:
    """One device's history: wall time `t_s` (s since 1970) and one column per field, units in the names."""
    h = _history(request)
    hist = h.devices.get(device_id)
    if hist is None:
        if device_id not in request.app.state.service.pipeline.kinds:
            raise HTTPException(404, f"unknown device {device_id!r}")
        return {"device_id": device_id, "bucket_s": h.settings.bucket_s, "series": {"t_s": []}}
    return {"device_id": device_id, "bucket_s": h.settings.bucket_s,
            "series": hist.columns(time.time() - seconds, max_points)}  # fmt: skip
