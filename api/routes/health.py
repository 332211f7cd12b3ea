"""``/healthz``: database, Redis when configured, workers seen. No API key needed (probes)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from api.deps import SettingsDep, StoreDep
from api.schemas import Health
from api.services import health as service

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, responses={503: {"model": Health}})
def healthz(store: StoreDep, settings: SettingsDep):
    report = service.health(store, settings)
    if report.status != "ok":
        return JSONResponse(report.model_dump(mode="json"), status_code=503)
    return report
