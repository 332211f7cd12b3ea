"""Trials of a study: a filtered page (with ``changed_since`` for incremental polling), one trial."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response

from api.deps import ApiKeyDep, StoreDep, StudyViewsDep
from api.schemas import TrialDetail, TrialPage
from api.services import trials
from api.store import TrialFilter
from optimizer.protocols import TrialState

router = APIRouter(prefix="/api/v1/studies/{study_id}/trials", tags=["trials"])


@router.get("", response_model=TrialPage)
def list_trials(
    study_id: str,
    principal: ApiKeyDep,
    store: StoreDep,
    views: StudyViewsDep,
    limit: Annotated[int, Query(ge=1, le=5000, description="Page size.")] = 100,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
    generation: Annotated[int | None, Query(ge=0, le=1_000_000)] = None,
    state: Annotated[TrialState | None, Query()] = None,
    pareto: Annotated[bool | None, Query(description="Only (non-)members of the Pareto front.")] = None,
    changed_since: Annotated[
        int | None,
        Query(ge=0, le=2**62, description="Only trials changed after this change number of the study: "
              "pass the previous page's changes to poll incrementally."),
    ] = None,
):
    where = TrialFilter(generation=generation, state=state, pareto=pareto, changed_since=changed_since)
    return Response(
        trials.list_trials_json(store, views, study_id, principal, where, limit, offset),
        media_type="application/json",
    )


@router.get("/{trial_id}", response_model=TrialDetail)
def get_trial(study_id: str, trial_id: str, principal: ApiKeyDep, store: StoreDep):
    return trials.get_trial(store, study_id, trial_id, principal)
