"""The REST side of sharding: device lists and details from every shard, `/api/shards`, and config fan-out.

`install(app, node)` (gateway/app.py) registers these routes ahead of `gateway.api` so `GET /api/devices` and
`GET /api/devices/{id}` answer for the devices of all shards (each shard answers for its own over zenoh,
gateway/shard/node.py), and adds a middleware that publishes the whole configuration to the other shards after
each successful REST change of thresholds, device settings or reel mode. Alarm history needs no route: every
shard stores every shard's alarm rows.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from fastapi import APIRouter, FastAPI, HTTPException, Request, Response

from gateway import schemas
from gateway.api.deps import AlarmIdPath, DeviceIdPath, ServiceDep, WriterDep
from gateway.api.routes import alarm_clear, alarms, health, history, reel
from gateway.ingest.runner import GatewayService
from gateway.ingest.stats import merge_ingest_stats
from gateway.shard.node import CALL_TIMEOUT_S, QUERY_TIMEOUT_S, ShardNode, query

log = logging.getLogger("gateway.shard")
STATS_TIMEOUT_S = 5.0  # an overloaded shard still answers (from its zenoh thread), but may be slow to
CONFIG_PATHS = ("/api/thresholds/", "/api/devices/", "/api/rods/")  # REST writes that change the configuration


def _node(request: Request) -> ShardNode:
    node: ShardNode = request.app.state.shard
    return node


async def _query(node: ShardNode, selector: str, timeout_s: float) -> list[tuple[str, bytes]]:
    """A zenoh query from a worker thread; this shard's ingest does not hold its batches for the answer."""
    with node.service.awaiting_remote() if node.service is not None else contextlib.nullcontext():
        return await asyncio.to_thread(query, node.bus, selector, timeout_s)


async def _ask(node: ShardNode, selector: str, timeout_s: float = QUERY_TIMEOUT_S) -> list[Any]:
    replies = await _query(node, selector, timeout_s)
    return [json.loads(p) for k, p in replies if k.split("/")[2] != node.shard_id]


router = APIRouter(tags=["shards"])


# These two shadow gateway.api's routes of the same paths (registered first); the OpenAPI schema keeps those.
@router.get("/devices", include_in_schema=False)
async def list_devices_of_all_shards(request: Request) -> list[dict[str, Any]]:
    """Every device seen (data or liveliness) or configured, from every live shard (`shard`: which serves it)."""
    node = _node(request)
    rows = {d["device_id"]: d for d in node.device_list()}
    for answer in await _ask(node, "gw/shard/*/devices"):
        for d in answer:
            rows.setdefault(d["device_id"], d)
    return [rows[k] for k in sorted(rows)]


@router.get("/devices/{device_id}", include_in_schema=False)
async def get_device_from_its_shard(device_id: DeviceIdPath, request: Request) -> dict[str, Any]:
    """Live state of one device from the shard that serves it, with stream counters and the gyro bias estimate."""
    node = _node(request)
    owner = node.ownership.owner(device_id)
    if owner == node.shard_id or owner is None:
        local = await node._device(device_id)
        if local is None:
            raise HTTPException(404, f"unknown device {device_id!r}")
        return local
    answers = await _ask(node, f"gw/shard/{owner}/device/{device_id}")
    if not answers:
        raise HTTPException(404, f"unknown device {device_id!r} (shard {owner} has no state for it)")
    return answers[0]  # type: ignore[no-any-return]


@router.get("/stats", include_in_schema=False)
async def stats_of_all_shards(request: Request, service: ServiceDep) -> dict[str, Any]:
    """This shard's /api/stats (queue, batches, delays, publisher) with the ingest counters summed over every live
    shard, so a device shows up whichever shard serves it; per-shard figures are in /api/shards."""
    node = _node(request)
    local = await health.stats(service)
    others = await _ask(node, "gw/shard/*/stats", STATS_TIMEOUT_S)
    fields = schemas.IngestStats.model_fields
    parts = [schemas.IngestStats.model_validate({k: v for k, v in d.items() if k in fields}) for d in (local, *others)]
    merged = merge_ingest_stats(parts)
    assert merged is not None
    return {**local, **merged.model_dump(exclude={"shard"}), "shards": len(parts)}


@router.get("/shards")
async def list_shards(request: Request) -> dict[str, Any]:
    """The live shards with their ingest counters (`owned` devices, `ignored` packets of the others' devices)."""
    node = _node(request)
    shards = [node.stats(), *await _ask(node, "gw/shard/*/stats", STATS_TIMEOUT_S)]
    shards.sort(key=lambda s: str(s["shard"]))
    return {"me": node.shard_id, "live": sorted(node.ownership.live), "shards": shards}


async def _forward(node: ShardNode, owner: str, call: dict[str, Any]) -> dict[str, Any]:
    """Run a write on the shard that serves its device (`ShardNode.run_call` there) and answer as it did."""
    selector = f"gw/shard/{owner}/call/{json.dumps(call, separators=(',', ':')).encode().hex()}"
    replies = await _query(node, selector, CALL_TIMEOUT_S + 1.0)
    if not replies:
        raise HTTPException(503, f"shard {owner} (which serves the device) did not answer")
    answer = json.loads(replies[0][1])
    if answer["status"] != 200:
        raise HTTPException(answer["status"], answer.get("detail"))
    return answer["body"]  # type: ignore[no-any-return]


