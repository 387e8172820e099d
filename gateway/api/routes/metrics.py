"""`GET /metrics`: Prometheus text format (prometheus-client), for operators' scrapers.

Counters and gauges are read from the service's own snapshots at scrape time (the ingest loop keeps owning its
state; a scrape only reads). The one histogram, sample-to-publish latency, is observed by a hub listener: the
gateway's clock when it publishes an attitude or alarm minus the device's wall time of the sample behind it
(meaningful when the device clock is synchronised, as the simulators' are). Its observations are binned many at a
time (`BatchedHistogram`): one attitude per device and batch made `Histogram.observe` cost ~2.5 µs per packet.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import prometheus_client.metrics
from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

from gateway import schemas
from gateway.hub import listens_to
from gateway.ingest.runner import GatewayService

router = APIRouter(tags=["health"])
LATENCY_BUCKETS_S = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
HISTOGRAM_FLUSH_EVERY = 4096  # observations a series holds before they are binned (bounded without a scraper)


@dataclass
class _Series:
    """One label set's state: bucket counts (not cumulative), running sum, creation time, observations not binned."""

    counts: list[float]
    created_s: float
    sum: float = 0.0
    pending: list[float] = field(default_factory=list)


class BatchedHistogram(Collector):
    """A labelled histogram exposed exactly as prometheus_client's `Histogram` exposes one (buckets, `_count`,
    `_sum`, `_created` per label set in creation order; the sum added up in observation order, each observation
    clamped at 0), whose `observe` only appends: observations are binned with numpy when a series holds
    `HISTOGRAM_FLUSH_EVERY` of them or at a scrape.

    Why: `Histogram.observe` takes a lock and walks the buckets in Python (~2.5 µs on the ingest task per attitude
    published). prometheus_client has no bulk observe; its maintainers point to a custom collector for that
    (prometheus/client_python#733, #911). `observe` may run on another thread than `collect`: appends need no lock,
    binning takes one (tests/gateway/test_metrics_histogram.py compares the text exposition with `Histogram`'s)."""

    def __init__(self, name: str, documentation: str, labelnames: Sequence[str], buckets: Sequence[float]) -> None:
        self.name = name
        self.documentation = documentation
        self.labelnames = tuple(labelnames)
        self.upper_bounds = np.array([*buckets, math.inf], dtype=np.float64)
        self._le = [floatToGoString(b) for b in self.upper_bounds.tolist()]  # type: ignore[no-untyped-call]
        self._series: dict[tuple[str, ...], _Series] = {}
        self._lock = threading.Lock()

    def observe(self, labelvalues: tuple[str, ...], value: float) -> None:
        """Record one observation of the series `labelvalues` (binned later, as max(0.0, value))."""
        series = self._series.get(labelvalues)
        if series is None:
            with self._lock:
                series = self._series.setdefault(labelvalues, _Series([0.0] * len(self._le), time.time()))
        series.pending.append(value)
        if len(series.pending) >= HISTOGRAM_FLUSH_EVERY:
            with self._lock:
                self._bin(series)

    def _bin(self, series: _Series) -> None:
        """Move a series' pending observations into its buckets and sum, as `Histogram.observe` of each in turn
        (the caller holds the lock)."""
        n = len(series.pending)
        if n == 0:
            return
        values = np.array(series.pending[:n], dtype=np.float64)
        del series.pending[:n]  # (what another thread appended meanwhile stays for the next time)
        values = np.where(values > 0.0, values, 0.0)  # max(0.0, value), NaN included
        found = np.bincount(np.searchsorted(self.upper_bounds, values, side="left"), minlength=len(self._le))
        series.counts = [c + k for c, k in zip(series.counts, found.tolist(), strict=True)]
        total = series.sum
        for v in values.tolist():  # one by one, in order: the float sum Histogram's would be
            total += v
        series.sum = total

    def collect(self) -> Iterator[Any]:
        family = HistogramMetricFamily(self.name, self.documentation, labels=self.labelnames)
        with_created = prometheus_client.metrics._use_created  # as Histogram (PROMETHEUS_DISABLE_CREATED_SERIES)
        with self._lock:
            state = []
            for labelvalues, series in self._series.items():
                self._bin(series)
                state.append((labelvalues, series.counts, series.sum, series.created_s))
        for labelvalues, counts, total, created_s in state:
            acc, buckets = 0.0, []
            for le, count in zip(self._le, counts, strict=True):
                acc += count
                buckets.append((le, acc))
            family.add_metric(list(labelvalues), buckets, total)
            if with_created:
                family.add_sample(f"{self.name}_created", dict(zip(self.labelnames, labelvalues, strict=True)),
                                  created_s)  # fmt: skip
        yield family


