"""Composition root: `create_app(settings)` wires store, token, bus, service and routes; nothing else."""

from __future__ import annotations

import logging
import sqlite3
import sys
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from gateway import view3d
from gateway.api import api_router, ws
from gateway.api.security import BrowserGuard
from gateway.config import Settings
from gateway.errors import BadSettings, UnknownDevice
from gateway.ingest.bus import Bus, ZenohBus
from gateway.ingest.runner import GatewayService
from gateway.store import ApiToken, Store, ensure_token

log = logging.getLogger("gateway")
WEB_DIR = Path(__file__).resolve().parent.parent / "web"
PLACEHOLDER = """<!doctype html><title>rig-gateway</title><h1>rig-gateway</h1>
<p>The dashboard is not installed yet. See the <a href="/docs">REST API</a>, <a href="/api/devices">devices</a>,
<a href="/api/alarms">alarms</a>, <a href="/api/spots">spots</a>, <a href="/api/stats">ingest statistics</a>.</p>"""


def create_app(
    settings: Settings, bus_factory: Callable[[Settings], Bus] = ZenohBus.open, *, warm_up: bool = True
) -> FastAPI:
    """The gateway as an ASGI app; the bus opens (and always closes) in the lifespan. `warm_up` compiles the
    fusion kernels before ingest starts (in-process tests that already compiled them may skip it)."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = Store(settings.db_path)
        token, created = ensure_token(settings.data_dir)
        if created:  # shown once; afterwards read it from the 0600 file
            print(f"API token (shown once, also in {settings.data_dir / 'api_token'}): {token}", file=sys.stderr)
        app.state.token = ApiToken(token)
        bus = bus_factory(settings)
        service = GatewayService(settings, bus, store)
        app.state.service = service
        try:
            # Kernels compile before the first packet is processed, not on it (cached in __pycache__ after the first
            # start), but in the background: REST and presence answer meanwhile (a SIGKILLed gateway is back in
            # seconds), packets wait in the bounded inbox.
            await service.start(warm_up=warm_up)
            ws.start_live(app, service)
            yield
        finally:
            await ws.stop_live(app)
            view3d.stop_view3d(app)
            await service.stop()
            bus.close()
            store.close()

    app = FastAPI(title="rig-gateway", lifespan=lifespan)
    app.add_middleware(BrowserGuard, allowed_hosts=settings.allowed_hosts)  # Host check, CSP, frame options
    app.include_router(api_router, prefix="/api")
    app.include_router(ws.router)
    app.include_router(view3d.router)

    @app.exception_handler(BadSettings)
    async def bad_settings(_: Request, exc: BadSettings) -> JSONResponse:
        return JSONResponse({"detail": exc.errors}, status_code=422)

    @app.exception_handler(sqlite3.Error)
    async def store_failed(_: Request, exc: sqlite3.Error) -> JSONResponse:  # e.g. disk full on a REST write
        log.error("store error on a REST request: %s", exc)
        return JSONResponse({"detail": f"storage unavailable: {exc}"[:300]}, status_code=503)

    @app.exception_handler(UnknownDevice)
    async def unknown_device(_: Request, exc: UnknownDevice) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=404)

    if (WEB_DIR / "index.html").is_file():
        app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    else:
        app.add_api_route("/", lambda: HTMLResponse(PLACEHOLDER), include_in_schema=False)
    return app
