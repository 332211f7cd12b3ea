"""Trials of a study as clients read them: pages, one trial, the Pareto front, the per-generation
summary (the paper's Fig. 5, computed by ``optimizer/generations.py``), the recommendation
with its equivalent sets, and CSV/JSON exports.

The two reads every dashboard polls, the trial page and the Pareto front, return JSON bytes:
they are built from plain column rows and serialised once by pydantic, and the front is cached
per study version (``api/services/views.py``). The routes still declare their response models.

A run that measured nothing (``optimizer/outcomes.py``) is never sent as an N_t value or on the
front: its ``n_remaining`` is null (the raw count stays in the trial's full result), its individual's
objectives are null as stored, and summaries count it by status.

It reads only; the optimiser (through the store) is the one that writes objectives and Pareto
flags. Every function first checks that the caller may see the study (404 otherwise).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator

from pydantic_core import to_json

from api.auth import Principal
from api.models import TrialRow, decode_value
from api.schemas import (
    GenerationSummary,
    TrialDetail,
    TrialPage,
    TrialRead,
    finite_or_none,
)
from api.services.generations import latest_generation
from api.services.views import Served, StudyViewCache
from api.store import Page, SqlStore, TrialFilter
from optimizer.generations import Run, per_generation
from optimizer.objectives import protocol_times
from optimizer.outcomes import individual_failures, is_failed, measured_n
from optimizer.protocols import TrialState
from optimizer.report import response_column, study_parameter_names, trial_csv_columns
from optimizer.study import StudyDefinition


def _objectives(row) -> tuple[float | None, float | None]:
    f1 = decode_value(row.f1_value, row.f1_kind)
    f2 = decode_value(row.f2_value, row.f2_kind)
    return finite_or_none(f1), finite_or_none(f2)


def trial_read(row: TrialRow) -> TrialRead:
    f1, f2 = _objectives(row)
    return TrialRead(
        id=row.id, generation=row.generation, individual=row.individual, replicate=row.replicate,
        seed=row.seed, params=row.params, state=row.state, status=row.status,
        n_remaining=measured_n(row.status, row.n_remaining), responses=row.responses, engine=row.engine,
        wall_time_s=row.wall_time_s, cost=row.cost, **protocol_times(row), f1=f1, f2=f2, pareto=row.pareto,
        worker=row.worker, attempts=row.attempts, message=row.message, updated_at=row.updated_at,
    )


def _point_item(row) -> dict:
    """A ``ParetoPoint`` as a dict, from a row of ``trial_columns`` or ``TRIAL_READ_COLUMNS``.
    Serialised as it is (``_json``), not validated again: what the store holds came through the
    optimiser's models, and validating the recommendation's 344 matching points of the benchmark's
    study once more was half of its build's 12 ms of CPU (benchmarks/README.md, session 8)."""
    return {
        "id": row.id, "generation": row.generation, "individual": row.individual, "replicate": row.replicate,
        "params": row.params, "n_remaining": measured_n(row.status, row.n_remaining),
        "responses": row.responses, "wall_time_s": row.wall_time_s, "cost": row.cost,
        "f1": _finite_objective(row.f1_value, row.f1_kind),
        "f2": _finite_objective(row.f2_value, row.f2_kind),
    }


def _json(document: dict) -> bytes:
    """A document of plain values as JSON, an infinite or NaN number as null (as the response
    models' ``ser_json_inf_nan`` default writes it)."""
    return to_json(document, inf_nan_mode="null")


def _trial_item(row) -> dict:
    """A ``TrialRead`` as a dict, from a row of ``TRIAL_READ_COLUMNS``."""
    item = row._asdict() | protocol_times(row)
    del item["full_load_factor"]
    item["n_remaining"] = measured_n(item["status"], item["n_remaining"])
    item["f1"] = _finite_objective(item.pop("f1_value"), item.pop("f1_kind"))
    item["f2"] = _finite_objective(item.pop("f2_value"), item.pop("f2_kind"))
    return item


def _finite_objective(value: float | None, kind: str | None) -> float | None:
    if kind == "finite":  # the common case, without decode_value's enum lookups
        return value
    return finite_or_none(decode_value(value, kind))


