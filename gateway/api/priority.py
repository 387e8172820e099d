"""REST first between batches: an ASGI middleware counts HTTP requests in flight on the service (`rest_inflight`),
and the ingest task lets them finish before it takes the next batch (up to `GatewayService.rest_grace_s`).

Under overload the ingest task always has a batch waiting; a request needs several event-loop turns (read, route,
handler, its owner command, write), so with one turn per batch it waited for several batches (6-17 s for
/api/stats at 200 rods, issue 16). Websockets are not counted: a dashboard stream is open for hours.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Receive, Scope, Send


class RestInFlight:
    """ASGI middleware: `app.state.service.rest_inflight` += 1 while an HTTP request runs."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        service = getattr(scope["app"].state, "service", None) if scope["type"] == "http" else None
        if service is None:
            await self.app(scope, receive, send)
            return
        service.rest_inflight += 1
        try:
            await self.app(scope, receive, send)
        finally:
            service.rest_inflight -= 1
