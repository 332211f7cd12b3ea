"""Studies: create, list, read, pause/resume/cancel, delete; and the per-study views (Pareto
front, per-generation summary, recommendation, exports). Thin handlers over ``api/services``."""

from __future__ import annotations

import math
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response, status
from fastapi.responses import StreamingResponse

from api.deps import ApiKeyDep, Limit, Offset, SettingsDep, StoreDep, StudyViewsDep
from api.schemas import (
    GenerationSummary,
    IdentifiabilityRead,
    ParetoFront,
    RecommendationRead,
    StudyPage,
    StudyProgressRead,
    StudyRead,
)
from api.services import progress, studies, trials
from api.services.views import Served
from optimizer.protocols import StudyStatus
from optimizer.study import StudyDefinition

router = APIRouter(prefix="/api/v1/studies", tags=["studies"])


def cached_json(served: Served) -> Response:
    """A polled view's JSON with an ETag (its version and a digest of its bytes, ``views.etag``) and
    ``Cache-Control: no-cache``, so that a browser asks again each time with ``If-None-Match`` and a
    view it holds comes back as an empty 304 (the dashboard's fetch does this by itself), decided by
    ``views.serve(..., held=)``.

    ``X-Demcal-View`` says whether the view is of the study's current version or a stale one
    served while the current one builds (progress, identifiability): the dashboard asks for a
    view again only when the study changed or its last answer was stale. It is on every answer,
    304s too, because a cache keeps a stored header the 304 does not replace. A stale view whose
    builds rest (identifiability), resting or building, also says in ``Retry-After`` how many
    seconds pass at least before a newer version can be ready: the dashboard does not ask for it
    again before."""
    headers = {
        "ETag": served.etag, "Cache-Control": "no-cache",
        "X-Demcal-View": "current" if served.current else "stale",
    }
    if not served.current and served.retry_after_s is not None:
        headers["Retry-After"] = str(max(1, math.ceil(served.retry_after_s)))
    if served.not_modified:
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    return Response(served.body, media_type="application/json", headers=headers)


def held(request: Request) -> str | None:
    """The ETags the client holds (``If-None-Match``)."""
    return request.headers.get("if-none-match")


@router.post("", status_code=status.HTTP_201_CREATED, response_model=StudyRead)
def create_study(definition: StudyDefinition, principal: ApiKeyDep, store: StoreDep, settings: SettingsDep):
    """Create a study from a definition (the same document `demcal calibrate` reads)."""
    return studies.create_study(
        store, definition, principal, max_population=settings.max_population,
        max_simulations=settings.max_simulations, data_dir=settings.data_dir,
    )


@router.get("", response_model=StudyPage)
def list_studies(
    principal: ApiKeyDep, store: StoreDep, limit: Limit = 50, offset: Offset = 0,
    status: Annotated[StudyStatus | None, Query(description="Only studies in this status.")] = None,
):
    return studies.list_studies(store, principal, status, limit, offset)


@router.get("/{study_id}", response_model=StudyRead)
def get_study(
    study_id: str, principal: ApiKeyDep, store: StoreDep, views: StudyViewsDep, request: Request
):
    """A study with its progress (trials done / total, generation) and best trial so far."""
    return cached_json(studies.study_json(store, views, study_id, principal, held(request)))


@router.post("/{study_id}/pause", response_model=StudyRead)
def pause_study(study_id: str, principal: ApiKeyDep, store: StoreDep):
    return studies.change_status(store, study_id, "pause", principal)


@router.post("/{study_id}/resume", response_model=StudyRead)
def resume_study(study_id: str, principal: ApiKeyDep, store: StoreDep):
    return studies.change_status(store, study_id, "resume", principal)


@router.post("/{study_id}/cancel", response_model=StudyRead)
def cancel_study(study_id: str, principal: ApiKeyDep, store: StoreDep):
    return studies.change_status(store, study_id, "cancel", principal)


@router.delete("/{study_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response)
def delete_study(study_id: str, principal: ApiKeyDep, store: StoreDep):
    studies.delete_study(store, study_id, principal)


@router.get("/{study_id}/pareto", response_model=ParetoFront)
def pareto_front(
    study_id: str, principal: ApiKeyDep, store: StoreDep, views: StudyViewsDep, request: Request
):
    """The current Pareto front (f1 = |N_t - target|, f2 = computation time), best f1 first."""
    return cached_json(trials.pareto_front_json(store, views, study_id, principal, held(request)))


@router.get("/{study_id}/generations", response_model=list[GenerationSummary])
def generation_summary(
    study_id: str, principal: ApiKeyDep, store: StoreDep, views: StudyViewsDep, request: Request
):
    """Median and spread of N_t and T per generation (the paper's Fig. 5)."""
    return cached_json(trials.generation_summary_json(store, views, study_id, principal, held(request)))


@router.get("/{study_id}/progress", response_model=StudyProgressRead)
def study_progress(
    study_id: str, principal: ApiKeyDep, store: StoreDep, views: StudyViewsDep, request: Request
):
    """Hypervolume, best f1 and best validated f1 against simulations, one point per completed batch."""
    return cached_json(progress.progress_json(store, views, study_id, principal, held(request)))


@router.get("/{study_id}/identifiability", response_model=IdentifiabilityRead)
def identifiability(
    study_id: str, principal: ApiKeyDep, store: StoreDep, views: StudyViewsDep, request: Request
):
    """Which searched parameters the experiment pins down, from the spread of the matching sets."""
    served = progress.identifiability_json(store, views, study_id, principal, held(request))
    return cached_json(served)


@router.get("/{study_id}/recommendation", response_model=RecommendationRead)
def recommendation(
    study_id: str, principal: ApiKeyDep, store: StoreDep, views: StudyViewsDep, request: Request
):
    """The recommended parameter set and every other set that matches the experiment as well."""
    return cached_json(trials.recommendation_json(store, views, study_id, principal, held(request)))


@router.get(
    "/{study_id}/export.csv",
    responses={200: {"content": {"text/csv": {}}, "description": "One row per trial."}},
)
def export_csv(study_id: str, principal: ApiKeyDep, store: StoreDep):
    columns, rows = trials.export_rows(store, study_id, principal)
    return StreamingResponse(
        trials.export_csv(columns, rows), media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{study_id}-trials.csv"'},
    )


@router.get("/{study_id}/export.json")
def export_json(study_id: str, principal: ApiKeyDep, store: StoreDep) -> dict:
    """The study (definition, status, recommendation) and every trial, in one document."""
    return {
        "study": studies.get_study(store, study_id, principal).model_dump(mode="json"),
        "trials": trials.export_rows(store, study_id, principal)[1],
    }
