"""The REST side of sharding: device lists and details from every shard, `/api/shards`, and config fan-out.

`install(app, node)` (gateway/app.py) registers these routes ahead of `gateway.api` so `GET /api/devices` and
`GET /api/devices/{id}` answer for the devices of all shards (each shard answers for its own over zenoh,
gateway/shard/node.py), and adds a middleware that publishes the whole configuration to the other shards after
each successful REST change of thresholds, device settings or reel mode. Alarm history needs no route: every
shard stores every shard's alarm rows.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from fastapi import APIRouter, FastAPI, HTTPException, Request, Response

from gateway.api.deps import DeviceIdPath
from gateway.shard.node import QUERY_TIMEOUT_S, ShardNode, query

log = logging.getLogger("gateway.shard")
STATS_TIMEOUT_S = 5.0  # an overloaded shard still answers (from its zenoh thread), but may be slow to
CONFIG_PATHS = ("/api/thresholds/", "/api/devices/", "/api/rods/")  # REST writes that change the configuration


def _node(request: Request) -> ShardNode:
    node: ShardNode = request.app.state.shard
    return node


async def _ask(node: ShardNode, selector: str, timeout_s: float = QUERY_TIMEOUT_S) -> list[Any]:
    replies = await asyncio.to_thread(query, node.bus, selector, timeout_s)
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


@router.get("/shards")
async def list_shards(request: Request) -> dict[str, Any]:
    """The live shards with their ingest counters (`owned` devices, `ignored` packets of the others' devices)."""
    node = _node(request)
    shards = [node.stats(), *await _ask(node, "gw/shard/*/stats", STATS_TIMEOUT_S)]
    shards.sort(key=lambda s: str(s["shard"]))
    return {"me": node.shard_id, "live": sorted(node.ownership.live), "shards": shards}


def install(app: FastAPI) -> None:
    """Routes (before gateway.api's, which they override) and the config fan-out middleware; the lifespan sets
    `app.state.shard`."""
    app.include_router(router, prefix="/api")

    @app.middleware("http")
    async def fan_out_config(request: Request, call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        response = await call_next(request)
        node: ShardNode | None = getattr(request.app.state, "shard", None)
        if (node is not None and request.method in ("PUT", "POST", "DELETE") and response.status_code < 300
                and request.url.path.startswith(CONFIG_PATHS) and node.service is not None):  # fmt: skip
            try:
                async with node.service.config_lock:
                    node.publish_config()
            except Exception:
                log.exception("configuration change not sent to the other shards")
        return response