def list_trials_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, where: TrialFilter,
    limit: int, offset: int,
) -> bytes:
    """A ``TrialPage`` as JSON bytes, from plain rows (no ORM objects, one serialisation pass).

    The unfiltered total only changes when trials are added, which updates the study row, so it
    is cached per study version like the Pareto front; filtered totals are counted each time,
    unless the page itself tells (``trial_page_rows``).

    A dashboard polls for the changes since its last page (``changed_since``, that page's
    ``changes``): the study's change counter, read before the page, so that every write numbered
    up to it has committed (numbers are taken in commit order) and one committed later is sent
    again at the next poll, not missed, whatever its process's clock said (wall-clock stamps
    could miss it). A poll with nothing newer is answered from the counter alone.
    """
    study = store.study_version(study_id, principal.visible_to)
    since = where.changed_since
    if since is not None and study.trial_changes <= since:
        page = Page([], 0)
    else:
        total = None
        if where == TrialFilter():
            total = int(views.get_or_build(
                "trial-count", study_id, study.change_number,
                lambda: str(store.trial_count(study_id, where)).encode(),
            ))
        page = store.trial_page_rows(study_id, where, limit, offset, total=total)
    return TrialPage.model_validate(
        {"items": [_trial_item(row) for row in page.items], "total": page.total, "limit": limit,
         "offset": offset, "changes": study.trial_changes}
    ).model_dump_json().encode()


def get_trial(store: SqlStore, study_id: str, trial_id: str, principal: Principal) -> TrialDetail:
    store.get_study(study_id, principal.visible_to)
    row = store.get_trial(study_id, trial_id)
    compact = trial_read(row)
    return TrialDetail(
        **compact.model_dump(), dt=row.dt, timeout_s=row.timeout_s, result=row.result,
        created_at=row.created_at, started_at=row.started_at, finished_at=row.finished_at,
    )


def pareto_front_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, held: str | None = None
) -> Served:
    """The ``ParetoFront`` as JSON bytes, built once per version of the study row (see ``views``;
    ``held``: the client's ``If-None-Match``)."""
    study = store.study_version(study_id, principal.visible_to)
    build = views.builder("pareto", _pareto_front, store, study_id, study.generation)
    return views.serve("pareto", study_id, study.change_number, build, held=held)


def _pareto_front(store: SqlStore, views: StudyViewCache, study_id: str, generation: int) -> bytes:
    """The front's JSON, ``generation`` the study's as its version was read."""
    rows = [row for row in store.pareto_columns(study_id) if not is_failed(row.status)]
    points = sorted(
        (point for point in map(_point_item, rows) if point["f1"] is not None),
        key=lambda p: (_sort_key(p["f1"]), _sort_key(p["f2"])),
    )
    generations = store.load_study(study_id).definition.get("ga", {}).get("generations")
    return _json({"study_id": study_id, "generation": latest_generation(generation, generations),
                  "points": points})


def _sort_key(value: float | None) -> float:
    return math.inf if value is None else value


# The summary's fields as of this version (2: as_experiment's ``alike``; 3: the whole protocol's
# T and cost): a part of the ETag's version, so that a browser that cached a finished study's
# summary before a new field fetches it.
GENERATIONS_FORMAT = 3


def generation_summary_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, held: str | None = None
) -> Served:
    """The per-generation summary as JSON, built once per version of the study row like the
    Pareto front (every trial written changes it): the dashboard reads it after each change of
    the trials for Fig. 5's medians and W1s, so a poll with nothing new is a 304 (``held``: the
    client's ``If-None-Match``) and one build serves every dashboard."""
    study = store.study_version(study_id, principal.visible_to)
    build = views.builder("generations", _generation_summary, store, study_id)
    return views.serve("generations", study_id, (study.change_number, GENERATIONS_FORMAT), build, held=held)


