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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from numpy.typing import NDArray

from gateway import schemas
from gateway.api.deps import DeviceIdPath
from gateway.fusion.base import FloatArray
from gateway.hub import HubSink
from gateway.ingest.runner import GatewayService
from gateway.views import PLOT_FIELDS, PlotBatch, PlotPoint

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


_MEAN, _MAX, _LAST = 0, 1, 2
_AGG_CODE: dict[Agg, int] = {"mean": _MEAN, "max": _MAX, "last": _LAST}


class OpenBuckets:
    """The open buckets of many devices' histories as rows of arrays: whether one is open, its start and newest
    time, and per field how many finite values it took and their aggregate. `fold` adds a batch's points with a few
    numpy calls (a device's k-th point of the batch in step k, so its points keep their order), where a Python fold
    per point and field cost ~5 µs a point at 1000 devices; each value goes through the arithmetic that fold did,
    so the buckets hold the same floats. One owner: the event loop (a History and its DeviceHistory rows)."""

    def __init__(self) -> None:
        self.names: list[str] = []  # column -> field name
        self.fields: dict[str, int] = {}  # field name -> column
        self.agg = np.zeros(0, dtype=np.int64)  # per column: _MEAN, _MAX or _LAST
        self.owners: list[DeviceHistory] = []  # per row: whose open bucket it is
        self.open = np.zeros(0, dtype=np.bool_)
        self.t0_s = np.zeros(0)
        self.t_s = np.zeros(0)  # the newest point's time (0.0 in a new bucket)
        self.n = np.zeros((0, 0), dtype=np.int64)
        self.value = np.zeros((0, 0))

    def columns_of(self, names: Sequence[str]) -> list[int]:
        """The column of each field, added when new (aggregated as `FIELDS` says, a mean when not listed there)."""
        for k in names:
            if k not in self.fields:
                self.fields[k] = len(self.names)
                self.names.append(k)
                self.agg = np.append(self.agg, _AGG_CODE[FIELDS.get(k, "mean")])
                self.n = np.hstack([self.n, np.zeros((self.n.shape[0], 1), dtype=np.int64)])
                self.value = np.hstack([self.value, np.zeros((self.value.shape[0], 1))])
        return [self.fields[k] for k in names]

    def add_row(self, owner: DeviceHistory) -> int:
        """A row for `owner`'s open bucket (none open yet)."""
        row = len(self.owners)
        self.owners.append(owner)
        if row >= self.open.shape[0]:
            more = max(4, row)  # doubling
            self.open = np.concatenate([self.open, np.zeros(more, dtype=np.bool_)])
            self.t0_s = np.concatenate([self.t0_s, np.zeros(more)])
            self.t_s = np.concatenate([self.t_s, np.zeros(more)])
            self.n = np.vstack([self.n, np.zeros((more, self.n.shape[1]), dtype=np.int64)])
            self.value = np.vstack([self.value, np.zeros((more, self.value.shape[1]))])
        return row

    def taken(self, row: int) -> dict[str, float]:
        """The open bucket's aggregate of each field it took a finite value of ({} when none is open)."""
        if not self.open[row]:
            return {}
        counts, values = self.n[row].tolist(), self.value[row].tolist()
        return {k: values[j] for j, k in enumerate(self.names) if counts[j] > 0}

    def fold(self, rows: NDArray[np.int64], t_s: FloatArray, cols: Sequence[int], values: FloatArray,
             bucket_s: float) -> None:  # fmt: skip
        """Add points: point k to the open bucket of row `rows[k]` at wall time `t_s[k]`, with `values[k]` in the
        columns `cols` (a non-finite value is skipped, like a field the point does not carry); a row's points in
        their order. A point older than its row's open bucket is dropped; one past the bucket's end closes it into
        the device's ring (`DeviceHistory._close`) and opens the bucket it falls in."""
        m = rows.shape[0]
        if m == 0:
            return
        order = np.argsort(rows, kind="stable")
        first = np.ones(m, dtype=np.bool_)
        first[1:] = rows[order][1:] != rows[order][:-1]
        if first.all():  # one point per row (most batches): one step
            self._step(rows, t_s, np.asarray(cols, dtype=np.int64), values, bucket_s)
            return
        rank = np.empty(m, dtype=np.int64)
        rank[order] = np.arange(m) - np.maximum.accumulate(np.where(first, np.arange(m), 0))
        for r in range(int(rank.max()) + 1):
            at = np.flatnonzero(rank == r)
            self._step(rows[at], t_s[at], np.asarray(cols, dtype=np.int64), values[at], bucket_s)

    def _step(self, rows: NDArray[np.int64], t: FloatArray, cols: NDArray[np.int64], v: FloatArray,
              bucket_s: float) -> None:  # fmt: skip
        """`fold` of one point per row (the rows distinct)."""
        is_open = self.open[rows]
        t0 = self.t0_s[rows]
        late = is_open & (t < t0)
        renew = ~late & (~is_open | (t >= t0 + bucket_s))
        if renew.any():
            if not np.isfinite(t[renew]).all():  # no bucket to open (`math.floor` raised here before)
                raise ValueError(f"history points at non-finite times: {t[renew & ~np.isfinite(t)]}")
            fresh = rows[renew]
            closing = fresh[is_open[renew] & (self.n[fresh] > 0).any(axis=1)]  # open buckets that took values
            for row in closing.tolist():
                self.owners[row]._close(float(self.t_s[row]), self.taken(row))
            self.open[fresh] = True
            self.t0_s[fresh] = np.floor(t[renew] / bucket_s) * bucket_s
            self.t_s[fresh] = 0.0
            self.n[fresh] = 0
            self.value[fresh] = 0.0
        if late.any():
            keep = ~late
            rows, t, v = rows[keep], t[keep], v[keep]
        newest = self.t_s[rows]
        self.t_s[rows] = np.where(t > newest, t, newest)
        cell = np.ix_(rows, cols)
        n0, v0 = self.n[cell], self.value[cell]
        agg = self.agg[cols]
        with np.errstate(all="ignore"):  # (the mean of a first or a skipped value is not taken)
            mean = v0 + (v - v0) / (n0 + 1)
        new = np.where(n0 == 0, v, np.where(agg == _LAST, v, np.where(agg == _MAX, np.where(v > v0, v, v0), mean)))
        finite = np.isfinite(v)
        self.value[cell] = np.where(finite, new, v0)
        self.n[cell] = n0 + finite


