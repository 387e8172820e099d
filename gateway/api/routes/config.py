"""Thresholds: kind defaults and per-device settings (filter + partial threshold override). Writes need the token.

Every write is validated before anything is stored or applied; a bad value gives 422 with one readable message
per problem in `detail`.
"""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Body, HTTPException
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gateway.api.deps import DeviceIdPath, ServiceDep, WriterDep
from gateway.config import THRESHOLD_MODELS, CalibrationJson, DeviceSettings, ThresholdModel
from gateway.schemas import DeviceKind

router = APIRouter(tags=["config"])
Kind = DeviceKind


def _messages(exc: ValidationError) -> list[str]:
    return [f"{'.'.join(str(p) for p in e['loc']) or '(thresholds)'}: {e['msg']}" for e in exc.errors()]


class DeviceSettingsIn(BaseModel):
    """Settings of one device; `kind` is required the first time a device is configured before it was seen.
    `auto_reel` (rods): None keeps the current mode (also switched by `POST /api/rods/{id}/reel`). `calibration`: the
    JSON of `python -m gateway.calibrate`; left out keeps the stored one, null removes it."""

    model_config = ConfigDict(extra="forbid")

    kind: Kind | None = None
    filter_name: str | None = None
    thresholds: dict[str, Any] = Field(default_factory=dict)
    auto_reel: bool | None = None
    calibration: CalibrationJson = None


# Handlers are `async` (on the event loop; a batch never yields, so their reads see no half-done batch). They change
# the live state only through owner commands (`service.call`: the ingest task runs them between batches) and the
# store only through its one writer thread (`service.store_write`), so the loop never waits on the disk; one lock
# per service orders concurrent writes so the store and the live state end in the same order.


@router.get("/thresholds/{kind}")
async def get_defaults(kind: Kind, service: ServiceDep) -> dict[str, Any]:
    """Default thresholds of a device kind."""
    return service.pipeline.defaults[kind].model_dump()


@router.put("/thresholds/{kind}")
async def put_defaults(
    kind: Kind, body: Annotated[dict[str, Any], Body()], service: ServiceDep, _: WriterDep
) -> dict[str, Any]:
    """Replace a kind's defaults (fields left out take the built-in default); applied live and stored."""
    try:
        model = THRESHOLD_MODELS[kind].model_validate(body)
    except ValidationError as exc:
        raise HTTPException(422, _messages(exc)) from exc
    pl = service.pipeline

    def apply(new: ThresholdModel) -> ThresholdModel:
        old = pl.defaults[kind]
        pl.set_defaults(kind, new)  # BadSettings -> 422 (a device override would become invalid)
        service.config_changed()
        return old

    async with service.config_lock:
        old = await service.call(lambda: apply(model))
        try:
            await service.store_write(lambda store: store.save_defaults(kind, model))
        except Exception:  # not stored (disk full: 503): not applied either
            await service.call(lambda: apply(old))
            raise
    service.writer.log_event(time.time(), "defaults_changed", None, {"kind": kind})
    return model.model_dump()


def _kind_of(service: ServiceDep, device_id: str, given: str | None) -> str:
    kind = service.pipeline.kinds.get(device_id) or given
    if kind is None:
        raise HTTPException(422, [f"kind: unknown device {device_id!r}, give its kind (rod, hook or ball)"])
    if given is not None and given != kind:
        raise HTTPException(422, [f"kind: device {device_id!r} is a {kind}, not a {given}"])
    return kind


@router.get("/devices/{device_id}/settings")
async def get_settings(device_id: DeviceIdPath, service: ServiceDep) -> dict[str, Any]:
    """Stored settings of a device and the thresholds in effect."""
    return _settings_view(device_id, service)


def _settings_view(device_id: str, service: ServiceDep) -> dict[str, Any]:
    kind = service.pipeline.kinds.get(device_id)
    if kind is None:
        raise HTTPException(404, f"unknown device {device_id!r}")
    entry = service.pipeline.device_settings.get(device_id)
    filter_name, th = service.pipeline.effective(kind, device_id)
    return {
        "device_id": device_id, "kind": kind,
        "settings": (entry[1] if entry else DeviceSettings()).model_dump(),
        "effective": {"filter_name": filter_name, "thresholds": th.model_dump()},
    }  # fmt: skip


@router.put("/devices/{device_id}/settings")
async def put_settings(
    device_id: DeviceIdPath, body: DeviceSettingsIn, service: ServiceDep, _: WriterDep
) -> dict[str, Any]:
    """Replace a device's settings (validated against its kind's defaults), applied live and stored."""
    async with service.config_lock:
        return await _put_settings(device_id, body, service)


async def _put_settings(device_id: str, body: DeviceSettingsIn, service: ServiceDep) -> dict[str, Any]:
    kind = _kind_of(service, device_id, body.kind)
    auto = service.pipeline.auto_reel.get(device_id, False) if body.auto_reel is None else body.auto_reel
    entry = service.pipeline.device_settings.get(device_id)
    keep = entry[1].calibration if entry else None
    cal = body.calibration if "calibration" in body.model_fields_set else keep
    ds = DeviceSettings(filter_name=body.filter_name, thresholds=body.thresholds, auto_reel=auto, calibration=cal)
    service.pipeline.validate_device_settings(kind, ds)  # BadSettings -> 422
    # not stored (disk full: 503): not applied either
    await service.store_write(lambda store: store.save_device_settings(device_id, kind, ds))
    await service.call(lambda: _apply_settings(service, device_id, kind, ds))
    service.writer.log_event(time.time(), "settings_changed", device_id, ds.model_dump())
    return _settings_view(device_id, service)


@router.delete("/devices/{device_id}/settings")
async def delete_settings(device_id: DeviceIdPath, service: ServiceDep, _: WriterDep) -> dict[str, Any]:
    """Forget a device's filter and threshold overrides: it follows its kind's defaults again (auto reel and the IMU
    calibration, properties of the hardware, stay)."""
    async with service.config_lock:
        kind = _kind_of(service, device_id, None)
        entry = service.pipeline.device_settings.get(device_id)
        kept = DeviceSettings(auto_reel=service.pipeline.auto_reel.get(device_id, False),
                              calibration=entry[1].calibration if entry else None)  # fmt: skip
        keep = kept.auto_reel or kept.calibration is not None
        if keep:
            await service.store_write(lambda store: store.save_device_settings(device_id, kind, kept))
        else:
            await service.store_write(lambda store: store.delete_device_settings(device_id))
        await service.call(lambda: _apply_settings(service, device_id, kind, kept, forget=not keep))
        return _settings_view(device_id, service)


def _apply_settings(service: ServiceDep, device_id: str, kind: str, ds: DeviceSettings, forget: bool = False) -> None:
    """Owner command: put a device's settings in force (`forget`: it has no stored settings any more)."""
    service.pipeline.set_device_settings(device_id, kind, ds)
    if forget:
        service.pipeline.device_settings.pop(device_id, None)
    service.config_changed()

