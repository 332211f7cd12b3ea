"""Studies in the SQL store: create, read, status transitions, and the GA state per generation."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import undefer

from api.errors import NotFoundError
from api.models import StudyRow, TrialRow, UTCDateTime, encode_value, utcnow
from api.store.base import ALL_OWNERS, KEEP_VERSION, Page, StoreBase, chunks, new_id, owner_clause
from optimizer.protocols import FINISHED_STUDIES, StudyRecord, StudyStatus, TrialState
from optimizer.validation import settled

log = logging.getLogger(__name__)


class StudyStore(StoreBase):
    def create_study(
        self,
        definition_json: dict[str, Any],
        owner: str | None,
        name: str | None = None,
        warnings: Sequence[str] | None = None,
    ) -> str:
        """Store a validated study definition as a new study in status ``created``; its id.
        ``warnings`` (``StudyDefinition.warnings``, computed once here rather than on every read)
        are kept in ``extra["warnings"]``."""
        study_id = new_id("st-")
        with self.session() as s:
            s.add(
                StudyRow(
                    id=study_id,
                    name=name or str(definition_json.get("name") or study_id),
                    owner=owner,
                    status=StudyStatus.CREATED.value,
                    definition=definition_json,
                    extra={} if warnings is None else {"warnings": list(warnings)},
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
        """(id, owner, status, generation, change_number, trial_changes) of a visible study, without
        loading its JSON columns: the check that a hot read may go ahead, and the versions of
        cached views: ``change_number`` of the views made from the study row, ``trial_changes``
        (the study's change counter) of those that every trial write changes (counts), and the
        cursor of a trial poll (``changed_since``)."""
        with self.session() as s:
            row = s.execute(
                sa.select(
                    StudyRow.id, StudyRow.owner, StudyRow.status, StudyRow.generation, StudyRow.change_number,
                    StudyRow.trial_changes,
                )
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

    def keep_warnings(self, study_id: str, warnings: Sequence[str]) -> None:
        """Store the warnings of a study made before they were stored at creation; no change of
        the study for cached views (its ``updated_at`` stays)."""
        with self.session() as s:
            extra = s.scalar(sa.select(StudyRow.extra).where(StudyRow.id == study_id)) or {}
            s.execute(
                sa.update(StudyRow)
                .where(StudyRow.id == study_id)
                .values(KEEP_VERSION | {"extra": {**extra, "warnings": list(warnings)}})
                .execution_options(synchronize_session=False)
            )

    def list_studies(
        self,
        visible_to: str | None = ALL_OWNERS,
        status: StudyStatus | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> Page:
        where = [owner_clause(StudyRow.owner, visible_to)]
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
            _settle(row)

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
            if done and to in FINISHED_STUDIES:
                row = self._study_row(s, study_id)
                row.recommendation = settled(row.recommendation)
            if done and to is StudyStatus.CANCELLED:
                number = self._change_numbers(s, [study_id])[study_id]  # the study's row is locked already
                s.execute(
                    sa.update(TrialRow)
                    .where(
                        TrialRow.study_id == study_id,
                        TrialRow.state.in_(
                            [TrialState.PENDING.value, TrialState.QUEUED.value, TrialState.RUNNING.value]
                        ),
                    )
                    .values(state=TrialState.CANCELLED.value, updated_at=utcnow(), change_number=number)
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
        """Persist the GA after a generation, atomically with its Pareto ranking and the (f1, f2)
        the driver hands over (trial id -> values, which may be infinite or None), as the Store
        protocol says; trials not named keep theirs."""
        with self.session() as s:
            row = self._study_row(s, study_id)
            number = self._change_numbers(s, [study_id])[study_id]
            row.generation = generation
            row.ga_state = ga_state
            row.recommendation = recommendation
            _settle(row)  # a driver finishing its batch after a cancel
            now = utcnow()
            s.execute(
                sa.update(TrialRow)
                .where(TrialRow.study_id == study_id, TrialRow.pareto.is_(True))
                .values(pareto=False, updated_at=now, change_number=number)
            )
            for chunk in chunks(list(pareto_trial_ids), 500):
                s.execute(
                    sa.update(TrialRow)
                    .where(TrialRow.study_id == study_id, TrialRow.id.in_(chunk))
                    .values(pareto=True, updated_at=now, change_number=number)
                )
            if objectives:
                updates = []
                for tid, values in objectives.items():
                    f1_value, f1_kind = encode_value(values[0])
                    f2_value, f2_kind = encode_value(values[1] if len(values) > 1 else None)
                    updates.append(
                        {"id": tid, "f1_value": f1_value, "f1_kind": f1_kind,
                         "f2_value": f2_value, "f2_kind": f2_kind, "updated_at": now, "change_number": number}
                    )
                s.execute(sa.update(TrialRow), updates)


def _settle(row: StudyRow) -> None:
    """A study that has ended keeps no ``pending`` validation (``optimizer.validation.settled``)."""
    if row.status in {status.value for status in FINISHED_STUDIES}:
        row.recommendation = settled(row.recommendation)


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