def _generation_summary(store: SqlStore, views: StudyViewCache, study_id: str) -> bytes:
    """``optimizer/generations.py`` on the stored rows (objectives as stored)."""
    definition = StudyDefinition.model_validate(store.get_study(study_id).definition)
    runs = (
        Run.measured(
            row.generation,
            row.status if row.state == TrialState.DONE.value else None,
            row.responses or {},
            row,
            _objectives(row)[0],
        )
        for row in store.trial_columns(study_id)
    )
    summaries = [
        GenerationSummary.model_validate(entry)
        for entry in per_generation(runs, definition.measured_by_response())
    ]
    return _json([summary.model_dump(mode="json") for summary in summaries])


def recommendation_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, held: str | None = None
) -> Served:
    """``RecommendationRead`` as JSON, built once per version of the study row: every input (status,
    the stored recommendation, the objectives f1/f2 that ``save_generation`` writes) changes the
    row, while dashboards read it after each such change (``held``: the client's
    ``If-None-Match``)."""
    study = store.study_version(study_id, principal.visible_to)
    build = views.builder("recommendation", _recommendation_json, store, study_id)
    return views.serve("recommendation", study_id, study.change_number, build, held=held)


def _recommendation_json(store: SqlStore, views: StudyViewCache, study_id: str) -> bytes:
    return _json(_recommendation(store, study_id))


def _recommendation(store: SqlStore, study_id: str) -> dict:
    study = store.get_study(study_id)
    try:
        tolerance = StudyDefinition.model_validate(study.definition).match_tolerance()
    except ValueError:
        tolerance = 0.0
    matching: dict[int, dict] = {}
    # Only the matching trials are read: most of a long study's trials do not match, and reading
    # all 10,000 of the benchmark's study was 130 of the build's 150 ms (benchmarks/README.md).
    for row in store.trial_columns(study_id, f1_at_most=tolerance):
        # One entry per parameter set: replicates of an individual share their objectives.
        if row.individual not in matching:
            matching[row.individual] = _point_item(row)
    equivalent = sorted(matching.values(), key=lambda p: (_sort_key(p["f2"]), _sort_key(p["f1"])))
    return {
        "study_id": study_id, "status": study.status, "recommendation": study.recommendation,
        "equivalent": equivalent,
    }


def export_rows(store: SqlStore, study_id: str, principal: Principal) -> tuple[list[str], list[dict]]:
    """The export's columns (``optimizer.report.trial_csv_columns``) and every trial as a flat
    row (CSV and JSON export): parameters, one column per declared response (headed with its
    unit), time, cost and objectives."""
    from api.services.studies import declared_responses

    study = store.get_study(study_id, principal.visible_to)
    declared = declared_responses(study.definition)
    names = study_parameter_names(study.definition)
    columns = trial_csv_columns(names, [response_column(r) for r in declared])
    rows = []
    trial_rows = store.trial_rows_for_export(study_id)
    failures = individual_failures((row.individual, row.replicate, row.status) for row in trial_rows)
    for row in trial_rows:
        f1, f2 = _objectives(row)
        measured = row.responses or {}
        values = {
            "trial_id": row.id, "generation": row.generation, "individual": row.individual,
            "replicate": row.replicate, "seed": row.seed,
            **{name: row.params.get(name) for name in names},
            "engine": row.engine, "state": row.state, "status": row.status,
            # Only runs that measured: a failed run's responses are not measurements.
            **{response_column(r): measured.get(r.name) if row.status == "ok" else None
               for r in declared},
            "wall_time_s": row.wall_time_s, "cost": row.cost, "dt": row.dt, "f1": f1, "f2": f2,
            "failure": failures.get(row.individual, ""),
            "pareto": row.pareto, "worker": row.worker, "attempts": row.attempts,
            "message": row.message,
        }
        rows.append({column: values[column] for column in columns})
    return columns, rows


def export_csv(columns: list[str], rows: list[dict]) -> Iterator[str]:
    """CSV text in chunks, so a large study streams instead of building one big string."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for index, row in enumerate(rows, start=1):
        writer.writerow({key: "" if value is None else value for key, value in row.items()})
        if index % 500 == 0:
            yield buffer.getvalue()
            buffer.seek(0)
            buffer.truncate()
    yield buffer.getvalue()
