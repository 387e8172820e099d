"""Fishing-spot ranking from the environment balls."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter

from gateway.api.deps import ServiceDep

router = APIRouter(tags=["spots"])


@router.get("/spots")
async def spots(service: ServiceDep) -> dict[str, Any]:
    """Spots best first (score 0..1) with the reasons, from the latest reading at each spot."""
    return service.pipeline.rank_spots(time.time()).model_dump()
