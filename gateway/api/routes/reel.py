"""Reel control of a rod: manual in/out/stop with a speed, or the automatic fish-walking mode."""

from __future__ import annotations

import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, ConfigDict, Field

from gateway.api.deps import DeviceIdPath, ServiceDep, WriterDep
from gateway.config import DeviceSettings

router = APIRouter(prefix="/rods", tags=["reel"])


class ReelRequest(BaseModel):
    """`in`/`out`/`stop` drive the reel manually (auto off); `auto` hands it to the fish-walking controller."""

    model_config = ConfigDict(extra="forbid")

    action: Literal["in", "out", "stop", "auto"]
    speed_m_s: Annotated[float, Field(gt=0.0, le=5.0)] | None = None
    drag_n: Annotated[float, Field(ge=0.0, le=200.0)] | None = None


@router.post("/{device_id}/reel")
async def reel(device_id: DeviceIdPath, body: ReelRequest, service: ServiceDep, who: WriterDep) -> dict[str, Any]:
    """Send a ReelCommand to `rig/rod/{id}/reel/cmd` (CongestionControl.BLOCK), or switch auto mode on.

    The auto-reel state is the pipeline's: switched by the ingest task (a command); the command is published by
    the hub's blocking-put thread."""
    if service.pipeline.kinds.get(device_id) not in (None, "rod"):
        raise HTTPException(422, [f"device {device_id!r} is not a rod"])
    pl = service.pipeline
    on = body.action == "auto"

    def switch() -> tuple[bool, bool, tuple[str, DeviceSettings] | None]:
        was = pl.auto_reel.get(device_id, False)
        available = pl.set_auto_reel(device_id, on)
        return was, available, pl.device_settings.get(device_id)

    was, available, entry = await service.call(switch)
    if was != on and entry is not None:  # the mode is stored in the rod's settings, so a restart keeps it
        kind, ds = entry
        await service.store_write(lambda store: store.save_device_settings(device_id, kind, ds))
        service.writer.log_event(time.time(), "reel_auto", device_id, {"on": on, "by": who})
    if on:
        return {"device_id": device_id, "auto": True, "controller_available": available}
    cmd = await service.call(lambda: service.hub.send_reel(device_id, body.action, body.speed_m_s, body.drag_n,
                                                           sender=who))  # fmt: skip
    return {"device_id": device_id, "auto": False, "command": cmd.model_dump()}
