"""Health and ingest statistics."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Request

from gateway.api.deps import ServiceDep

router = APIRouter(tags=["health"])


@router.get("/health")
async def health(service: ServiceDep, request: Request) -> dict[str, Any]:
    """Liveness: `ok`, or `degraded` with `reasons` (e.g. store writes failing: alarms are still published and their
    rows wait in the writer's journal); `ready` is false while the gateway warms up (fusion kernels loading, ingest
    not started yet); uptime, devices online, zenoh mode and endpoints, the store writer's state."""
    s = service.settings
    store = service.writer.status()
    reasons = [store["reason"]] if store["reason"] else []
    status = "degraded" if reasons else "ok"
    if service.warming_since_s is not None:  # packets are queued, not yet processed
        reasons.append(f"preparing fusion kernels for {time.time() - service.warming_since_s:.0f} s "
                       "(the first start after install compiles them)")  # fmt: skip
        status = "starting"
    return {
        "status": status,
        "reasons": reasons,
        "ready": bool(getattr(request.app.state, "ready", False)),
        "store": {k: v for k, v in store.items() if k != "reason"},
        "uptime_s": round(time.time() - service.started_s, 3),
        "devices_online": sum(p.online for p in service.presence.devices.values()),
        "zenoh": {"mode": s.zenoh_mode, "listen": s.zenoh_listen, "connect": s.zenoh_connect},
    }


@router.get("/stats")
async def stats(service: ServiceDep) -> dict[str, Any]:
    """Ingest counters (same as `gw/diag/ingest`) plus queue depth, batches processed, the blocking-put queue and the
    owner's command queue. Reads on the event loop between batches (a batch never yields): never waits for ingest."""
    snap = service.counters.snapshot(int(time.time() * 1e6)).model_dump()
    if service.inbox is not None:
        snap["queue_drops"] = service.inbox.drops
        snap["queue_depth"] = len(service.inbox)
        snap["offered"] = service.inbox.offered
    snap["batches"] = service.batches
    delays = sorted(service.batch_delay_s)
    if delays:  # arrival of a batch's oldest packet -> its results handed to zenoh, last 2000 batches
        snap["batch_delay_ms"] = {
            "p50": 1e3 * delays[len(delays) // 2], "p99": 1e3 * delays[min(len(delays) - 1, int(0.99 * len(delays)))],
            "max": 1e3 * delays[-1], "n": len(delays),
        }  # fmt: skip
    snap["published"] = service.hub.published
    snap["unmatched"] = service.hub.unmatched  # attitude / height messages no subscriber took: not encoded, not put
    publisher = service.hub.publisher
    if publisher is not None:  # BLOCK puts (alarms, swing, reel commands) waiting for a slow subscriber, and dropped
        snap["blocking_puts"] = {"queued": len(publisher), "dropped": publisher.dropped, "failures": publisher.failures}
    snap["commands"] = {"queued": len(service.commands), "ran": service.commands.ran}  # owner task's command queue
    snap["batch_limit"] = service.batch_limit()  # packets the next batch may take (sized to `batch_budget_s`)
    snap["invalid_tokens"] = service.presence.invalid_tokens  # liveliness tokens with a bad key (ignored)
    return snap
