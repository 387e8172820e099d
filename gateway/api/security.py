"""Browser-facing guards: the Host header check (DNS rebinding), security headers (CSP, frame options), and the
Origin/token check of the live websocket.

DNS rebinding: a page on `attacker.example` whose name is re-pointed at the gateway's address can read the
gateway's responses from the victim's browser, but the browser still sends `Host: attacker.example`. So the server
answers only Host names that cannot be an attacker's: IP literals, `localhost`, dotless names (LAN hostnames) and
`.local` / `.localhost` names, plus `Settings.allowed_hosts`. Anything else gets a 421.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Iterable
from urllib.parse import urlsplit

from starlette.datastructures import Headers
from starlette.responses import PlainTextResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

CSP = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; "
       "connect-src 'self' {ws}; object-src 'none'; base-uri 'none'; form-action 'self'; "
       "frame-ancestors 'none'")  # fmt: skip
_HOST_RE = re.compile(r"(\[[0-9a-f:.]+\]|[a-z0-9.-]+)(:[0-9]{1,5})?")
MAX_BODY_BYTES = 1024 * 1024  # the largest REST body (device settings with a calibration) is a few kB
NO_CSP_PREFIXES = ("/docs", "/redoc")  # FastAPI's API docs pages load Swagger UI / ReDoc with inline script


def host_name(host_header: str) -> str:
    """`Host` header -> lower-case name without port ('[::1]:8000' -> '::1')."""
    h = host_header.strip().lower()
    if h.startswith("["):
        return h[1 : h.find("]")] if "]" in h else h
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def host_allowed(host_header: str | None, extra: Iterable[str] = ()) -> bool:
    """True for a Host an attacker's page cannot send (see module docstring)."""
    if not host_header or not _HOST_RE.fullmatch(host_header.strip().lower()):
        return False  # also keeps header text out of the CSP this host is written into
    name = host_name(host_header)
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        pass
    if name in {e.lower() for e in extra}:
        return True
    name = name.rstrip(".")
    return name == "localhost" or "." not in name or name.endswith((".local", ".localhost"))


def origin_allowed(origin: str, host_header: str | None, allowed: Iterable[str] = ()) -> bool:
    """Same origin as the page's Host (the dashboard served by the gateway), or one of `allowed`."""
    if origin in set(allowed):
        return True
    parts = urlsplit(origin)
    same = parts.netloc.lower() == (host_header or "").lower()
    return bool(host_header) and parts.scheme in ("http", "https") and same


class BrowserGuard:
    """ASGI middleware: 421 for a Host that fails `host_allowed` (HTTP and websocket), 413 for a request body over
    `MAX_BODY_BYTES`, and security headers on every HTTP response (CSP except on the API docs pages,
    X-Frame-Options, nosniff, no referrer)."""

    def __init__(self, app: ASGIApp, allowed_hosts: Iterable[str] = ()) -> None:
        self.app = app
        self.allowed_hosts = tuple(allowed_hosts)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        host = Headers(scope=scope).get("host")
        if not host_allowed(host, self.allowed_hosts):
            if scope["type"] == "websocket":
                await send({"type": "websocket.close", "code": 1008})
                return
            resp = PlainTextResponse(f"unknown host {str(host)[:100]!r}: add it with --allowed-host", status_code=421)
            await resp(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        csp = None if scope["path"].startswith(NO_CSP_PREFIXES) else CSP.format(ws=f"ws://{host} wss://{host}")

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [(b"x-frame-options", b"DENY"), (b"x-content-type-options", b"nosniff"),
                            (b"referrer-policy", b"no-referrer")]  # fmt: skip
                if csp is not None:
                    headers.append((b"content-security-policy", csp.encode("latin-1")))
                message = {**message, "headers": headers}
            await send(message)

        too_large = PlainTextResponse(f"request body over {MAX_BODY_BYTES} bytes", status_code=413)
        length = Headers(scope=scope).get("content-length")
        if length is not None and (not length.isdigit() or int(length) > MAX_BODY_BYTES):
            await too_large(scope, receive, send_with_headers)
            return
        # A body without Content-Length (chunked) is counted as it arrives: FastAPI reads a body before it checks
        # the token, so an unauthenticated client could otherwise make the server hold any amount of memory.
        state = {"received": 0, "over": False, "started": False}

        async def limited_receive() -> Message:
            message = await receive()
            if message["type"] == "http.request":
                state["received"] += len(message.get("body", b""))
                if state["received"] > MAX_BODY_BYTES:
                    state["over"] = True
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: Message) -> None:
            if state["over"]:
                return  # the app's answer to a body it never got whole
            state["started"] = True
            await send_with_headers(message)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except Exception:
            if not state["over"]:
                raise
        if state["over"] and not state["started"]:
            await too_large(scope, receive, send_with_headers)
