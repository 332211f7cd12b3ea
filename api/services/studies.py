"""Studies: creation within the service's limits, progress, and the status rules.

Status transitions a client may ask for (anything else is a 409 that says what is possible):

    pause:  created | running -> paused
    resume: paused -> running
    cancel: created | running | paused -> cancelled (pending and queued trials are cancelled too)
    delete: any status but running (pause or cancel it first)

The driver loop, not this module, moves studies to running, done or failed.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from api.auth import Principal
from api.errors import ConflictError, InvalidInputError
from api.schemas import Failures, Progress, ResponseRead, StudyListItem, StudyPage, StudyRead, TrialRead
from api.services.generations import latest_generation
from api.services.scenario_paths import confine_paths
from api.services.shapes import attach_uploaded_shapes
from api.services.trials import trial_read
from api.services.views import Served, StudyViewCache
from api.store import SqlStore
from optimizer.objectives import f1_rule
from optimizer.outcomes import failures_from_counts
from optimizer.protocols import StudyStatus, TrialState
from optimizer.study import StudyDefinition, StudyLimitError, check_limits

logger = logging.getLogger(__name__)

TRANSITIONS: dict[str, tuple[tuple[StudyStatus, ...], StudyStatus]] = {
    "pause": ((StudyStatus.CREATED, StudyStatus.RUNNING), StudyStatus.PAUSED),
    "resume": ((StudyStatus.PAUSED,), StudyStatus.RUNNING),
    "cancel": ((StudyStatus.CREATED, StudyStatus.RUNNING, StudyStatus.PAUSED), StudyStatus.CANCELLED),
}


def create_study(
    store: SqlStore, definition: StudyDefinition, principal: Principal, *, max_population: int,
    max_simulations: int, data_dir: Path,
) -> StudyRead:
    try:
        check_limits(definition, max_population=max_population, max_simulations=max_simulations)
    except StudyLimitError as exc:
        raise InvalidInputError(str(exc)) from None
    document = definition.model_dump(mode="json")
    document["scenario"] = attach_uploaded_shapes(
        store, principal, confine_paths(document["scenario"], data_dir), data_dir
    )
    study_id = store.create_study(document, owner=principal.owner, warnings=study_warnings(definition))
    return get_study(store, study_id, principal)


def _failures(status_counts: dict[str, int]) -> Failures:
    counts = failures_from_counts(status_counts)
    return Failures(**counts.as_json(), text=counts.text())


def study_warnings(definition: StudyDefinition) -> list[str]:
    """The study's warnings, computed once when it is created and stored with it (the estimate
    builds the scenario's items); one that cannot be made (a user mesh missing here) is none."""
    try:
        warning = definition.validity_warning()
    except Exception:  # noqa: BLE001 - a warning must never turn a request into a 500
        logger.warning("no validity estimate for this study's scenario", exc_info=True)
        return []
    return [warning] if warning else []


def _warnings(store: SqlStore, row) -> list[str]:
    """The stored warnings; a study made before they were stored gets them once, now."""
    stored = (row.extra or {}).get("warnings")
    if stored is None:
        try:
            definition = StudyDefinition.model_validate(row.definition)
        except Exception:  # noqa: BLE001 - a warning must never turn a read into a 500
            logger.warning("study %s: its stored definition no longer validates", row.id, exc_info=True)
            return []
        stored = study_warnings(definition)
        store.keep_warnings(row.id, stored)
    return stored


def _parsed(definition: dict) -> StudyDefinition | None:
    """The stored definition, validated once per read; None if it no longer validates."""
    try:
        return StudyDefinition.model_validate(definition)
    except ValueError:
        return None


def _budget(parsed: StudyDefinition | None) -> tuple[int, int]:
    """(simulations, generations) the definition allows; (0, 0) if it cannot be read."""
    return (parsed.total_simulations(), parsed.ga.generations) if parsed else (0, 0)


def get_study(
    store: SqlStore, study_id: str, principal: Principal, views: StudyViewCache | None = None
) -> StudyRead:
    """The study as clients read it; with ``views`` (the polled route), its best trial comes from
    the view cache: it changes only when objectives are written, which versions the study."""
    row = store.get_study(study_id, principal.visible_to)
    if views is None:
        counts, status_counts = store.trial_counts(study_id)
    else:
        counts, status_counts = views.kept("trial-tally", study_id, _Tally).counts(store, study_id)
    parsed = _parsed(row.definition)
    trials_total, generations_total = _budget(parsed)
    best = _best_trial(store, row, views)
    failures = _failures(status_counts)
    return StudyRead(
        id=row.id, name=row.name, owner=row.owner, status=StudyStatus(row.status), message=row.message,
        definition=row.definition,
        progress=Progress(
            trials_total=trials_total, trials_done=counts.get(TrialState.DONE.value, 0),
            trials_by_state=counts,
            failures=failures,
            generation=latest_generation(row.generation, generations_total),
            generations_total=generations_total,
            validation_batch=parsed.validation_batch() if parsed else None,
        ),
        best=best,
        recommendation=row.recommendation, warnings=_warnings(store, row),
        created_at=row.created_at, updated_at=row.updated_at, version=row.change_number,
        started_at=row.started_at, finished_at=row.finished_at, responses=declared_responses(row.definition),
        f1_unit=f1_unit(row.definition), f1_rule=f1_rule(parsed) if parsed else "",
    )