def _other_owner(node: ShardNode, device_id: str) -> str | None:
    """The live shard that serves `device_id` when it is not this one (None: this one, or none at all)."""
    owner = node.ownership.owner(device_id)
    return None if owner in (None, node.shard_id) else owner


# Writes that change a device's live state run on the shard that serves it (its owner task and engine).
@router.post("/rods/{device_id}/reel", include_in_schema=False)
async def reel_on_its_shard(device_id: DeviceIdPath, body: reel.ReelRequest, request: Request, service: ServiceDep,
                            who: WriterDep) -> dict[str, Any]:  # fmt: skip
    owner = _other_owner(_node(request), device_id)
    if owner is None:
        return await reel.reel(device_id, body, service, who)
    call = {"op": "reel", "device_id": device_id, "body": body.model_dump(exclude_none=True), "who": who}
    return await _forward(_node(request), owner, call)


async def _alarm_shard(node: ShardNode, service: GatewayService, alarm_id: str) -> str | None:
    """The other shard that serves the device of a stored alarm (every shard stores every shard's rows)."""
    stored = await asyncio.to_thread(service.store.get_alarm, alarm_id)
    return None if stored is None else _other_owner(node, stored.device_id)


LocalAlarmWrite = Callable[[str, GatewayService, str], Awaitable[dict[str, Any]]]


async def _alarm_write(op: str, local: LocalAlarmWrite, alarm_id: str, request: Request, service: GatewayService,
                       who: str) -> dict[str, Any]:  # fmt: skip
    """Ack or clear here when this shard serves the alarm's device, else on the shard that does."""
    owner = await _alarm_shard(_node(request), service, alarm_id)
    if owner is None:
        return await local(alarm_id, service, who)
    return await _forward(_node(request), owner, {"op": op, "alarm_id": alarm_id, "who": who})


@router.post("/alarms/{alarm_id}/ack", include_in_schema=False)
async def ack_on_its_shard(alarm_id: AlarmIdPath, request: Request, service: ServiceDep,
                           who: WriterDep) -> dict[str, Any]:  # fmt: skip
    return await _alarm_write("ack", alarms.ack_alarm, alarm_id, request, service, who)


@router.post("/alarms/{alarm_id}/clear", include_in_schema=False)
async def clear_on_its_shard(alarm_id: AlarmIdPath, request: Request, service: ServiceDep,
                             who: WriterDep) -> dict[str, Any]:  # fmt: skip
    return await _alarm_write("clear", alarm_clear.clear_alarm, alarm_id, request, service, who)


# History is kept by the shard that serves the device (it gets every output); the others ask it.
@router.get("/history", include_in_schema=False)
async def history_of_all_shards(request: Request, seconds: history.Seconds = 300.0,
                                max_points: history.MaxPoints = 60) -> dict[str, Any]:  # fmt: skip
    node = _node(request)
    out = await history.all_history(request, seconds, max_points)
    out["devices"] = {d: cols for d, cols in out["devices"].items() if _other_owner(node, d) is None}
    for answer in await _ask(node, f"gw/shard/*/history_all/{seconds:g}/{max_points}"):
        out["devices"].update(answer["devices"])
    out["devices"] = dict(sorted(out["devices"].items()))
    return out


@router.get("/history/{device_id}", include_in_schema=False)
async def history_from_its_shard(device_id: DeviceIdPath, request: Request, seconds: history.Seconds = 600.0,
                                 max_points: history.MaxPoints = 4000) -> dict[str, Any]:  # fmt: skip
    node = _node(request)
    owner = _other_owner(node, device_id)
    if owner is not None:
        answers = await _ask(node, f"gw/shard/{owner}/history/{device_id}/{seconds:g}/{max_points}")
        if answers:
            return answers[0]  # type: ignore[no-any-return]
    return await history.device_history(device_id, request, seconds, max_points)


def _forwarded(node: ShardNode, path: str) -> bool:
    """A reel request another shard ran (`reel_on_its_shard`): that shard publishes its configuration, this one's
    would undo the mode change."""
    parts = path.split("/")  # "", "api", "rods", id, "reel"
    return path.startswith("/api/rods/") and len(parts) > 3 and _other_owner(node, parts[3]) is not None


def install(app: FastAPI) -> None:
    """Routes (before gateway.api's, which they override) and the config fan-out middleware; the lifespan sets
    `app.state.shard`."""
    app.include_router(router, prefix="/api")

    @app.middleware("http")
    async def fan_out_config(request: Request, call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        response = await call_next(request)
        node: ShardNode | None = getattr(request.app.state, "shard", None)
        if (node is not None and request.method in ("PUT", "POST", "DELETE") and response.status_code < 300
                and request.url.path.startswith(CONFIG_PATHS) and node.service is not None
                and not _forwarded(node, request.url.path)):  # fmt: skip
            try:
                async with node.service.config_lock:
                    node.publish_config()
            except Exception:
                log.exception("configuration change not sent to the other shards")
        return response
