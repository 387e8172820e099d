"""Devices: list and live state."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, HTTPException

from gateway.api.deps import DeviceIdPath, ServiceDep
from gateway.ingest.runner import GatewayService

router = APIRouter(prefix="/devices", tags=["devices"])


def device_view(service: GatewayService, device_id: str, *, detail: bool) -> dict[str, Any]:
    """Live state of one device: presence, last packet age, stream counters, attitude / readings."""
    pl = service.pipeline
    kind = pl.kinds[device_id]
    stream = service.counters.devices.get(device_id)
    mono = time.monotonic()
    out: dict[str, Any] = {
        "device_id": device_id,
        "kind": kind,
        "online": service.presence.online(device_id),
        "last_packet_age_s": None if stream is None or stream.last_arrival_s is None else mono - stream.last_arrival_s,
        "loss_fraction": 0.0 if stream is None else stream.loss_fraction(),
        "filter": pl.effective(kind, device_id)[0] if kind != "ball" else None,
        "active_alarms": [a.type for a in pl.engine.active(device_id)],
    }
    dev = pl.devices.get(device_id)
    if dev is not None:
        out["attitude"] = {
            "quat_wxyz": [float(x) for x in dev.quat], "roll_rad": float(dev.euler[0]),
            "pitch_rad": float(dev.euler[1]), "yaw_rad": float(dev.euler[2]), "yaw_unwrapped_rad": dev.yaw_unwrapped,
            "t_us": dev.t_us, "seq": dev.seq,
        }  # fmt: skip
        if dev.swing is not None:
            out["swing"] = dev.swing.model_dump()
        if dev.height is not None:
            out["height"] = dev.height.model_dump()
        if kind == "rod":
            out["auto_reel"] = pl.auto_reel.get(device_id, False)
    if device_id in pl.env:
        out["readings"] = pl.env[device_id].model_dump(exclude={"profile"} if not detail else set())
    if device_id in pl.reel:
        out["reel"] = pl.reel[device_id][0].model_dump()
    if detail:
        out["gyro_bias_rad_s"] = pl.bias_rad_s(device_id)
        if stream is not None:
            t = stream.main()
            out["stream"] = {"ok": t.ok, "lost": t.lost, "duplicates": t.duplicates, "reordered": t.reordered,
                             "reboots": t.reboots, "rejected": dict(stream.rejected),
                             "filter_restarts": dict(stream.filter_restarts)}  # fmt: skip
    return out


@router.get("")
async def list_devices(service: ServiceDep) -> list[dict[str, Any]]:
    """Every device seen (data or liveliness) or configured."""
    return [device_view(service, d, detail=False) for d in sorted(service.pipeline.kinds)]


@router.get("/{device_id}")
async def get_device(device_id: DeviceIdPath, service: ServiceDep) -> dict[str, Any]:
    """Live state of one device, with stream counters and the gyro bias estimate."""
    if device_id not in service.pipeline.kinds:
        raise HTTPException(404, f"unknown device {device_id!r}")
    return device_view(service, device_id, detail=True)
