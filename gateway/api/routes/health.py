"""Health and ingest statistics."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter

from gateway.api.deps import ServiceDep

router = APIRouter(tags=["health"])


@router.get("/health")
def health(service: ServiceDep) -> dict[str, Any]:
    """Liveness: uptime, devices online, zenoh mode and endpoints."""
    s = service.settings
    return {
        "status": "ok",
        "uptime_s": round(time.time() - service.started_s, 3),
        "devices_online": sum(p.online for p in service.presence.devices.values()),
        "zenoh": {"mode": s.zenoh_mode, "listen": s.zenoh_listen, "connect": s.zenoh_connect},
    }


@router.get("/stats")
def stats(service: ServiceDep) -> dict[str, Any]:
    """Ingest counters (same as `gw/diag/ingest`) plus queue depth and batches processed."""
    snap = service.counters.snapshot(int(time.time() * 1e6)).model_dump()
    if service.inbox is not None:
        snap["queue_drops"] = service.inbox.drops
        snap["queue_depth"] = len(service.inbox)
    snap["batches"] = service.batches
    snap["published"] = service.hub.published
    return snap
