"""Devices: list and live state."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException

from gateway.api.deps import DeviceIdPath, ServiceDep
from gateway.views import device_view

router = APIRouter(prefix="/devices", tags=["devices"])


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
