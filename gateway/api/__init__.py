"""REST API of the gateway: `api_router` collects the routes under /api."""

from __future__ import annotations

from fastapi import APIRouter

from gateway.api.routes import alarm_clear, alarms, config, devices, health, history, reel, spots

api_router = APIRouter()
for _r in (health.router, devices.router, config.router, alarms.router, alarm_clear.router, history.router,
           reel.router, spots.router):  # fmt: skip
    api_router.include_router(_r)
