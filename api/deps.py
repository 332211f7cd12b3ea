"""FastAPI dependencies as typed aliases: the settings, the store and the caller.

``ApiKeyDep`` authenticates the ``Authorization: Bearer <key>`` header on every route that uses
it (all but health); a missing, unknown or revoked key is a 401 that says how to get one.

The dependencies are ``async`` where they do not block: FastAPI runs a sync dependency in the
thread pool, and a thread hop per dependency was a large share of a small read's latency under
load. The key check goes to the thread pool only when the key is not in the short-lived cache.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from api.auth import KeyCache, Principal, authenticate
from api.errors import InvalidInputError, NotFoundError
from api.services.views import StudyViewCache
from api.settings import Settings
from api.store import SqlStore

_bearer = HTTPBearer(auto_error=False, description="An API key from `demcal apikey create`.")


async def get_settings_dep(request: Request) -> Settings:
    return request.app.state.settings


async def get_store(request: Request) -> SqlStore:
    return request.app.state.store


async def get_study_views(request: Request) -> StudyViewCache:
    return request.app.state.study_views


SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
StudyViewsDep = Annotated[StudyViewCache, Depends(get_study_views)]
StoreDep = Annotated[SqlStore, Depends(get_store)]
# Paging of the owned-resource lists (studies, shapes, simulations).
Limit = Annotated[int, Query(ge=1, le=500, description="Page size.")]
Offset = Annotated[int, Query(ge=0, le=10_000_000, description="Rows to skip.")]


def _authenticate(store: SqlStore, token: str | None) -> Principal:
    # A short transaction of its own: the key check must not hold a connection for the request.
    with store.session() as session:
        return authenticate(session, token)


async def require_key(
    request: Request, store: StoreDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    token = credentials.credentials if credentials is not None else None
    cache: KeyCache = request.app.state.key_cache
    principal = cache.get(token) if token else None
    if principal is None:
        principal = await run_in_threadpool(_authenticate, store, token)
        cache.put(token, principal)
    return principal


ApiKeyDep = Annotated[Principal, Depends(require_key)]


async def reject_impossible_ids(request: Request) -> None:
    """An id with a NUL character (``/studies/%00``) names nothing: 404 here, because PostgreSQL
    refuses NUL in text and the lookup would otherwise end in a 500."""
    for name, value in request.path_params.items():
        if isinstance(value, str) and "\x00" in value:
            raise NotFoundError(f"no such {name.removesuffix('_id')}: ids never contain a NUL character")


async def reject_unknown_query(request: Request) -> None:
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
