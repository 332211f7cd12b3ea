"""The FastAPI application: ``create_app(settings)`` composes the store, the routers, the error
handlers and the request-size limit. ``/`` and ``/static`` are left free for the dashboard.

It refuses to start on a database whose schema is not at the newest migration
(``SchemaOutOfDateError`` says to run ``demcal db upgrade``); it never migrates by itself, because
a service with several replicas must not race to alter its schema.
"""

from __future__ import annotations

import contextlib
import logging

import sqlalchemy as sa
from fastapi import Depends, FastAPI
from fastapi.responses import JSONResponse

from api import __version__
from api.auth import KeyCache
from api.dashboard import dashboard_router
from api.db import check_schema_current, create_db_engine
from api.deps import reject_impossible_ids, reject_unknown_query
from api.errors import PayloadTooLargeError, install_error_handlers
from api.routes import health, metrics, shapes, simulations, studies, trials
from api.schemas import ErrorDetail
from api.services.offload import ViewProcesses
from api.services.views import StudyViewCache
from api.settings import Settings
from api.store import SqlStore

log = logging.getLogger(__name__)

UPLOAD_PATH = "/api/v1/shapes"
ERROR_RESPONSES = {
    status: {"model": ErrorDetail, "description": description}
    for status, description in (
        (400, "The body cannot be parsed (not UTF-8 JSON, broken multipart)."),
        (401, "No API key, an unknown one, or a revoked one."),
        (404, "No such object, or it belongs to another owner."),
        (409, "The object's state forbids this request."),
        (413, "The request body is larger than the configured limit."),
        (422, "The request is invalid; the message says what to fix."),
    )
}
MULTIPART_OVERHEAD = 64 * 1024  # form fields and boundaries around the mesh file


class BodySizeLimit:
    """Refuse request bodies above the configured size with 413, before they are read whole.

    A declared Content-Length is checked up front; a chunked body is counted as it arrives.
    Mesh uploads get the upload limit, every other request the JSON limit.
    """

    def __init__(self, app, max_request_bytes: int, max_upload_bytes: int):
        self.app = app
        self.max_request_bytes = max_request_bytes
        self.max_upload_bytes = max_upload_bytes + MULTIPART_OVERHEAD

    def _limit(self, path: str) -> int:
        return self.max_upload_bytes if path.rstrip("/") == UPLOAD_PATH else self.max_request_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self._limit(scope.get("path", ""))
        message = (
            f"the request body is larger than {limit} bytes; "
            + ("DEMCAL_MAX_UPLOAD_BYTES" if limit == self.max_upload_bytes else "DEMCAL_MAX_REQUEST_BYTES")
            + " sets the limit"
        )
        declared = dict(scope.get("headers") or ()).get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > limit):
            response = JSONResponse({"detail": message}, status_code=413)
            await response(scope, receive, send)
            return
        received = 0

        async def counting_receive():
            nonlocal received
            event = await receive()
            if event["type"] == "http.request":
                received += len(event.get("body", b""))
                if received > limit:
                    raise PayloadTooLargeError(message)
            return event

        await self.app(scope, counting_receive, send)


@contextlib.asynccontextmanager
async def _lifespan(app: FastAPI):
    yield
    app.state.study_views.close()  # the view-building processes end with the app


def create_app(settings: Settings, engine: sa.Engine | None = None) -> FastAPI:
    """The REST API on the database of ``settings`` (or the given engine)."""
    engine = engine if engine is not None else create_db_engine(settings.database_url)
    check_schema_current(engine)
    app = FastAPI(
        title="demcal",
        version=__version__,
        summary="Calibrate DEM contact parameters with a multi-objective genetic algorithm.",
        description="Every endpoint except /healthz needs `Authorization: Bearer <key>` "
        "(`demcal apikey create`). Errors are `{\"detail\": \"what to fix\"}` with a 4xx status.",
        lifespan=_lifespan,
    )
    app.state.settings = settings
    app.state.store = SqlStore(engine)
    app.state.key_cache = KeyCache(settings.api_key_cache_s)
    processes = None  # views built on the server's threads
    if settings.view_processes:
        processes = ViewProcesses(settings.view_processes, settings.view_kept_studies)
    app.state.study_views = StudyViewCache(max_kept_studies=settings.view_kept_studies, processes=processes)
    install_error_handlers(app)
    strict_query = [Depends(reject_unknown_query), Depends(reject_impossible_ids)]
    for module in (studies, trials, simulations, shapes, metrics):
        app.include_router(module.router, responses=ERROR_RESPONSES, dependencies=strict_query)
    app.include_router(
        health.router, responses={413: ERROR_RESPONSES[413], 422: ERROR_RESPONSES[422]},
        dependencies=strict_query,
    )
    app.include_router(
        dashboard_router(), responses=ERROR_RESPONSES, dependencies=[Depends(reject_impossible_ids)]
    )
    app.add_middleware(
        BodySizeLimit,
        max_request_bytes=settings.max_request_bytes,
        max_upload_bytes=settings.max_upload_bytes,
    )
    log.info("API ready on %s", engine.url.render_as_string(hide_password=True))
    return app
