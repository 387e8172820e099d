"""FastAPI dependencies (Annotated aliases): the running service and the bearer-token guard for writes."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Path, Query, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from gateway import schemas
from gateway.ingest.runner import GatewayService
from gateway.store import ApiToken

_bearer = HTTPBearer(auto_error=False, description="The token printed at first start (file <data_dir>/api_token).")


def get_service(request: Request) -> GatewayService:
    service: GatewayService = request.app.state.service
    return service


def require_token(
    request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
) -> str:
    """401 without a bearer token, 403 with a wrong one; returns who acted (for alarm acks)."""
    token: ApiToken = request.app.state.token
    if creds is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token", {"WWW-Authenticate": "Bearer"})
    if not token.verify_token(creds.credentials):
        raise HTTPException(status.HTTP_403_FORBIDDEN, "invalid token")
    return "api"


ServiceDep = Annotated[GatewayService, Depends(get_service)]
WriterDep = Annotated[str, Depends(require_token)]

DeviceIdPath = Annotated[
    str, Path(pattern=schemas.DEVICE_ID_PATTERN, max_length=64, description="1-64 of A-Z a-z 0-9 _ -")
]
"""A device id in a route path: anything else is a 422 before the route runs (it could not name a zenoh key)."""
DeviceIdQuery = Annotated[
    str | None, Query(pattern=schemas.DEVICE_ID_PATTERN, max_length=64, description="1-64 of A-Z a-z 0-9 _ -")
]
AlarmIdPath = Annotated[str, Path(pattern=schemas.DEVICE_ID_PATTERN, max_length=64)]
