"""The reads the API and dashboard make: trial pages, Pareto members, summaries, counters.

Plain rows of the columns a view needs (no ORM objects, no JSON blobs but ``params``) where a
read is hot; one query per page of studies for their counts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import sqlalchemy as sa

from api.models import SimulationRow, StudyRow, TrialRow, ValueKind
from api.store.base import Page, StoreBase
from optimizer.protocols import TrialState


@dataclass(frozen=True)
class TrialFilter:
    generation: int | None = None
    state: TrialState | None = None
    pareto: bool | None = None
    changed_since: int | None = None  # a change number of the study (``StoreBase._change_numbers``)


TRIAL_READ_COLUMNS = (
    TrialRow.id, TrialRow.generation, TrialRow.individual, TrialRow.replicate, TrialRow.seed,
    TrialRow.params, TrialRow.state, TrialRow.status, TrialRow.n_remaining, TrialRow.responses,
    TrialRow.engine, TrialRow.wall_time_s, TrialRow.cost, TrialRow.full_load_factor, TrialRow.pareto,
    TrialRow.worker, TrialRow.attempts, TrialRow.message, TrialRow.updated_at, TrialRow.f1_value,
    TrialRow.f1_kind, TrialRow.f2_value, TrialRow.f2_kind,
)



class DashboardReads(StoreBase):
    @staticmethod
    def _trial_clauses(study_id: str, where: TrialFilter) -> list:
        clauses = [TrialRow.study_id == study_id]
        if where.generation is not None:
            clauses.append(TrialRow.generation == where.generation)
        if where.state is not None:
            clauses.append(TrialRow.state == where.state.value)
        if where.pareto is not None:
            clauses.append(TrialRow.pareto.is_(where.pareto))
        if where.changed_since is not None:
            clauses.append(TrialRow.change_number > where.changed_since)
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
        ``total``, when the caller knows it, saves the count query; so does a page that is the
        last one (fewer rows than ``limit``, and some or it is the first): it tells the total."""
        clauses = self._trial_clauses(study_id, where)
        with self.session() as s:
            rows = s.execute(
                sa.select(*TRIAL_READ_COLUMNS).where(*clauses)
                .order_by(TrialRow.generation, TrialRow.individual, TrialRow.replicate)
                .limit(limit).offset(offset)
            ).all()
            if total is None and len(rows) < limit and (rows or offset == 0):
                total = offset + len(rows)
            if total is None:
                total = s.scalar(sa.select(sa.func.count()).select_from(TrialRow).where(*clauses))
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

    def trial_columns(self, study_id: str, f1_at_most: float | None = None) -> list[sa.Row]:
        """Every trial's plot and summary columns, without the JSON blobs (for summaries); with
        ``f1_at_most``, only the ok trials whose finite f1 is at most that (the matching ones:
        most of a long study's trials are not, and reading them all was most of a
        recommendation's cost), read off the index on (study, f1) (migration 0008)."""
        query = (
            sa.select(
                TrialRow.id, TrialRow.generation, TrialRow.individual, TrialRow.replicate,
                TrialRow.state, TrialRow.status, TrialRow.n_remaining, TrialRow.responses,
                TrialRow.wall_time_s, TrialRow.cost, TrialRow.full_load_factor, TrialRow.pareto,
                TrialRow.f1_value, TrialRow.f1_kind, TrialRow.f2_value, TrialRow.f2_kind, TrialRow.params,
            )
            .where(TrialRow.study_id == study_id)
            .order_by(TrialRow.generation, TrialRow.individual, TrialRow.replicate)
        )
        if f1_at_most is not None:
            query = query.where(
                TrialRow.status == "ok", TrialRow.f1_kind == ValueKind.FINITE.value,
                TrialRow.f1_value <= f1_at_most,
            )
        with self.session() as s:
            return list(s.execute(query))

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

    def run_status_counts_many(self, study_ids: Sequence[str]) -> dict[str, dict[str, int]]:
        """Finished trials by simulation status per study, for a page of studies in one query."""
        if not study_ids:
            return {}
        counts: dict[str, dict[str, int]] = {}
        with self.session() as s:
            for study_id, status, n in s.execute(
                sa.select(TrialRow.study_id, TrialRow.status, sa.func.count())
                .where(TrialRow.study_id.in_(list(study_ids)), TrialRow.status.is_not(None))
                .group_by(TrialRow.study_id, TrialRow.status)
            ):
                counts.setdefault(study_id, {})[status] = int(n)
        return counts

    def trial_state_counts(self, study_id: str | None = None) -> dict[str, int]:
        query = sa.select(TrialRow.state, sa.func.count()).group_by(TrialRow.state)
        if study_id is not None:
            query = query.where(TrialRow.study_id == study_id)
        with self.session() as s:
            return {state: int(n) for state, n in s.execute(query)}

    def trial_counts(self, study_id: str) -> tuple[dict[str, int], dict[str, int]]:
        """A study's trials by state, and its finished trials by how their simulation ended (ok,
        unstable, ...), from one grouped query."""
        by_state: dict[str, int] = {}
        by_status: dict[str, int] = {}
        with self.session() as s:
            for state, status, n in s.execute(
                sa.select(TrialRow.state, TrialRow.status, sa.func.count())
                .where(TrialRow.study_id == study_id)
                .group_by(TrialRow.state, TrialRow.status)
            ):
                by_state[state] = by_state.get(state, 0) + int(n)
                if status is not None:
                    by_status[status] = by_status.get(status, 0) + int(n)
        return by_state, by_status

    def trial_states(self, study_id: str, since: int | None = None) -> list[sa.Row]:
        """(id, state, status, change_number) of a study's trials written after the change number
        ``since`` (all of them without): what a tally of its states kept between reads needs."""
        query = sa.select(TrialRow.id, TrialRow.state, TrialRow.status, TrialRow.change_number).where(
            TrialRow.study_id == study_id
        )
        if since is not None:
            query = query.where(TrialRow.change_number > since)
        with self.session() as s:
            return list(s.execute(query))

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

