"""A study's progress against simulations (hypervolume, best f1, best validated f1 per batch) and
which parameters its experiment pins down, as clients read them.

Both are computed by the optimiser's own functions (``optimizer/progress.py``,
``optimizer/identifiability.py``) from the stored trials, the same way ``summary.json`` is, and
kept as JSON per study version (``api/services/views.py``): they change once per batch, while a
dashboard polls every few seconds. Progress also keeps its tracker per study between versions and
reads only the batches completed since (a study of 100 batches is not read and evaluated again
whole after each one). It reads only, and checks first that the caller may see the
study (404 otherwise).
"""

from __future__ import annotations

import threading

from api.auth import Principal
from api.schemas import IdentifiabilityRead, StudyProgressRead
from api.services.offload import in_child
from api.services.views import Served, StudyViewCache
from api.store import SqlStore
from optimizer.identifiability import study_identifiability
from optimizer.objectives import evaluate
from optimizer.progress import ProgressTracker
from optimizer.space import ParameterSpace
from optimizer.study import StudyDefinition

IDENTIFIABILITY_REST = 9.0  # at most a tenth of a core on average, however fast the batches come


class _Folded:
    """A study's progress tracker, kept between builds of its view: a point never changes once
    given, so each build reads and folds only the batches completed since the previous one."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.tracker: ProgressTracker | None = None


def progress_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, held: str | None = None
) -> Served:
    study = store.study_version(study_id, principal.visible_to)
    build = views.builder("progress", _progress, store, study_id)
    return views.serve("progress", study_id, study.change_number, build, stale_ok=True, held=held)


def identifiability_json(
    store: SqlStore, views: StudyViewCache, study_id: str, principal: Principal, held: str | None = None
) -> Served:
    study = store.study_version(study_id, principal.visible_to)
    # Once per completed batch (and status), not per change of the study row (a batch queued,
    # then saved, changes it twice), in the low-priority child process (``offload``): a build
    # reads and evaluates every trial and fits a Gaussian process, seconds of CPU for a long study,
    # so it rests IDENTIFIABILITY_REST times as long before the next (``views``).
    version = (study.generation, study.status)
    build = lambda: in_child(_identifiability, store, study_id)  # noqa: E731 - one line, one use
    return views.serve(
        "identifiability", study_id, version, build, stale_ok=True, rest=IDENTIFIABILITY_REST, held=held
    )


def _progress(store: SqlStore, views: StudyViewCache, study_id: str) -> bytes:
    """Progress as JSON, folding only the batches completed since the tracker ``views`` keeps for the
    study (a view-building process's own cache, or the server's)."""
    record = store.load_study(study_id)
    validation = (record.recommendation or {}).get("validation", [])
    folded = views.kept("progress", study_id, _Folded)
    with folded.lock:
        if folded.tracker is None:
            folded.tracker = ProgressTracker(StudyDefinition.model_validate(record.definition))
        tracker = folded.tracker
        if tracker.next_batch < record.generation:
            tracker.advance(store.batch_trials(study_id, tracker.next_batch, record.generation),
                            record.generation)
        progress = tracker.progress(validation)
    return StudyProgressRead(study_id=study_id, **progress.as_json()).model_dump_json().encode()


def _identifiability(store: SqlStore, study_id: str) -> bytes:
    definition = StudyDefinition.model_validate(store.load_study(study_id).definition)
    evaluations = evaluate(store.trials(study_id), definition, definition.n_items(), intervals=False)
    space = ParameterSpace(definition.parameters)
    result = study_identifiability(evaluations, definition, space)
    return IdentifiabilityRead(study_id=study_id, **result).model_dump_json().encode()
