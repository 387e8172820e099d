"""Alarm history (filtered, paged) and acknowledgement. `id` is the `alarm_id` of the wire AlarmEvent."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query

from gateway.alarm.engine import Alarm, AlarmStatus, Severity
from gateway.api.deps import AlarmIdPath, DeviceIdQuery, ServiceDep, WriterDep

router = APIRouter(prefix="/alarms", tags=["alarms"])
READ_WAIT_S = 1.0  # longest wait for pending alarm writes before a read (the store may be failing)
MAX_OFFSET = 2**53  # SQLite integers stop at 2**63 - 1: a larger OFFSET was a 500


def alarm_json(a: Alarm) -> dict[str, Any]:
    return {
        "id": a.id, "device_id": a.device_id, "type": a.type,
        "severity": a.severity.value, "status": a.status.value, "acknowledged": a.acknowledged,
        "started_at": a.started_at, "updated_at": a.updated_at, "cleared_at": a.cleared_at,
        "acknowledged_at": a.acknowledged_at, "acknowledged_by": a.acknowledged_by, "value": a.value,
        "peak": a.peak, "threshold": a.threshold, "count": a.count, "message": a.message, "details": dict(a.details),
    }  # fmt: skip


@router.get("")
def list_alarms(
    service: ServiceDep,
    device_id: DeviceIdQuery = None,
    type: Annotated[str | None, Query(max_length=64)] = None,
    status: AlarmStatus | None = None,
    severity: Severity | None = None,
    acknowledged: bool | None = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
) -> dict[str, Any]:
    """Alarms newest first; `total` counts every match, `items` is one page."""
    service.writer.flush(READ_WAIT_S)  # read what ingest has handed the writer so far (unless the store is failing)
    rows, total = service.store.list_alarms(device_id, type, status, severity, acknowledged, limit=limit, offset=offset)
    return {"total": total, "limit": limit, "offset": offset, "items": [alarm_json(a) for a in rows],
            "counts": service.store.counts(device_id)}  # fmt: skip


@router.post("/{alarm_id}/ack")
async def ack_alarm(alarm_id: AlarmIdPath, service: ServiceDep, who: WriterDep) -> dict[str, Any]:
    """Acknowledge an alarm (it stays active until its condition clears); published on its alarm key with
    `state: acknowledged`. An already acknowledged alarm is returned unchanged.

    The alarm engine is the authority: the ingest task acknowledges it there (a command), publishes the event and
    hands the row to the store writer. An alarm the engine no longer holds (cleared) is acknowledged from its
    stored row the same way."""
    now = time.time()
    alarm = await service.call(lambda: service.acknowledge_alarm(alarm_id, who, now))
    if alarm is not None:
        return alarm_json(alarm)
    await asyncio.to_thread(service.writer.flush, READ_WAIT_S)  # the newest row of it, if one is pending
    stored = await asyncio.to_thread(service.store.get_alarm, alarm_id)
    if stored is None:
        raise HTTPException(404, f"unknown alarm {alarm_id!r}")
    if stored.acknowledged:
        return alarm_json(stored)
    acked = replace(stored, acknowledged=True, acknowledged_at=now, acknowledged_by=who, updated_at=now)
    await service.call(lambda: service.publish_stored_alarm("acknowledged", acked, now))
    return alarm_json(acked)
