"""FastAPI dependencies as typed aliases: the settings, the store, a session and the caller.

``ApiKeyDep`` authenticates the ``Authorization: Bearer <key>`` header on every route that uses
it (all but health); a missing, unknown or revoked key is a 401 that says how to get one.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from api.auth import Principal, authenticate
from api.errors import InvalidInputError
from api.settings import Settings
from api.store import SqlStore

_bearer = HTTPBearer(auto_error=False, description="An API key from `demcal apikey create`.")


def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> SqlStore:
    return request.app.state.store


def get_session(request: Request) -> Iterator[Session]:
    with request.app.state.store.session() as session:
        yield session


SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
StoreDep = Annotated[SqlStore, Depends(get_store)]
SessionDep = Annotated[Session, Depends(get_session)]


def require_key(
    store: StoreDep, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
) -> Principal:
    token = credentials.credentials if credentials is not None else None
    # A short transaction of its own: the key check must not hold a connection for the request.
    with store.session() as session:
        return authenticate(session, token)


ApiKeyDep = Annotated[Principal, Depends(require_key)]


def reject_unknown_query(request: Request) -> None:
    """A misspelt filter (``?statuss=done``) must not silently return everything: 422 instead."""
    route = request.scope.get("route")
    if route is None or not hasattr(route, "dependant"):
        return
    known: set[str] = set()
    pending = [route.dependant]
    while pending:
        dependant = pending.pop()
        known.update(param.alias for param in dependant.query_params)
        pending.extend(dependant.dependencies)
    unknown = sorted(set(request.query_params) - known)
    if unknown:
        accepted = ", ".join(sorted(known)) or "none"
        raise InvalidInputError(f"unknown query parameter(s) {', '.join(unknown)}; accepted: {accepted}")