class ServiceCollector(Collector):
    """Ingest, loss, rejects, filter restarts and active alarms from a running GatewayService."""

    def __init__(self, service: GatewayService) -> None:
        self.service = service

    def collect(self) -> Iterator[Any]:
        svc = self.service
        snap = svc.counters.snapshot(int(time.time() * 1e6))
        received = CounterMetricFamily("rig_ingest_received", "Packets received from the bus (all keys)")
        received.add_metric([], snap.received)
        yield received
        drops = CounterMetricFamily("rig_ingest_queue_drops", "Packets dropped because the ingest queue was full")
        drops.add_metric([], svc.inbox.drops if svc.inbox is not None else 0)
        yield drops
        depth = GaugeMetricFamily("rig_ingest_queue_depth", "Packets waiting in the ingest queue")
        depth.add_metric([], len(svc.inbox) if svc.inbox is not None else 0)
        yield depth
        labels = ["device_id", "kind"]
        ok = CounterMetricFamily("rig_packets", "Packets accepted per device", labels=labels)
        lost = CounterMetricFamily("rig_packets_lost", "Packets missing by sequence gaps per device", labels=labels)
        dup = CounterMetricFamily("rig_packets_duplicate", "Duplicate packets per device", labels=labels)
        loss = GaugeMetricFamily("rig_packet_loss_ratio", "lost / (ok + lost) per device", labels=labels)
        for d in snap.devices:
            ok.add_metric([d.device_id, d.kind], d.ok)
            lost.add_metric([d.device_id, d.kind], d.lost)
            dup.add_metric([d.device_id, d.kind], d.duplicates)
            loss.add_metric([d.device_id, d.kind], d.lost / (d.ok + d.lost) if d.ok + d.lost else 0.0)
        yield from (ok, lost, dup, loss)
        rejects = CounterMetricFamily("rig_rejects", "Rejected packets by reason", labels=["reason"])
        for reason, n in sorted(snap.rejected.items()):
            rejects.add_metric([reason], n)
        yield rejects
        restarts = CounterMetricFamily("rig_filter_restarts", "Fusion filter restarts by device kind and reason",
                                       labels=["kind", "reason"])  # fmt: skip
        per_kind: dict[tuple[str, str], int] = {}
        for d in snap.devices:
            for reason, n in d.filter_restarts.items():
                per_kind[(d.kind, reason)] = per_kind.get((d.kind, reason), 0) + n
        for (kind, reason), n in sorted(per_kind.items()):
            restarts.add_metric([kind, reason], n)
        yield restarts
        active = GaugeMetricFamily("rig_alarms_active", "Active alarms by type and severity",
                                   labels=["type", "severity"])  # fmt: skip
        counts: dict[tuple[str, str], int] = {}
        for a in svc.pipeline.engine.active():
            counts[(a.type, a.severity.value)] = counts.get((a.type, a.severity.value), 0) + 1
        for (alarm_type, sev), n in sorted(counts.items()):
            active.add_metric([alarm_type, sev], n)
        yield active
        online = GaugeMetricFamily("rig_devices_online", "Devices holding a liveliness token")
        online.add_metric([], sum(p.online for p in svc.presence.devices.values()))
        yield online


class StreamCollector(Collector):
    """The dashboard stream (`/ws/stream`, app.state.live once started): clients and frames dropped for slow ones."""

    def __init__(self, app: Any) -> None:
        self.app = app

    def collect(self) -> Iterator[Any]:
        live = getattr(self.app.state, "live", None)
        clients = GaugeMetricFamily("rig_ws_clients", "Dashboard websocket clients connected")
        dropped = GaugeMetricFamily("rig_ws_dropped_frames", "Frames dropped for slow clients (connected clients)")
        clients.add_metric([], len(live.clients) if live is not None else 0)
        dropped.add_metric([], sum(c.dropped for c in live.clients) if live is not None else 0)
        yield clients
        yield dropped


class Metrics:
    """One registry per app (tests build many apps in one process)."""

    def __init__(self, service: GatewayService, clock: Any = time.time, app: Any = None) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self.registry.register(ServiceCollector(service))
        if app is not None:
            self.registry.register(StreamCollector(app))
        self.latency = BatchedHistogram("rig_sample_to_publish_seconds",
                                        "Device wall time of a sample -> gateway publish", ["kind", "topic"],
                                        LATENCY_BUCKETS_S)  # fmt: skip
        self.registry.register(self.latency)
        self.clock = clock
        service.hub.listeners.append(self.on_hub)

    @listens_to("attitude", "alarm")
    def on_hub(self, topic: str, model: schemas.WireModel) -> None:
        """Hub listener (ingest task): one observation per attitude / alarm with a device wall time."""
        if isinstance(model, schemas.Attitude) and model.wall_t_us is not None:
            self.latency.observe((model.kind, "attitude"), self.clock() - model.wall_t_us / 1e6)
        elif isinstance(model, schemas.AlarmEvent) and model.source_wall_us is not None:
            self.latency.observe((model.kind, "alarm"), (model.wall_t_us - model.source_wall_us) / 1e6)


def start_metrics(app: Any, service: GatewayService) -> Metrics:
    """Lifespan hook: keep the app's Metrics on app.state."""
    m = Metrics(service, app=app)
    app.state.metrics = m
    return m


@router.get("/metrics", response_class=Response, responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}})
async def metrics(request: Request) -> Response:
    """Prometheus text exposition: ingest rates (rate() of the counters), loss, rejects by reason, latency
    histogram, active alarms, filter restarts per device kind. Async: the collectors read the ingest task's counters
    and alarm engine on the event loop, between batches (a worker thread could read them mid-change)."""
    m: Metrics | None = getattr(request.app.state, "metrics", None)
    if m is None:
        return Response("# gateway starting\n", media_type=CONTENT_TYPE_LATEST, status_code=503)
    return Response(generate_latest(m.registry), media_type=CONTENT_TYPE_LATEST)