class DeviceHistory:
    """Closed buckets in a fixed ring (wall time float64, one float32 column per field the device has sent, NaN
    where a bucket lacks it) plus the open bucket, a row of `buckets` (shared by a History's devices; its own when
    not given). A column is allocated whole when its field first arrives, so memory stops growing within a device's
    first seconds: 8 + 4 bytes per field per bucket, ~200 kB for a rod-hour (a deque of dicts took 2.8 MB and grew
    for the whole hour)."""

    def __init__(self, bucket_s: float, maxlen: int, buckets: OpenBuckets | None = None) -> None:
        self.bucket_s = bucket_s
        self.maxlen = maxlen
        self.t_s = np.full(maxlen, np.nan)
        self.cols: dict[str, NDArray[np.float32]] = {}
        self.written = 0  # closed buckets so far; bucket i lives in row i % maxlen
        self.buckets = OpenBuckets() if buckets is None else buckets
        self.row = self.buckets.add_row(self)

    def add(self, t_s: float, **vals: float) -> None:
        self.add_values(t_s, vals)

    def add_values(self, t_s: float, vals: dict[str, float]) -> None:
        """One point: `vals` by field at wall time `t_s` (dropped when older than the open bucket)."""
        b = self.buckets
        cols = b.columns_of(list(vals))
        b.fold(np.array([self.row], dtype=np.int64), np.array([t_s], dtype=np.float64), cols,
               np.array([list(vals.values())], dtype=np.float64).reshape(1, len(cols)), self.bucket_s)  # fmt: skip

    def _close(self, t_s: float, taken: dict[str, float]) -> None:
        """The open bucket (its newest time, its aggregates) into the ring: `OpenBuckets` calls it before it opens
        the next."""
        row = self.written % self.maxlen
        self.t_s[row] = round(t_s, 3)
        for k, col in self.cols.items():
            col[row] = taken.get(k, np.nan)
        for k in taken.keys() - self.cols.keys():
            col = self.cols[k] = np.full(self.maxlen, np.nan, dtype=np.float32)
            col[row] = taken[k]
        self.written += 1

    def columns(self, since_s: float, max_points: int) -> dict[str, list[float | None]]:
        """Columnar `{"t_s": [...], field: [...]}` from `since_s`, at most `max_points` rows (`ring_columns`)."""
        taken = self.buckets.taken(self.row)
        open_bucket = (float(self.buckets.t_s[self.row]), taken) if taken else None
        return ring_columns(self.t_s, self.cols, self.written, open_bucket, since_s, max_points)


