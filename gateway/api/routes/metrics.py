"""`GET /metrics`: Prometheus text format (prometheus-client), for operators' scrapers.

Counters and gauges are read from the service's own snapshots at scrape time (the ingest loop keeps owning its
state; a scrape only reads). The one histogram, sample-to-publish latency, is observed by a hub listener: the
gateway's clock when it publishes an attitude or alarm minus the device's wall time of the sample behind it
(meaningful when the device clock is synchronised, as the simulators' are).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Histogram, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from gateway import schemas
from gateway.hub import listens_to
from gateway.ingest.runner import GatewayService

router = APIRouter(tags=["health"])
LATENCY_BUCKETS_S = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


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
        self.latency = Histogram("rig_sample_to_publish_seconds", "Device wall time of a sample -> gateway publish",
                                 ["kind", "topic"], buckets=LATENCY_BUCKETS_S, registry=self.registry)  # fmt: skip
        self.clock = clock
        self._latency: dict[tuple[str, str], Any] = {}  # (kind, topic) -> its histogram child (`labels` is slow)
        service.hub.listeners.append(self.on_hub)

    def _observe(self, kind: str, topic: str, delay_s: float) -> None:
        child = self._latency.get((kind, topic))
        if child is None:
            child = self._latency[(kind, topic)] = self.latency.labels(kind, topic)
        child.observe(max(0.0, delay_s))

    @listens_to("attitude", "alarm")
    def on_hub(self, topic: str, model: schemas.WireModel) -> None:
        """Hub listener (ingest task): one observation per attitude / alarm with a device wall time."""
        if isinstance(model, schemas.Attitude) and model.wall_t_us is not None:
            self._observe(model.kind, "attitude", self.clock() - model.wall_t_us / 1e6)
        elif isinstance(model, schemas.AlarmEvent) and model.source_wall_us is not None:
            self._observe(model.kind, "alarm", (model.wall_t_us - model.source_wall_us) / 1e6)


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
