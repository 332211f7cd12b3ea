"""``/metrics``: Prometheus text format (studies by status, trials by state, queue depth, simulation
seconds). It needs an API key like every other non-health endpoint."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import PlainTextResponse

from api.deps import ApiKeyDep, SettingsDep, StoreDep
from api.services import health as service

router = APIRouter(tags=["metrics"])


@router.get(
    "/metrics",
    responses={200: {"content": {"text/plain": {}}, "description": "Prometheus text format 0.0.4."}},
)
def metrics(principal: ApiKeyDep, store: StoreDep, settings: SettingsDep):
    return PlainTextResponse(
        service.metrics_text(store, settings), media_type="text/plain; version=0.0.4; charset=utf-8"
    )