def ring_columns(t_s: NDArray[np.float64], cols: dict[str, NDArray[np.float32]], written: int,
                 open_bucket: tuple[float, dict[str, float]] | None, since_s: float,
                 max_points: int) -> dict[str, list[float | None]]:  # fmt: skip
    """A history ring's columns (`written` rows so far into rings of `len(t_s)`) and its open bucket (its newest
    time and aggregates, if any) as `{"t_s": [...], field: [...]}` from `since_s`, at most `max_points` rows (every
    k-th bucket when there are more, the newest kept; fields a bucket lacks are null; values to 4 decimals)."""
    maxlen = len(t_s)
    n = min(written, maxlen)
    rows = np.arange(written - n, written) % maxlen  # oldest first
    rows = rows[t_s[rows] >= since_s]
    t = t_s[rows]
    vals = {k: col[rows].astype(np.float64) for k, col in cols.items()}
    if open_bucket is not None and open_bucket[0] >= since_s:
        t_open, taken = open_bucket
        t = np.append(t, round(t_open, 3))
        for k in taken.keys() - vals.keys():
            vals[k] = np.full(len(rows), np.nan)
        vals = {k: np.append(v, taken.get(k, np.nan)) for k, v in vals.items()}
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
        self.buckets = OpenBuckets()  # every device's open bucket, a row each
        self._plot_cols = self.buckets.columns_of(PLOT_FIELDS)
        self._seen: dict[tuple[str, str], tuple[Any, Any]] = {}

    def device(self, device_id: str) -> DeviceHistory:
        h = self.devices.get(device_id)
        if h is None:
            s = self.settings
            h = self.devices[device_id] = DeviceHistory(s.bucket_s, int(s.keep_s / s.bucket_s), self.buckets)
        return h

    wants_messages = False
    wants_plot = True

    def on_plot(self, points: Sequence[PlotPoint]) -> None:
        """Hub plot listener (ingest task): fold a batch's attitude and swing points in, from their columns
        (`PlotBatch`) with one `OpenBuckets.fold`; other sequences of points one by one."""
        accept, devices = self.service.accept, self.devices
        if not isinstance(points, PlotBatch):
            for device_id, t_s, values in points:
                if accept is None or accept(device_id):  # other shards keep their devices' own
                    h = devices.get(device_id)
                    (h if h is not None else self.device(device_id)).add_values(t_s, values)
            return
        ids, times, degrees = points.columns()
        if accept is not None:  # other shards keep their devices' own
            mine = [k for k, d in enumerate(ids) if accept(d)]
            ids, times, degrees = [ids[k] for k in mine], [times[k] for k in mine], degrees[mine]
        rows = [(h if (h := devices.get(d)) is not None else self.device(d)).row for d in ids]
        self.buckets.fold(np.array(rows, dtype=np.int64), np.array(times, dtype=np.float64), self._plot_cols,
                          degrees, self.settings.bucket_s)  # fmt: skip

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
                self.device(device_id).add_values(now_s, vals)

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
