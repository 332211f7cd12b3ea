"""Single simulations (``POST /api/v1/simulations``) in the SQL store.

For the driver loop that runs them: ``pending_simulations()`` lists what to enqueue,
``mark_simulation_queued(id)`` records the hand over (only from ``pending``),
``mark_simulation_running(id, worker)`` when a worker starts, and
``record_simulation_result(id, result, worker)`` stores the outcome once (``False`` if already
stored). A simulation left ``queued`` after a Redis flush goes back to ``pending`` with
``requeue_simulations(ids)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa

from api.errors import NotFoundError
from api.models import SimulationRow, utcnow
from api.store.base import ALL_OWNERS, Page, StoreBase, new_id, result_columns
from dem.result import SimulationResult
from optimizer.protocols import IN_FLIGHT, TrialSpec, TrialState

SIMULATION_ID_PREFIX = "sim-"


def is_simulation_id(job_id: str) -> bool:
    """Whether an executor's job is a single simulation rather than a trial (whose ids are
    ``<study id>-i...``, ``optimizer.protocols.trial_id``), from the id alone: no query."""
    return job_id.startswith(SIMULATION_ID_PREFIX)


class SimulationStore(StoreBase):
    def create_simulation(
        self,
        scenario: dict[str, Any],
        params: dict[str, float],
        seed: int,
        owner: str | None,
        timeout_s: float | None = None,
        engine: str = "numba",
    ) -> str:
        sim_id = new_id(SIMULATION_ID_PREFIX)
        with self.session() as s:
            s.add(
                SimulationRow(
                    id=sim_id, owner=owner, scenario=scenario, params=params, seed=seed,
                    timeout_s=timeout_s, state=TrialState.PENDING.value, attempts=0, engine=engine,
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
                    timeout_s=row.timeout_s, engine=row.engine,
                )
                for row in rows
            ]

    def in_flight_simulations(self) -> list[str]:
        """Ids of the simulations handed to an executor and not finished (for reconciliation)."""
        with self.session() as s:
            return list(
                s.scalars(
                    sa.select(SimulationRow.id).where(SimulationRow.state.in_([st.value for st in IN_FLIGHT]))
                )
            )

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
        values = result_columns(result) | {"state": TrialState.DONE.value, "finished_at": utcnow()}
        if worker is not None:
            values["worker"] = worker
        return bool(
            self._move_simulations(
                [sim_id], [TrialState.PENDING, TrialState.QUEUED, TrialState.RUNNING], **values
            )
        )

