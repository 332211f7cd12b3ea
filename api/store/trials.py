"""Trials in the SQL store as the driver writes them: added, queued (again, when lost), running, recorded.

``record_result`` is a conditional UPDATE (``... WHERE state not in (done, cancelled)``), so the
database, not a read-then-write in Python, decides which of two racing results wins.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from datetime import timedelta

import sqlalchemy as sa
from sqlalchemy.orm import undefer

from api.errors import NotFoundError
from api.models import StudyRow, TrialRow, utcnow
from api.store.base import StoreBase, chunks, result_columns, trial_record
from optimizer.protocols import TrialOutcome, TrialRecord, TrialSpec, TrialState

log = logging.getLogger(__name__)


class TrialStore(StoreBase):
    def add_trials(self, specs: Sequence[TrialSpec]) -> None:
        if not specs:
            return
        with self.session() as s:
            ids = [spec.trial_id for spec in specs]
            existing = set()
            for chunk in chunks(ids, 500):
                existing.update(s.scalars(sa.select(TrialRow.id).where(TrialRow.id.in_(chunk))))
            now = utcnow()
            numbers = self._change_numbers(
                s, {spec.study_id for spec in specs if spec.trial_id not in existing}
            )
            new_rows = [
                {
                    "id": spec.trial_id, "study_id": spec.study_id, "individual": spec.individual,
                    "generation": spec.generation, "replicate": spec.replicate, "seed": spec.seed,
                    "params": dict(spec.params), "scenario": dict(spec.scenario),
                    "engine": spec.engine, "engine_options": spec.engine_options,
                    "timeout_s": spec.timeout_s, "state": TrialState.PENDING.value,
                    "message": "", "attempts": 0, "pareto": False,
                    "created_at": now, "updated_at": now, "change_number": numbers[spec.study_id],
                }
                for spec in specs
                if spec.trial_id not in existing
            ]
            if new_rows:
                s.execute(sa.insert(TrialRow), new_rows)
                # The study's updated_at versions its cached views (``api/services/views.py``);
                # new trials change the unfiltered trial count.
                s.execute(
                    sa.update(StudyRow)
                    .where(StudyRow.id.in_({row["study_id"] for row in new_rows}))
                    .values(updated_at=now)
                )

    def trials(self, study_id: str, states: Sequence[TrialState] | None = None) -> list[TrialRecord]:
        query = _records(study_id)
        if states is not None:
            query = query.where(TrialRow.state.in_([st.value for st in states]))
        with self.session() as s:
            return [trial_record(row) for row in s.scalars(query)]

    def batch_trials(self, study_id: str, first: int, end: int) -> list[TrialRecord]:
        """The trials of batches ``first`` to ``end`` (exclusive): what a progress view that kept
        the earlier batches still needs."""
        query = _records(study_id).where(TrialRow.generation >= first, TrialRow.generation < end)
        with self.session() as s:
            return [trial_record(row) for row in s.scalars(query)]

    def changed_trials(self, study_id: str, since: int | None = None) -> tuple[list[TrialRecord], int | None]:
        """Trials written after the cursor ``since``, a change number of the study (every write
        to its trials takes the next one, in commit order: ``_change_numbers``), and the newest
        number read as the next cursor. Wall-clock stamps missed a row committed late with an
        older stamp (another process's clock behind, a slow commit); numbers cannot."""
        query = _records(study_id)
        if since is not None:
            query = query.where(TrialRow.change_number > since)
        with self.session() as s:
            rows = list(s.scalars(query))
            newest = max((row.change_number for row in rows), default=since)
            return [trial_record(row) for row in rows], newest

    def mark_queued(self, trial_ids: Sequence[str], message: str = "") -> None:
        """Queued: the driver handed them to the executor, the first time or again (a trial it
        finds running but unknown to the executor was lost with a restarted process or a flushed
        queue, and waits for a worker again); ``message`` says why they may wait (no worker has
        their engine yet)."""
        self._move(
            trial_ids, (TrialState.PENDING, TrialState.QUEUED, TrialState.RUNNING),
            state=TrialState.QUEUED.value, attempts=TrialRow.attempts + 1, message=message,
        )

    def mark_running(self, trial_id: str, worker: str | None = None) -> None:
        """A worker took it: whatever it waited for (``mark_queued``'s message) is over."""
        self._move(
            [trial_id], (TrialState.PENDING, TrialState.QUEUED),
            state=TrialState.RUNNING.value, worker=worker, started_at=utcnow(), message="",
        )

    def _move(self, trial_ids: Sequence[str], from_states: Sequence[TrialState], **values) -> None:
        """The trials among ``trial_ids`` in one of ``from_states`` get ``values``: the database
        decides, so a trial that moved on meanwhile (done, cancelled) is left as it is."""
        with self.session() as s:
            studies: dict[str, list[str]] = {}
            for chunk in chunks(list(trial_ids), 500):
                rows = s.execute(sa.select(TrialRow.id, TrialRow.study_id).where(TrialRow.id.in_(chunk)))
                for trial, study in rows:
                    studies.setdefault(study, []).append(trial)
            numbers = self._change_numbers(s, studies)
            for study, ids in studies.items():
                for chunk in chunks(ids, 500):
                    s.execute(
                        sa.update(TrialRow)
                        .where(TrialRow.id.in_(chunk), TrialRow.state.in_([st.value for st in from_states]))
                        .values(updated_at=utcnow(), change_number=numbers[study], **values)
                    )

    def record_result(self, outcome: TrialOutcome) -> bool:
        result = outcome.result
        now = utcnow()
        values = result_columns(result) | {
            "state": TrialState.DONE.value, "cost": result.cost, "dt": result.dt,
            "full_load_factor": result.full_load_factor,
            "message": result.message, "finished_at": now, "updated_at": now,
            "attempts": TrialRow.attempts + outcome.retries,
        }
        if outcome.worker is not None:
            values["worker"] = outcome.worker
        # A run shorter than the driver's poll is never seen running: its start is then its end
        # less the run's own wall time, so every finished trial has one.
        started = now - timedelta(seconds=result.wall_time_s)
        values["started_at"] = sa.func.coalesce(TrialRow.started_at, started)
        with self.session() as s:
            study = s.scalar(sa.select(TrialRow.study_id).where(TrialRow.id == outcome.trial_id))
            values["change_number"] = self._change_numbers(s, [study]).get(study, 0) if study else 0
            recorded = s.execute(
                sa.update(TrialRow)
                .where(
                    TrialRow.id == outcome.trial_id,
                    TrialRow.state.not_in([TrialState.DONE.value, TrialState.CANCELLED.value]),
                )
                .values(**values)
            ).rowcount
        if not recorded:
            log.info("result for trial %s not recorded: already done, cancelled or unknown", outcome.trial_id)
        return bool(recorded)

    def get_trial(self, study_id: str, trial_id: str) -> TrialRow:
        with self.session() as s:
            row = s.scalars(
                sa.select(TrialRow)
                .where(TrialRow.study_id == study_id, TrialRow.id == trial_id)
                .options(undefer(TrialRow.result))
            ).one_or_none()
            if row is None:
                raise NotFoundError(
                    f"no trial {trial_id!r} in study {study_id!r}; list them with "
                    f"GET /api/v1/studies/{study_id}/trials"
                )
            return row



def _records(study_id: str) -> sa.Select:
    """A study's trials with what a ``TrialRecord`` needs, in (individual, replicate) order."""
    return (
        sa.select(TrialRow)
        .where(TrialRow.study_id == study_id)
        .options(undefer(TrialRow.scenario), undefer(TrialRow.result))
        .order_by(TrialRow.individual, TrialRow.replicate)
    )
