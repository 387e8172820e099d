"""Manual clear of an alarm (token): for a stale alarm whose condition can no longer clear it, e.g. a drop-back
that stayed active across a restart or a device-offline alarm of a device that was taken away for good."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

from fastapi import APIRouter, HTTPException

from gateway.alarm.engine import AlarmChange, AlarmStatus
from gateway.api.deps import AlarmIdPath, ServiceDep, WriterDep
from gateway.api.routes.alarms import alarm_json
from gateway.pipeline import AlarmOut, Output

router = APIRouter(prefix="/alarms", tags=["alarms"])


@router.post("/{alarm_id}/clear")
async def clear_alarm(alarm_id: AlarmIdPath, service: ServiceDep, who: WriterDep) -> dict[str, Any]:
    """Clear an active alarm by hand; it is published as `cleared` like any other clear. 404 if it is not active.

    Async on purpose: it runs on the event loop, the thread that owns the alarm engine (ingest runs there too)."""
    now = time.time()
    change = service.pipeline.engine.clear(alarm_id, who, now)
    if change is None:
        stored = service.store.get_alarm(alarm_id)
        if stored is None or not stored.active:
            raise HTTPException(404, f"no active alarm {alarm_id!r}")
        # active in the store only (the engine never resumed it): clear the row directly
        change = AlarmChange("cleared", replace(stored, status=AlarmStatus.CLEARED, cleared_at=now, updated_at=now,
                                                message=f"{stored.message}; cleared by hand ({who})"))  # fmt: skip
    kind = service.pipeline.kinds.get(change.alarm.device_id, "rod")
    service.hub.emit(Output(alarms=[AlarmOut(kind, change, int(now * 1e6), None)]))
    # the engine's record is the authority: the store row follows from the writer thread a moment later
    return alarm_json(change.alarm)
