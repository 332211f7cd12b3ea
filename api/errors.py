"""The errors users can cause, and how the API turns them into 4xx JSON ``{"detail": "..."}``.

Every message says what to fix. The store and the services raise these; the routes do not catch
them: ``install_error_handlers`` maps each to its status code, turns request-validation errors
into 422 messages naming the field, and makes anything unexpected a logged 500 that leaks nothing.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import compile_path

log = logging.getLogger(__name__)


class DemcalError(Exception):
    """Base of the errors a client can cause; ``status_code`` is what the API answers."""

    status_code = 400

    def __init__(self, detail: str):
        super().__init__(detail)
        self.detail = detail


class InvalidInputError(DemcalError, ValueError):
    """The request is well-formed but its content is not acceptable (bounds, limits, mesh)."""

    status_code = 422


class NotFoundError(DemcalError, LookupError):
    """No such object, or it belongs to another owner (we do not say which)."""

    status_code = 404


class ConflictError(DemcalError):
    """The object is in a state that forbids the request (e.g. resuming a finished study)."""

    status_code = 409


class PayloadTooLargeError(DemcalError):
    status_code = 413


class AuthenticationError(DemcalError):
    """No API key, an unknown one, or a revoked one."""

    status_code = 401


def _validation_message(exc: RequestValidationError, body_model=None) -> str:
    """One part per error: the field's path once (not again when the message starts with it),
    and for an unknown key the nearest valid one of the request's body model."""
    from dem.scenarios.base import error_line

    parts = []
    for err in exc.errors():
        loc = tuple(p for p in err.get("loc", ()) if p != "body")
        parts.append(error_line({**err, "loc": loc}, body_model))
    return "; ".join(parts) or "the request is not valid"


def _body_model(request: Request):
    """The pydantic model of the route's JSON body, if it has one."""
    field = getattr(request.scope.get("route"), "body_field", None)
    model = getattr(getattr(field, "field_info", None), "annotation", None)
    return model if isinstance(model, type) and hasattr(model, "model_fields") else None


HTTP_METHODS = frozenset({"GET", "PUT", "POST", "DELETE", "OPTIONS", "HEAD", "PATCH", "TRACE"})


def _method_not_allowed(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    """405 whose ``Allow`` names the methods of every operation on the path, from the published
    OpenAPI document: Starlette names only those of the first route that matched the path
    (DELETE, not GET, on ``/studies/{id}``)."""
    allowed: set[str] = set()
    for template, operations in request.app.openapi()["paths"].items():
        if compile_path(template)[0].match(request.url.path):
            allowed |= {method.upper() for method in operations} & HTTP_METHODS
    if not allowed:  # a route left out of the document (/docs): Starlette's own answer
        allowed = {m.strip() for m in (exc.headers or {}).get("Allow", "").split(",") if m.strip()}
    allow = ", ".join(sorted(allowed))
    return JSONResponse(
        {"detail": f"{request.method} is not allowed on {request.url.path}; use {allow}"},
        status_code=405,
        headers={"Allow": allow},
    )


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(DemcalError)
    async def _demcal_error(request: Request, exc: DemcalError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if isinstance(exc, AuthenticationError) else None
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": _validation_message(exc, _body_model(request))}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        if exc.status_code == 405:
            return _method_not_allowed(request, exc)
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": "internal error; it has been logged"}, status_code=500)
