"""The SQL store: the optimiser's ``Store`` protocol on SQLAlchemy, plus the reads the API needs.

What it is for: every write a study, a trial or a single simulation goes through, each method one
transaction (``api.db.unit_of_work``), identical on SQLite and PostgreSQL. ``demcal calibrate``
and ``demcal serve`` use the same class, so the service shows studies run from the CLI.

What it must not do: decide business rules (which status transitions are allowed, what a valid
definition is: ``api/services/``), or know about HTTP.

Idempotence: ``record_result`` and ``record_simulation_result`` are conditional UPDATEs
(``... WHERE state <> 'done'``), so the database, not a read-then-write in Python, decides
which of two racing results wins; the loser gets ``False`` and changes nothing.

For the background loop that runs single simulations (``POST /api/v1/simulations``):
``pending_simulations()`` lists what to enqueue, ``mark_simulation_queued(id)`` records the hand
over (only from ``pending``), ``mark_simulation_running(id, worker)`` when a worker starts, and
``record_simulation_result(id, result, worker)`` stores the outcome once (``False`` if already
stored). A simulation left ``queued`` after a Redis flush can be sent back to ``pending`` with
``requeue_simulations(ids)``.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import undefer

from api.db import session_factory, unit_of_work
from api.errors import NotFoundError
from api.models import (
    ShapeRow,
    SimulationRow,
    StudyRow,
    TrialRow,
    UTCDateTime,
    encode_value,
    utcnow,
)
from dem.result import SimulationResult
from optimizer.protocols import (
    StudyRecord,
    StudyStatus,
    TrialOutcome,
    TrialRecord,
    TrialSpec,
    TrialState,
)

log = logging.getLogger(__name__)

ALL_OWNERS = None  # ``visible_to=ALL_OWNERS``: an admin's view, no owner filter


def new_id(prefix: str) -> str:
    return f"{prefix}{uuid.uuid4().hex[:12]}"


@dataclass(frozen=True)
class Page:
    """One page of a list and the total number of matching rows."""

    items: list[Any]
    total: int


@dataclass(frozen=True)
class TrialFilter:
    generation: int | None = None
    state: TrialState | None = None
    pareto: bool | None = None
    updated_since: datetime | None = None


# The columns of a trial as lists and plots show it (``api.schemas.TrialRead``).
TRIAL_READ_COLUMNS = (
    TrialRow.id, TrialRow.generation, TrialRow.individual, TrialRow.replicate, TrialRow.seed,
    TrialRow.params, TrialRow.state, TrialRow.status, TrialRow.n_remaining, TrialRow.wall_time_s,
    TrialRow.cost, TrialRow.pareto, TrialRow.worker, TrialRow.attempts, TrialRow.message,
    TrialRow.updated_at, TrialRow.f1_value, TrialRow.f1_kind, TrialRow.f2_value, TrialRow.f2_kind,
)


def _owner_clause(column, visible_to: str | None):
    return sa.true() if visible_to is ALL_OWNERS else column == visible_to


def _result_columns(result: SimulationResult) -> dict[str, Any]:
    return {
        "status": result.status.value,
        "n_remaining": result.n_remaining,
        "wall_time_s": result.wall_time_s,
        "result": result.model_dump(mode="json"),
    }


class SqlStore:
    """The store of studies, trials, shapes and single simulations in one SQL database."""

    def __init__(self, engine: sa.Engine):
        self.engine = engine
        self._sessions = session_factory(engine)

    def session(self):
        """A unit of work on this store's database (commit on exit, roll back on error)."""
        return unit_of_work(self._sessions)

    # ---- studies ---------------------------------------------------------------------------

    def create_study(
        self, definition_json: dict[str, Any], owner: str | None, name: str | None = None
    ) -> str:
        """Store a validated study definition as a new study in status ``created``; its id."""
        study_id = new_id("st-")
        with self.session() as s:
            s.add(
                StudyRow(
                    id=study_id,
                    name=name or str(definition_json.get("name") or study_id),
                    owner=owner,
                    status=StudyStatus.CREATED.value,
                    definition=definition_json,
                    extra={},
                )
            )
        log.info("study %s created for owner %s", study_id, owner)
        return study_id

    def _study_row(self, s, study_id: str, visible_to: str | None = ALL_OWNERS) -> StudyRow:
        row = s.get(StudyRow, study_id)
        if row is None or not (visible_to is ALL_OWNERS or row.owner == visible_to):
            raise NotFoundError(f"no study {study_id!r}; list your studies with GET /api/v1/studies")
        return row

    def get_study(self, study_id: str, visible_to: str | None = ALL_OWNERS) -> StudyRow:
        with self.session() as s:
            return self._study_row(s, study_id, visible_to)

    def study_version(self, study_id: str, visible_to: str | None = ALL_OWNERS) -> sa.Row:
        """(id, updated_at, generation) of a visible study, without loading its JSON columns:
        the check that a hot read may go ahead, and the version of cached views."""
        with self.session() as s:
            row = s.execute(
                sa.select(StudyRow.id, StudyRow.owner, StudyRow.updated_at, StudyRow.generation)
                .where(StudyRow.id == study_id)
            ).one_or_none()
        if row is None or not (visible_to is ALL_OWNERS or row.owner == visible_to):
            raise NotFoundError(f"no study {study_id!r}; list your studies with GET /api/v1/studies")
        return row

    def load_study(self, study_id: str) -> StudyRecord:
        with self.session() as s:
            row = s.scalars(
                sa.select(StudyRow).where(StudyRow.id == study_id).options(undefer(StudyRow.ga_state))
            ).one_or_none()
            if row is None:
                raise NotFoundError(f"no study {study_id!r}")
            return StudyRecord(
                study_id=row.id,
                definition=row.definition,
                status=StudyStatus(row.status),
                generation=row.generation,
                ga_state=row.ga_state,
                recommendation=row.recommendation,
                message=row.message,
                extra=dict(row.extra or {}),
            )

    def list_studies(
        self,
        visible_to: str | None = ALL_OWNERS,
        status: StudyStatus | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> Page:
        where = [_owner_clause(StudyRow.owner, visible_to)]
        if status is not None:
            where.append(StudyRow.status == status.value)
        with self.session() as s:
            total = s.scalar(sa.select(sa.func.count()).select_from(StudyRow).where(*where))
            rows = s.scalars(
                sa.select(StudyRow).where(*where).order_by(StudyRow.created_at.desc(), StudyRow.id)
                .limit(limit).offset(offset)
            ).all()
            return Page(list(rows), int(total or 0))

    def studies_in(self, statuses: Iterable[StudyStatus]) -> list[str]:
        """Ids of the studies in these statuses, oldest first (what a driver loop should advance)."""
        with self.session() as s:
            return list(
                s.scalars(
                    sa.select(StudyRow.id)
                    .where(StudyRow.status.in_([st.value for st in statuses]))
                    .order_by(StudyRow.created_at)
                )
            )

    def set_status(self, study_id: str, status: StudyStatus, message: str = "") -> None:
        with self.session() as s:
            row = self._study_row(s, study_id)
            row.status = status.value
            row.message = message
            row.started_at, row.finished_at = _study_times(row.started_at, row.finished_at, status)

    def transition(
        self, study_id: str, allowed_from: Iterable[StudyStatus], to: StudyStatus, message: str = ""
    ) -> bool:
        """Set ``to`` only if the study is in one of ``allowed_from``, atomically; whether it did."""
        allowed = [st.value for st in allowed_from]
        with self.session() as s:
            done = s.execute(
                sa.update(StudyRow)
                .where(StudyRow.id == study_id, StudyRow.status.in_(allowed))
                .values(status=to.value, message=message, updated_at=utcnow(), **_time_columns(to))
            ).rowcount
            if done and to is StudyStatus.CANCELLED:
                s.execute(
                    sa.update(TrialRow)
                    .where(
                        TrialRow.study_id == study_id,
                        TrialRow.state.in_([TrialState.PENDING.value, TrialState.QUEUED.value]),
                    )
                    .values(state=TrialState.CANCELLED.value, updated_at=utcnow())
                )
            return bool(done)

    def delete_study(self, study_id: str) -> None:
        with self.session() as s:
            # Explicit delete of the trials: ON DELETE CASCADE needs PRAGMA foreign_keys on SQLite
            # connections made by other tools; this way it holds whoever made the connection.
            s.execute(sa.delete(TrialRow).where(TrialRow.study_id == study_id))
            s.execute(sa.delete(StudyRow).where(StudyRow.id == study_id))

    def save_generation(
        self,
        study_id: str,
        generation: int,
        ga_state: bytes,
        pareto_trial_ids: Sequence[str],
        recommendation: dict[str, Any] | None,
        objectives: Mapping[str, Sequence[float]] | None = None,
    ) -> None:
        """Persist the GA after a generation, atomically with its Pareto ranking and objectives.

        ``objectives`` maps trial ids to their (f1, f2) (values may be infinite). Without it the
        objectives of every finished individual are computed here with the optimiser's own
        ``optimizer.objectives.evaluate``, so that lists and plots show the f1/f2 the GA was told.
        """
        with self.session() as s:
            row = self._study_row(s, study_id)
            if objectives is None:
                objectives = self._evaluate(s, row)
            row.generation = generation
            row.ga_state = ga_state
            row.recommendation = recommendation
            now = utcnow()
            s.execute(
                sa.update(TrialRow)
                .where(TrialRow.study_id == study_id, TrialRow.pareto.is_(True))
                .values(pareto=False, updated_at=now)
            )
            for chunk in _chunks(list(pareto_trial_ids), 500):
                s.execute(
                    sa.update(TrialRow)
                    .where(TrialRow.study_id == study_id, TrialRow.id.in_(chunk))
                    .values(pareto=True, updated_at=now)
                )
            if objectives:
                updates = []
                for tid, values in objectives.items():
                    f1_value, f1_kind = encode_value(values[0])
                    f2_value, f2_kind = encode_value(values[1] if len(values) > 1 else None)
                    updates.append(
                        {"id": tid, "f1_value": f1_value, "f1_kind": f1_kind,
                         "f2_value": f2_value, "f2_kind": f2_kind, "updated_at": now}
                    )
                s.execute(sa.update(TrialRow), updates)

    def _evaluate(self, s, study: StudyRow) -> dict[str, tuple[float, float]]:
        from optimizer.objectives import evaluate
        from optimizer.study import StudyDefinition

        definition = StudyDefinition.model_validate(study.definition)
        rows = s.scalars(
            sa.select(TrialRow)
            .where(TrialRow.study_id == study.id, TrialRow.state == TrialState.DONE.value)
            .options(undefer(TrialRow.scenario), undefer(TrialRow.result))
        )
        records = [_trial_record(row) for row in rows if row.result is not None]
        return {
            tid: (evaluation.f1, evaluation.f2)
            for evaluation in evaluate(records, definition, definition.n_items())
            for tid in evaluation.trial_ids
        }

    # ---- trials ----------------------------------------------------------------------------

    def add_trials(self, specs: Sequence[TrialSpec]) -> None:
        if not specs:
            return
        with self.session() as s:
            ids = [spec.trial_id for spec in specs]
            existing = set()
            for chunk in _chunks(ids, 500):
                existing.update(s.scalars(sa.select(TrialRow.id).where(TrialRow.id.in_(chunk))))
            now = utcnow()
            new_rows = [
                {
                    "id": spec.trial_id, "study_id": spec.study_id, "individual": spec.individual,
                    "generation": spec.generation, "replicate": spec.replicate, "seed": spec.seed,
                    "params": dict(spec.params), "scenario": dict(spec.scenario),
                    "timeout_s": spec.timeout_s, "state": TrialState.PENDING.value,
                    "message": "", "attempts": 0, "pareto": False,
                    "created_at": now, "updated_at": now,
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
        query = (
            sa.select(TrialRow)
            .where(TrialRow.study_id == study_id)
            .options(undefer(TrialRow.scenario), undefer(TrialRow.result))
            .order_by(TrialRow.individual, TrialRow.replicate)
        )
        if states is not None:
            query = query.where(TrialRow.state.in_([st.value for st in states]))
        with self.session() as s:
            return [_trial_record(row) for row in s.scalars(query)]

    def mark_queued(self, trial_ids: Sequence[str]) -> None:
        with self.session() as s:
            for chunk in _chunks(list(trial_ids), 500):
                s.execute(
                    sa.update(TrialRow)
                    .where(
                        TrialRow.id.in_(chunk),
                        TrialRow.state.in_([TrialState.PENDING.value, TrialState.QUEUED.value]),
                    )
                    .values(state=TrialState.QUEUED.value, attempts=TrialRow.attempts + 1,
                            updated_at=utcnow())
                )

    def mark_running(self, trial_id: str, worker: str | None = None) -> None:
        with self.session() as s:
            now = utcnow()
            s.execute(
                sa.update(TrialRow)
                .where(
                    TrialRow.id == trial_id,
                    TrialRow.state.in_([TrialState.PENDING.value, TrialState.QUEUED.value]),
                )
                .values(state=TrialState.RUNNING.value, worker=worker, started_at=now, updated_at=now)
            )

    def requeue(self, trial_ids: Sequence[str]) -> None:
        """Send trials lost in flight (queued or running, unknown to the executor) back to pending."""
        with self.session() as s:
            for chunk in _chunks(list(trial_ids), 500):
                s.execute(
                    sa.update(TrialRow)
                    .where(
                        TrialRow.id.in_(chunk),
                        TrialRow.state.in_([TrialState.QUEUED.value, TrialState.RUNNING.value]),
                    )
                    .values(state=TrialState.PENDING.value, updated_at=utcnow())
                )

    def record_result(self, outcome: TrialOutcome) -> bool:
        result = outcome.result
        now = utcnow()
        values = _result_columns(result) | {
            "state": TrialState.DONE.value, "cost": result.cost, "dt": result.dt,
            "message": result.message, "finished_at": now, "updated_at": now,
        }
        if outcome.worker is not None:
            values["worker"] = outcome.worker
        with self.session() as s:
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

    @staticmethod
    def _trial_clauses(study_id: str, where: TrialFilter) -> list:
        clauses = [TrialRow.study_id == study_id]
        if where.generation is not None:
            clauses.append(TrialRow.generation == where.generation)
        if where.state is not None:
            clauses.append(TrialRow.state == where.state.value)
        if where.pareto is not None:
            clauses.append(TrialRow.pareto.is_(where.pareto))
        if where.updated_since is not None:
            # ">=": rows updated in the same clock tick as the previous poll are sent again rather
            # than missed; clients upsert by id.
            clauses.append(TrialRow.updated_at >= where.updated_since)
        return clauses

    def trial_count(self, study_id: str, where: TrialFilter) -> int:
        clauses = self._trial_clauses(study_id, where)
        with self.session() as s:
            return int(s.scalar(sa.select(sa.func.count()).select_from(TrialRow).where(*clauses)) or 0)

    def trial_page_rows(
        self, study_id: str, where: TrialFilter, limit: int, offset: int, total: int | None = None
    ) -> Page:
        """A page of the trial list as plain rows of the columns ``TrialRead`` needs: no ORM
        objects are built (that was most of a page's cost), and no JSON blob but ``params``.
        ``total``, when the caller knows it, saves the count query."""
        clauses = self._trial_clauses(study_id, where)
        with self.session() as s:
            if total is None:
                total = s.scalar(sa.select(sa.func.count()).select_from(TrialRow).where(*clauses))
            rows = s.execute(
                sa.select(*TRIAL_READ_COLUMNS).where(*clauses)
                .order_by(TrialRow.generation, TrialRow.individual, TrialRow.replicate)
                .limit(limit).offset(offset)
            ).all()
            return Page(list(rows), int(total or 0))

    def pareto_columns(self, study_id: str) -> list[sa.Row]:
        """The Pareto members' columns (as ``trial_columns``), without building ORM objects."""
        with self.session() as s:
            return list(
                s.execute(
                    sa.select(*TRIAL_READ_COLUMNS)
                    .where(TrialRow.study_id == study_id, TrialRow.pareto.is_(True))
                )
            )

    def best_f1s(self, study_ids: Sequence[str]) -> dict[str, float]:
        """The lowest finite f1 of an ok trial per study, for a page of studies in one query."""
        if not study_ids:
            return {}
        with self.session() as s:
            return {
                study_id: float(f1)
                for study_id, f1 in s.execute(
                    sa.select(TrialRow.study_id, sa.func.min(TrialRow.f1_value))
                    .where(
                        TrialRow.study_id.in_(list(study_ids)), TrialRow.status == "ok",
                        TrialRow.f1_kind == "finite",
                    )
                    .group_by(TrialRow.study_id)
                )
                if f1 is not None
            }

    def trial_columns(self, study_id: str) -> list[sa.Row]:
        """Every trial's plot and summary columns, without the JSON blobs (for summaries)."""
        with self.session() as s:
            return list(
                s.execute(
                    sa.select(
                        TrialRow.id, TrialRow.generation, TrialRow.individual, TrialRow.replicate,
                        TrialRow.state, TrialRow.status, TrialRow.n_remaining, TrialRow.wall_time_s,
                        TrialRow.cost, TrialRow.pareto, TrialRow.f1_value, TrialRow.f1_kind,
                        TrialRow.f2_value, TrialRow.f2_kind, TrialRow.params,
                    )
                    .where(TrialRow.study_id == study_id)
                    .order_by(TrialRow.generation, TrialRow.individual, TrialRow.replicate)
                )
            )

    def pareto_rows(self, study_id: str) -> list[TrialRow]:
        with self.session() as s:
            return list(
                s.scalars(sa.select(TrialRow).where(TrialRow.study_id == study_id, TrialRow.pareto.is_(True)))
            )

    def best_trial(self, study_id: str) -> TrialRow | None:
        """The ok trial with the lowest finite f1, fastest (f2) among equals; None before ranking."""
        with self.session() as s:
            return s.scalars(
                sa.select(TrialRow)
                .where(
                    TrialRow.study_id == study_id,
                    TrialRow.status == "ok",
                    TrialRow.f1_kind == "finite",
                )
                .order_by(TrialRow.f1_value, TrialRow.f2_value.nulls_last(), TrialRow.id)
                .limit(1)
            ).one_or_none()

    def trial_rows_for_export(self, study_id: str) -> list[TrialRow]:
        with self.session() as s:
            return list(
                s.scalars(
                    sa.select(TrialRow)
                    .where(TrialRow.study_id == study_id)
                    .order_by(TrialRow.generation, TrialRow.individual, TrialRow.replicate)
                )
            )

    def done_counts(self, study_ids: Sequence[str]) -> dict[str, int]:
        """Finished trials per study, for a page of studies in one query."""
        if not study_ids:
            return {}
        with self.session() as s:
            return {
                study_id: int(n)
                for study_id, n in s.execute(
                    sa.select(TrialRow.study_id, sa.func.count())
                    .where(TrialRow.study_id.in_(list(study_ids)), TrialRow.state == TrialState.DONE.value)
                    .group_by(TrialRow.study_id)
                )
            }

    def trial_state_counts(self, study_id: str | None = None) -> dict[str, int]:
        query = sa.select(TrialRow.state, sa.func.count()).group_by(TrialRow.state)
        if study_id is not None:
            query = query.where(TrialRow.study_id == study_id)
        with self.session() as s:
            return {state: int(n) for state, n in s.execute(query)}

    def study_status_counts(self) -> dict[str, int]:
        with self.session() as s:
            return {
                status: int(n)
                for status, n in s.execute(
                    sa.select(StudyRow.status, sa.func.count()).group_by(StudyRow.status)
                )
            }

    def simulation_seconds_total(self) -> float:
        """Wall-clock seconds of every finished trial and single simulation."""
        with self.session() as s:
            trials = s.scalar(sa.select(sa.func.coalesce(sa.func.sum(TrialRow.wall_time_s), 0.0)))
            singles = s.scalar(sa.select(sa.func.coalesce(sa.func.sum(SimulationRow.wall_time_s), 0.0)))
            return float(trials or 0.0) + float(singles or 0.0)

    # ---- single simulations ----------------------------------------------------------------

    def create_simulation(
        self,
        scenario: dict[str, Any],
        params: dict[str, float],
        seed: int,
        owner: str | None,
        timeout_s: float | None = None,
    ) -> str:
        sim_id = new_id("sim-")
        with self.session() as s:
            s.add(
                SimulationRow(
                    id=sim_id, owner=owner, scenario=scenario, params=params, seed=seed,
                    timeout_s=timeout_s, state=TrialState.PENDING.value, attempts=0,
                )
            )
        return sim_id

    def get_simulation(self, sim_id: str, visible_to: str | None = ALL_OWNERS) -> SimulationRow:
        with self.session() as s:
            row = s.get(SimulationRow, sim_id)
            if row is None or not (visible_to is ALL_OWNERS or row.owner == visible_to):
                raise NotFoundError(f"no simulation {sim_id!r}; POST /api/v1/simulations starts one")
            return row

    def list_simulations(self, visible_to: str | None, limit: int, offset: int) -> Page:
        return self._newest_first(SimulationRow, visible_to, limit, offset)

    def pending_simulations(self, limit: int = 100) -> list[TrialSpec]:
        """Single simulations waiting to be enqueued, oldest first, as specs a worker can run.

        The spec's ``trial_id`` is the simulation id and its ``study_id`` is empty.
        """
        with self.session() as s:
            rows = s.scalars(
                sa.select(SimulationRow)
                .where(SimulationRow.state == TrialState.PENDING.value)
                .order_by(SimulationRow.created_at).limit(limit)
            ).all()
            return [
                TrialSpec(
                    trial_id=row.id, study_id="", individual=0, generation=0, replicate=0,
                    seed=row.seed, params=dict(row.params), scenario=dict(row.scenario),
                    timeout_s=row.timeout_s,
                )
                for row in rows
            ]

    def _move_simulations(self, sim_ids: Sequence[str], from_states: Sequence[TrialState], **values) -> int:
        with self.session() as s:
            return s.execute(
                sa.update(SimulationRow)
                .where(SimulationRow.id.in_(list(sim_ids)),
                       SimulationRow.state.in_([st.value for st in from_states]))
                .values(updated_at=utcnow(), **values)
            ).rowcount

    def mark_simulation_queued(self, sim_id: str) -> bool:
        """pending -> queued; False if the simulation was not pending (already handed over)."""
        return bool(
            self._move_simulations(
                [sim_id], [TrialState.PENDING], state=TrialState.QUEUED.value,
                attempts=SimulationRow.attempts + 1,
            )
        )

    def mark_simulation_running(self, sim_id: str, worker: str | None = None) -> bool:
        return bool(
            self._move_simulations(
                [sim_id], [TrialState.PENDING, TrialState.QUEUED],
                state=TrialState.RUNNING.value, worker=worker,
            )
        )

    def requeue_simulations(self, sim_ids: Sequence[str]) -> int:
        """queued/running -> pending for simulations lost in flight; how many moved."""
        return self._move_simulations(
            sim_ids, [TrialState.QUEUED, TrialState.RUNNING], state=TrialState.PENDING.value
        )

    def record_simulation_result(
        self, sim_id: str, result: SimulationResult, worker: str | None = None
    ) -> bool:
        """Store a single simulation's result once; False (nothing changed) if already stored."""
        values = _result_columns(result) | {"state": TrialState.DONE.value, "finished_at": utcnow()}
        if worker is not None:
            values["worker"] = worker
        return bool(
            self._move_simulations(
                [sim_id], [TrialState.PENDING, TrialState.QUEUED, TrialState.RUNNING], **values
            )
        )

    # ---- shapes ----------------------------------------------------------------------------

    def add_shape(self, row: ShapeRow) -> str:
        with self.session() as s:
            s.add(row)
        return row.id

    def get_shape(
        self, shape_id: str, visible_to: str | None = ALL_OWNERS, with_data: bool = False
    ) -> ShapeRow:
        with self.session() as s:
            query = sa.select(ShapeRow).where(ShapeRow.id == shape_id)
            if with_data:
                query = query.options(undefer(ShapeRow.data))
            row = s.scalars(query).one_or_none()
            if row is None or not (visible_to is ALL_OWNERS or row.owner == visible_to):
                raise NotFoundError(f"no shape {shape_id!r}; list your shapes with GET /api/v1/shapes")
            return row

    def list_shapes(self, visible_to: str | None, limit: int, offset: int) -> Page:
        return self._newest_first(ShapeRow, visible_to, limit, offset)

    def _newest_first(self, model, visible_to: str | None, limit: int, offset: int) -> Page:
        """A page of an owned resource (shapes, simulations), newest first, with the total."""
        where = _owner_clause(model.owner, visible_to)
        with self.session() as s:
            total = s.scalar(sa.select(sa.func.count()).select_from(model).where(where))
            rows = s.scalars(
                sa.select(model).where(where).order_by(model.created_at.desc(), model.id)
                .limit(limit).offset(offset)
            ).all()
            return Page(list(rows), int(total or 0))

    def delete_shape(self, shape_id: str) -> None:
        with self.session() as s:
            s.execute(sa.delete(ShapeRow).where(ShapeRow.id == shape_id))


FINISHED_STUDIES = (StudyStatus.DONE, StudyStatus.CANCELLED, StudyStatus.FAILED)


def _study_times(
    started_at: datetime | None, finished_at: datetime | None, status: StudyStatus
) -> tuple[datetime | None, datetime | None]:
    """(started_at, finished_at) after a move to ``status``: the first start is kept; a finish
    time is set on the move to a finished status (and cleared if a study ever runs again)."""
    now = utcnow()
    if status is StudyStatus.RUNNING:
        return started_at or now, None
    if status in FINISHED_STUDIES:
        return started_at, finished_at or now
    return started_at, finished_at


def _now_literal():
    return sa.literal(utcnow(), UTCDateTime())


def _time_columns(status: StudyStatus) -> dict[str, Any]:
    """The same rule as ``_study_times`` as UPDATE values, for conditional (atomic) transitions."""
    if status is StudyStatus.RUNNING:
        return {"started_at": sa.func.coalesce(StudyRow.started_at, _now_literal()), "finished_at": None}
    if status in FINISHED_STUDIES:
        return {"finished_at": sa.func.coalesce(StudyRow.finished_at, _now_literal())}
    return {}


def _chunks(items: list, size: int) -> Iterable[list]:
    for start in range(0, len(items), size):
        yield items[start:start + size]


def _trial_record(row: TrialRow) -> TrialRecord:
    spec = TrialSpec(
        trial_id=row.id, study_id=row.study_id, individual=row.individual, generation=row.generation,
        replicate=row.replicate, seed=row.seed, params=dict(row.params), scenario=dict(row.scenario),
        timeout_s=row.timeout_s,
    )
    result = SimulationResult.model_validate(row.result) if row.result is not None else None
    return TrialRecord(
        spec=spec, state=TrialState(row.state), result=result, worker=row.worker, attempts=row.attempts
    )
