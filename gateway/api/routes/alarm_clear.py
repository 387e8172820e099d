"""Manual clear of an alarm (token): for a stale alarm whose condition can no longer clear it, e.g. a drop-back
that stayed active across a restart or a device-offline alarm of a device that was taken away for good."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from typing import Any

from fastapi import APIRouter, HTTPException

from gateway.alarm.engine import AlarmStatus
from gateway.api.deps import AlarmIdPath, ServiceDep, WriterDep
from gateway.api.routes.alarms import alarm_json

router = APIRouter(prefix="/alarms", tags=["alarms"])


@router.post("/{alarm_id}/clear")
async def clear_alarm(alarm_id: AlarmIdPath, service: ServiceDep, who: WriterDep) -> dict[str, Any]:
    """Clear an active alarm by hand; it is published as `cleared` like any other clear. 404 if it is not active.

    The engine is the authority: the ingest task clears it there (a command), publishes and stores the row."""
    now = time.time()
    alarm = await service.call(lambda: service.clear_alarm(alarm_id, who, now))
    if alarm is None:
        stored = await asyncio.to_thread(service.store.get_alarm, alarm_id)
        if stored is None or not stored.active:
            raise HTTPException(404, f"no active alarm {alarm_id!r}")
        # active in the store only (the engine never resumed it): clear the row directly
        row = replace(stored, status=AlarmStatus.CLEARED, cleared_at=now, updated_at=now,
                      message=f"{stored.message}; cleared by hand ({who})")  # fmt: skip
        await service.call(lambda: service.publish_stored_alarm("cleared", row, now))
        alarm = row
    # the store row follows from the writer thread a moment later
    return alarm_json(alarm)
