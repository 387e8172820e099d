"""Composition root: `compose` builds the gateway's parts (store writer, blocking-put publisher, hub, pipeline,
ingest service) and hands them to each other; `create_app(settings)` adds token, bus, the hub's sinks (dashboard
history and live stream, metrics, 3-D view) and routes; nothing else."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sqlite3
import sys
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

from gateway import view3d
from gateway.api import api_router, ws
from gateway.api.priority import RestInFlight
from gateway.api.routes import history, metrics
from gateway.api.routes.docs import API_DESCRIPTION, install_openapi, install_redoc
from gateway.api.security import BrowserGuard
from gateway.config import Settings
from gateway.errors import BadSettings, UnknownDevice
from gateway.hub import Hub
from gateway.ingest.bus import Bus
from gateway.ingest.publisher import BlockingPublisher
from gateway.ingest.runner import BATCH_BUDGET_S, GatewayService, build_pipeline
from gateway.pipeline import PipelineSettings
from gateway.shard import routes as shard_routes
from gateway.shard.launch import default_shard_id
from gateway.shard.node import ShardNode, open_bus
from gateway.store import ApiToken, Store, StoreWriter, ensure_token

log = logging.getLogger("gateway")
WEB_DIR = Path(__file__).resolve().parent.parent / "web"
PLACEHOLDER = """<!doctype html><title>rig-gateway</title><h1>rig-gateway</h1>
<p>The dashboard is not installed yet. See the <a href="/docs">REST API</a>, <a href="/api/devices">devices</a>,
<a href="/api/alarms">alarms</a>, <a href="/api/spots">spots</a>, <a href="/api/stats">ingest statistics</a>.</p>"""


def compose(
    settings: Settings, bus: Bus, store: Store, pipeline_settings: PipelineSettings | None = None,
    *, blocking_thread: bool = True, max_batch: int = 2000, diag_period_s: float = 1.0,
    batch_budget_s: float = BATCH_BUDGET_S, writer_factory: Callable[[Store], StoreWriter] = StoreWriter,
) -> GatewayService:  # fmt: skip
    """The ingest side, wired: one `StoreWriter` thread (every store write), the hub publishing through a
    `BlockingPublisher` thread (BLOCK puts never stall ingest; `blocking_thread=False` puts them inline, for
    tests that read a MemoryBus right after `handle`), the pipeline loaded from the store, and the service whose
    ingest task owns them (`max_batch`, `diag_period_s`, `batch_budget_s`: see GatewayService)."""
    writer = writer_factory(store)  # a shard's mirrors alarm rows to the other shards (gateway/shard)
    hub = Hub(bus, writer, BlockingPublisher(bus) if blocking_thread else None)
    pipeline = build_pipeline(settings, store, pipeline_settings)
    pipeline.taker = hub.taker  # heights nobody subscribes to are not made
    return GatewayService(settings, bus, store, pipeline, hub, max_batch=max_batch, diag_period_s=diag_period_s,
                          batch_budget_s=batch_budget_s)  # fmt: skip


def create_app(
    settings: Settings,
    bus_factory: Callable[[Settings], Bus] = open_bus,
    *,
    warm_up: bool = True,
    start_view3d: bool = False,
    on_ready: Callable[[], None] | None = None,
    adopt_config: bool = False,
    announce: bool = True,
) -> FastAPI:
    """The gateway as an ASGI app; the bus opens (and always closes) in the lifespan.

    `warm_up`: compile the fusion kernels (numba, cached after the first time) before ingest starts. The HTTP
    server does not wait for it: the lifespan returns at once, the dashboard shows "warming up" (`GET
    /api/health` -> `ready: false`) and ingest starts when the kernels are ready. Without `warm_up` (in-process
    tests that already compiled them) ingest starts before the lifespan returns. `start_view3d`: start the viser
    3-D server with the gateway (else on the first `GET /view3d`). The URLs are printed when ready (not with
    `announce=False`: a local shard child, whose parent's URLs and token are the ones to use), then `on_ready`
    is called (on the event loop; `python -m gateway --with-devices` starts the simulators there, so they do not
    compete with the warm-up for the CPU). The gateway is one shard of however many share the devices over zenoh
    (gateway/shard); `adopt_config`: wait for an older shard's configuration (a local shard of `--shards N`)."""

    async def start(app: FastAPI, service: GatewayService) -> None:
        t0 = time.perf_counter()
        view_task = asyncio.create_task(view3d.start_view3d(app)) if start_view3d else None
        await app.state.shard.start(adopt_config)  # live shards, ownership, shared configuration
        # Subscriptions, presence and REST work at once (a SIGKILLed gateway sees its devices again in seconds);
        # with `warm_up` the ingest task first loads the fusion kernels in a thread (compiled once after install,
        # cached in __pycache__; scripts/env.sh does it) and packets wait in the bounded inbox meanwhile.
        await service.start(warm_up=warm_up)
        shard: ShardNode = app.state.shard  # other shards' devices on this endpoint's stream and history routes
        ws.start_live(app, service).peers = shard.peers
        shard.history = history.start_history(app, service)
        while service.warming_since_s is not None:
            await asyncio.sleep(0.1)
        if view_task is not None:
            try:
                await view_task
            except Exception:  # a busy port or a viser failure must not stop ingest
                log.exception("3-D view did not start")
        app.state.ready = True
        log.info("ready in %.1f s", time.perf_counter() - t0)
        if announce:  # printed, not logged: the URLs are shown whatever --log-level says (like the API token)
            print("rig-gateway ready\n" + "\n".join(ready_lines(settings, app)), file=sys.stderr, flush=True)
        if on_ready is not None:
            on_ready()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = Store(settings.db_path)
        token, created = ensure_token(settings.data_dir)
        if created and announce:  # shown once; afterwards read it from the 0600 file
            print(f"API token (shown once, also in {settings.data_dir / 'api_token'}): {token}", file=sys.stderr)
        app.state.token = ApiToken(token)
        app.state.ready = False
        bus = bus_factory(settings)
        shard = ShardNode(settings, bus, settings.shard_id or default_shard_id(settings))
        service = compose(settings, bus, store, writer_factory=shard.writer_factory)
        shard.attach(service)
        shard.mirror_demand = lambda: view3d.has_clients(app)  # other shards' attitudes: only for a 3-D view client
        app.state.service, app.state.shard = service, shard
        metrics.start_metrics(app, service)
        starting: asyncio.Task[None] | None = None
        try:
            if warm_up:
                starting = asyncio.create_task(start(app, service))
                if announce:
                    log.info("dashboard http://%s:%d/ (warming up)", _link_host(settings.http_host),
                             settings.http_port)  # fmt: skip
            else:
                await start(app, service)
            yield
        finally:
            if starting is not None and not starting.done():
                starting.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await starting
            await ws.stop_live(app)
            await history.stop_history(app)
            view3d.stop_view3d(app)
            await shard.stop()
            await service.stop()
            bus.close()
            store.close()

    # Swagger UI and ReDoc from the files fastapi-offline ships (no CDN): the docs work on a rig without internet
    app = FastAPIOffline(title="rig-gateway", lifespan=lifespan, description=API_DESCRIPTION, redoc_url=None,
                         swagger_ui_parameters={"persistAuthorization": True})  # the token survives a reload
    app.add_middleware(BrowserGuard, allowed_hosts=settings.allowed_hosts)  # Host check, CSP, frame options
    app.add_middleware(RestInFlight)  # ingest lets HTTP requests finish between batches
    shard_routes.install(app)  # before api_router: device lists and details from every shard
    app.include_router(api_router, prefix="/api")
    app.include_router(ws.router)
    app.include_router(metrics.router)
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

    install_openapi(app)
    install_redoc(app)
    if (WEB_DIR / "index.html").is_file():
        app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    else:
        app.add_api_route("/", lambda: HTMLResponse(PLACEHOLDER), include_in_schema=False)
    return app


def _link_host(host: str) -> str:
    return "127.0.0.1" if host in ("0.0.0.0", "::", "") else host


def ready_lines(settings: Settings, app: FastAPI) -> list[str]:
    """What a user opens, one URL a line (printed when the gateway is ready)."""
    base = f"http://{_link_host(settings.http_host)}:{settings.http_port}"
    view: view3d.View3D | None = getattr(app.state, "view3d", None)
    v3d = f"http://{_link_host(settings.viser_host)}:{view.port}/" if view is not None else f"{base}/view3d (on demand)"
    return [f"  dashboard  {base}/", f"  API docs   {base}/docs  (ReDoc {base}/redoc)",
            f"  metrics    {base}/metrics", f"  3D view    {v3d}"]  # fmt: skip
