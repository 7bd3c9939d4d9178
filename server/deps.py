"""Request dependencies: the store, the settings, and the bearer-token check for writes."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from worker.store import JobStore

from .settings import ServerSettings

_bearer = HTTPBearer(auto_error=False, description="Needed for POST requests when MODSAT_API_TOKEN is set.")


def get_store(request: Request) -> JobStore:
    return request.app.state.store


def get_settings(request: Request) -> ServerSettings:
    return request.app.state.settings


StoreDep = Annotated[JobStore, Depends(get_store)]
SettingsDep = Annotated[ServerSettings, Depends(get_settings)]


def require_token(
    settings: SettingsDep, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
) -> None:
    """Writes need ``Authorization: Bearer <MODSAT_API_TOKEN>`` when that setting is set."""
    if settings.api_token is None:
        return
    expected = settings.api_token.get_secret_value().encode()
    given = (creds.credentials if creds and creds.scheme.lower() == "bearer" else "").encode()
    if not given or not secrets.compare_digest(given, expected):
        raise HTTPException(
            status_code=401,
            detail="this server needs a bearer token for writes: send 'Authorization: Bearer <token>' "
            "(the value of MODSAT_API_TOKEN)"
            if not given
            else "the bearer token is not the right one",
            headers={"WWW-Authenticate": "Bearer"},
        )


WriteAccess = Depends(require_token)