class _Tally:
    """A study's trials by state and by how their simulation ended, kept between builds of its
    view and brought up to date from the trials written since (``trial_states``): counting all
    10,000 trials of a long study was 4 of the 5.3 CPU ms of each rebuild, one after every trial
    write (benchmarks/README.md, session 8). Trials are never deleted but with their study."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.since = -1  # change numbers start at 0
        self.trials: dict[str, tuple[str, str | None]] = {}  # id -> (state, status)
        self.by_state: dict[str, int] = {}
        self.by_status: dict[str, int] = {}

    def counts(self, store: SqlStore, study_id: str) -> tuple[dict[str, int], dict[str, int]]:
        """(trials by state, finished trials by status), as ``SqlStore.trial_counts``."""
        with self.lock:
            for trial, state, status, number in store.trial_states(study_id, self.since):
                if trial in self.trials:
                    self._add(*self.trials[trial], -1)
                self.trials[trial] = (state, status)
                self._add(state, status, 1)
                # Numbers are taken in commit order: every write up to the newest seen is read.
                self.since = max(self.since, number)
            return dict(sorted(self.by_state.items())), dict(sorted(self.by_status.items()))

    def _add(self, state: str, status: str | None, n: int) -> None:
        for counts, key in ((self.by_state, state), (self.by_status, status)):
            if key is None:
                continue
            counts[key] = counts.get(key, 0) + n
            if not counts[key]:
                del counts[key]


def study_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, held: str | None = None
) -> Served:
    """``get_study`` as JSON, built once per version of the study and of its trials (the study's
    change counter: every write to either takes the next number): the read every open dashboard
    polls, while results change it a few times a second at most. ``held``: the client's
    ``If-None-Match`` (``StudyViewCache.serve``)."""
    version = store.study_version(study_id, principal.visible_to)
    return views.serve(
        "study", study_id, version.trial_changes,
        lambda: get_study(store, study_id, principal, views).model_dump_json().encode(), held=held,
    )


def _best_trial(store: SqlStore, row, views: StudyViewCache | None) -> TrialRead | None:
    def build() -> bytes:
        best = store.best_trial(row.id)
        return trial_read(best).model_dump_json().encode() if best is not None else b"null"

    # The best trial is ranked by f1/f2, which only save_generation writes (it bumps the row).
    body = build() if views is None else views.get_or_build("best", row.id, row.change_number, build)
    return None if body == b"null" else TrialRead.model_validate_json(body)


def _compact(recommendation: dict | None) -> dict | None:
    """The recommendation without its list of equivalent sets, which may be long."""
    if recommendation is None:
        return None
    return {key: value for key, value in recommendation.items() if key != "equivalent"}


def list_studies(
    store: SqlStore, principal: Principal, status: StudyStatus | None, limit: int, offset: int
) -> StudyPage:
    page = store.list_studies(principal.visible_to, status, limit, offset)
    ids = [row.id for row in page.items]
    # One grouped query each for the whole page, not one per study.
    done = store.done_counts(ids)
    best_f1 = store.best_f1s(ids)
    statuses = store.run_status_counts_many(ids)
    items = []
    for row in page.items:
        trials_total, generations_total = _budget(_parsed(row.definition))
        items.append(
            StudyListItem(
                id=row.id, name=row.name, owner=row.owner, status=StudyStatus(row.status),
                message=row.message, generation=latest_generation(row.generation, generations_total),
                trials_done=done.get(row.id, 0),
                trials_total=trials_total, generations_total=generations_total,
                created_at=row.created_at, updated_at=row.updated_at, started_at=row.started_at,
                finished_at=row.finished_at, recommendation=_compact(row.recommendation),
                best_f1=best_f1.get(row.id), failures=_failures(statuses.get(row.id, {})),
                f1_unit=f1_unit(row.definition),
            )
        )
    return StudyPage(items=items, total=page.total, limit=limit, offset=offset)


def change_status(store: SqlStore, study_id: str, action: str, principal: Principal) -> StudyRead:
    row = store.get_study(study_id, principal.visible_to)
    allowed_from, to = TRANSITIONS[action]
    if not store.transition(study_id, allowed_from, to, message=f"{action} by {principal.owner}"):
        current = store.get_study(study_id).status
        possible = [name for name, (sources, _) in TRANSITIONS.items() if current in sources]
        raise ConflictError(
            f"cannot {action} study {row.id!r}: it is {current}; "
            + (f"possible now: {', '.join(possible)}" if possible else "it is finished and cannot change")
        )
    return get_study(store, study_id, principal)


def delete_study(store: SqlStore, study_id: str, principal: Principal) -> None:
    row = store.get_study(study_id, principal.visible_to)
    if row.status == StudyStatus.RUNNING.value:
        raise ConflictError(f"study {study_id!r} is running: pause or cancel it first, then delete it")
    store.delete_study(study_id)



def declared_responses(definition: dict) -> list[ResponseRead]:
    """What the study's scenario measures, with units (empty for a definition that no longer
    validates, e.g. a scenario kind this server does not have)."""
    from dem.scenarios.registry import UnknownScenarioError, for_config

    scenario_config = definition.get("scenario") or {}
    try:
        scenario = for_config(scenario_config)
        return [ResponseRead(**r.as_dict()) for r in scenario.declared(scenario_config)]
    except (UnknownScenarioError, ValueError):
        return []


def f1_unit(definition: dict) -> str:
    """The unit of the study's f1 (optimizer/objectives.py): one experiment's distance is in its
    response's unit; several are each divided by their tolerance, so their maximum has none."""
    experiments = definition.get("experiments") or [definition.get("experiment") or {}]
    declared = {r.name: r.unit for r in declared_responses(definition)}
    if len(experiments) != 1 or not declared:
        return "1"
    return declared.get(experiments[0].get("response") or next(iter(declared)), "1")
