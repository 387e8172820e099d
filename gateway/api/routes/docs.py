"""What /docs (Swagger UI) and /redoc show beyond the routes themselves: how to authenticate, the error codes
of write routes (401, 403, 422) and a curl example for every operation (ReDoc's `x-codeSamples`).

The pages themselves come from the files fastapi-offline ships (app.py), so they render without internet. ReDoc's
bundle draws one image from the internet (the Redocly logo in its menu); `/redoc` serves that bundle with the logo
pointed at an empty inline SVG, so the page makes no request that leaves the machine.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import fastapi_offline
from fastapi import FastAPI
from fastapi.openapi.docs import get_redoc_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, Response

API_DESCRIPTION = """\
REST API of the rig gateway. Reads need nothing; **writes need the API token** as a bearer token:
the token printed once at first start, also in `<data_dir>/api_token` (file mode 0600).

```sh
TOKEN=$(cat var/api_token)
curl -s http://127.0.0.1:8000/api/devices
curl -s -X POST -H "Authorization: Bearer $TOKEN" http://127.0.0.1:8000/api/alarms/ALARM_ID/ack
```

In Swagger UI press **Authorize** and paste the token; "Try it out" then sends it.

Errors of write routes: **401** no bearer token (`WWW-Authenticate: Bearer`), **403** wrong token,
**422** a body or value that fails validation (`detail` lists one readable message per problem),
**404** an unknown device or alarm. Live data: the websocket `/ws/stream` (docs/dashboard.md);
Prometheus metrics: `/metrics`.
"""

_ERROR = {"type": "object", "properties": {"detail": {"type": "string"}}}
_ERRORS: dict[str, dict[str, Any]] = {
    "401": {"description": "No bearer token: send `Authorization: Bearer <token>`",
            "content": {"application/json": {"schema": _ERROR, "example": {"detail": "missing bearer token"}}}},
    "403": {"description": "Wrong token",
            "content": {"application/json": {"schema": _ERROR, "example": {"detail": "invalid token"}}}},
    "422": {"description": "Validation failed: one readable message per problem",
            "content": {"application/json": {"example": {"detail": [
                "bite_deviation_deg: Input should be less than or equal to 45"]}}}},
}  # fmt: skip


# request bodies shown in the curl samples, by (method, path)
EXAMPLE_BODIES: dict[tuple[str, str], dict[str, Any]] = {
    ("put", "/api/thresholds/{kind}"): {"bite_deviation_deg": 10.0, "sensitivity": 3},
    ("put", "/api/devices/{device_id}/settings"): {"kind": "rod", "thresholds": {"bite_deviation_deg": 12.0}},
    ("post", "/api/rods/{device_id}/reel"): {"action": "in", "speed_m_s": 0.5},
}


def curl_sample(method: str, path: str, secured: bool, body: dict[str, Any] | None) -> str:
    """A curl line for one operation (path parameters left as {name})."""
    parts = ["curl -s"]
    if method != "get":
        parts.append(f"-X {method.upper()}")
    if secured:
        parts.append('-H "Authorization: Bearer $TOKEN"')
    if body is not None:
        parts.append(f"-H 'Content-Type: application/json' -d '{json.dumps(body)}'")
    parts.append(f"http://127.0.0.1:8000{path}")
    return " ".join(parts)


def install_openapi(app: FastAPI) -> None:
    """Build the schema once with the error responses and curl samples added to every operation."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        for path, ops in schema.get("paths", {}).items():
            for method, op in ops.items():
                secured = bool(op.get("security"))
                responses = op.setdefault("responses", {})
                if secured:
                    responses.setdefault("401", _ERRORS["401"])
                    responses.setdefault("403", _ERRORS["403"])
                    responses["422"] = {**responses.get("422", {}), **_ERRORS["422"]}
                body = EXAMPLE_BODIES.get((method, path))
                op["x-codeSamples"] = [{"lang": "Shell", "label": "curl",
                                        "source": curl_sample(method, path, secured, body)}]  # fmt: skip
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


OFFLINE_STATIC = Path(fastapi_offline.__file__).resolve().parent / "static"
REDOC_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"
EMPTY_SVG = "data:image/svg+xml,%3Csvg xmlns='http://www.w3.org/2000/svg' width='1' height='1'/%3E"


@functools.cache
def redoc_bundle() -> str:
    """fastapi-offline's ReDoc bundle with its one external image replaced (read once, on first use)."""
    return (OFFLINE_STATIC / "redoc.standalone.js").read_text(encoding="utf-8").replace(REDOC_LOGO, EMPTY_SVG)


def install_redoc(app: FastAPI, path: str = "/redoc") -> None:
    """ReDoc at `path` from the patched local bundle (create the app with `redoc_url=None`)."""

    @app.get("/redoc-assets/redoc.standalone.js", include_in_schema=False)
    async def redoc_js() -> Response:
        return Response(redoc_bundle(), media_type="application/javascript")

    @app.get(path, include_in_schema=False)
    async def redoc_page() -> HTMLResponse:
        return get_redoc_html(openapi_url=app.openapi_url or "/openapi.json", title=f"{app.title} - ReDoc",
                              redoc_js_url="/redoc-assets/redoc.standalone.js", with_google_fonts=False,
                              redoc_favicon_url="/static-offline-docs/favicon.png")  # fmt: skip
