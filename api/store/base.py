"""What every part of the SQL store shares: the session, ids, pages and row conversions."""

from __future__ import annotations

import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa

from api.db import session_factory, unit_of_work
from api.models import StudyRow, TrialRow
from dem.result import SimulationResult
from optimizer.protocols import TrialRecord, TrialSpec, TrialState

ALL_OWNERS = None  # ``visible_to=ALL_OWNERS``: an admin's view, no owner filter
# The values of an UPDATE of a study row that is no change of what clients see (a lease, the
# stored warnings, a trial write's number): its ``updated_at`` and its change number stay.
KEEP_VERSION = {
    "updated_at": StudyRow.updated_at, "trial_changes": StudyRow.trial_changes,
    "change_number": StudyRow.change_number,
}


def new_id(prefix: str) -> str:
    return f"{prefix}{uuid.uuid4().hex[:12]}"


@dataclass(frozen=True)
class Page:
    """One page of a list and the total number of matching rows."""

    items: list[Any]
    total: int



class StoreBase:
    """The engine and its unit of work; the resource stores are mixed in on top of it."""

    def __init__(self, engine: sa.Engine):
        self.engine = engine
        self._sessions = session_factory(engine)

    def session(self):
        """A unit of work on this store's database (commit on exit, roll back on error)."""
        return unit_of_work(self._sessions)

    def _change_numbers(self, s, study_ids: Iterable[str]) -> dict[str, int]:
        """The next change number of each study, for the writes to its trials in the unit of work
        ``s`` (``TrialRow.change_number``; the driver's cursor, ``changed_trials``). Taking it
        updates the study's row, which the database keeps locked until the commit (SQLite: one
        writer at a time), so numbers are handed out in commit order: a reader that saw number n
        has seen every write numbered up to n, however late a write committed or whatever its
        process's clock said (a cursor of wall-clock stamps could miss those). Called before the
        unit of work touches the trials, in one order of studies, so writers lock alike."""
        numbers = {}
        for study_id in sorted(set(study_ids)):
            numbers[study_id] = s.execute(
                sa.update(StudyRow)
                .where(StudyRow.id == study_id)
                .values(KEEP_VERSION | {"trial_changes": StudyRow.trial_changes + 1})
                .returning(StudyRow.trial_changes)
                .execution_options(synchronize_session=False)
            ).scalar_one_or_none() or 0
        return numbers

    def _newest_first(self, model, visible_to: str | None, limit: int, offset: int) -> Page:
        """A page of an owned resource (shapes, simulations), newest first, with the total."""
        where = owner_clause(model.owner, visible_to)
        with self.session() as s:
            total = s.scalar(sa.select(sa.func.count()).select_from(model).where(where))
            rows = s.scalars(
                sa.select(model).where(where).order_by(model.created_at.desc(), model.id)
                .limit(limit).offset(offset)
            ).all()
            return Page(list(rows), int(total or 0))


def owner_clause(column, visible_to: str | None):
    return sa.true() if visible_to is ALL_OWNERS else column == visible_to


def result_columns(result: SimulationResult) -> dict[str, Any]:
    return {
        "status": result.status.value,
        "n_remaining": result.n_remaining,
        "responses": dict(result.responses),
        "wall_time_s": result.wall_time_s,
        "result": result.model_dump(mode="json"),
    }


def chunks(items: list, size: int) -> Iterable[list]:
    for start in range(0, len(items), size):
        yield items[start:start + size]


def trial_record(row: TrialRow) -> TrialRecord:
    spec = TrialSpec(
        trial_id=row.id, study_id=row.study_id, individual=row.individual, generation=row.generation,
        replicate=row.replicate, seed=row.seed, params=dict(row.params), scenario=dict(row.scenario),
        timeout_s=row.timeout_s, engine=row.engine, engine_options=row.engine_options,
    )
    result = SimulationResult.model_validate(row.result) if row.result is not None else None
    return TrialRecord(
        spec=spec, state=TrialState(row.state), result=result, worker=row.worker, attempts=row.attempts
    )

