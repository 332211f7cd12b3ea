"""A study as one JSON document, and back into any database.

Why: a full-size study runs for hours. This lets it move between machines and databases (a
laptop's SQLite to a cluster's PostgreSQL, or a long study carried across working sessions) and
continue with ``demcal calibrate --resume``, nothing that finished being run again.

The archive holds every column of the study's row and of its trials, so nothing is lost: the
definition, the GA state of the last generation, the ranking and every result. What belongs to
the old database's processes is not carried: the driver's lease, and the hand-over of unfinished
trials to executors (queued or running trials come back ``pending``, so the next driver sends them
again). A study that was running comes back ``paused``: no process drives it until someone
resumes it.

Format 2 keeps each distinct trial scenario once, in ``scenarios``; a trial's ``scenario`` is its
index there (every trial of a study usually shares one scenario, which was a quarter of a format
1 archive, where each trial carried its own copy). Format 1 archives still restore.
"""

from __future__ import annotations

import base64
import json
from datetime import datetime
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import undefer

from api.errors import ConflictError, InvalidInputError
from api.models import StudyRow, TrialRow
from api.store.base import chunks
from api.store.studies import StudyStore
from dem.result import SimulationResult
from optimizer.protocols import StudyStatus, TrialState
from optimizer.seeds import STUDY_WIDE_SEEDS

ARCHIVE_FORMAT = "demcal-study-archive/2"
READABLE_FORMATS = ("demcal-study-archive/1", ARCHIVE_FORMAT)  # 1: a scenario in every trial
NOT_CARRIED = frozenset({"driver", "driver_until"})  # the old database's lease
UNFINISHED = (TrialState.QUEUED.value, TrialState.RUNNING.value)


def _encode(value: Any) -> Any:
    if isinstance(value, datetime):
        return {"datetime": value.isoformat()}
    if isinstance(value, bytes | memoryview):
        return {"base64": base64.b64encode(bytes(value)).decode("ascii")}
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, dict) and len(value) == 1:
        if "datetime" in value:
            return datetime.fromisoformat(value["datetime"])
        if "base64" in value:
            return base64.b64decode(value["base64"])
    return value


def _row_dict(row, table: sa.Table) -> dict[str, Any]:
    return {c.key: _encode(getattr(row, c.key)) for c in table.columns if c.key not in NOT_CARRIED}


def _columns_of(record: dict[str, Any], table: sa.Table, what: str) -> dict[str, Any]:
    """The record's values for the table's columns; an unknown column means another version."""
    known = {c.key for c in table.columns}
    unknown = sorted(set(record) - known)
    if unknown:
        raise InvalidInputError(
            f"the archive's {what} has columns this demcal does not know ({', '.join(unknown)}): "
            "restore it with the demcal version that wrote it, or a newer one"
        )
    return {key: _decode(value) for key, value in record.items() if key not in NOT_CARRIED}


def _shared_scenario(scenarios: Any, number: Any, trial: Any) -> Any:
    """A format 2 trial's scenario: the one its index names in the archive's ``scenarios``."""
    if not isinstance(scenarios, list) or type(number) is not int or not 0 <= number < len(scenarios):
        raise InvalidInputError(
            f"trial {trial!r} names scenario {number!r}, which the archive's scenarios list does not "
            "hold: the archive is damaged; make it again with `demcal studies archive STUDY_ID`"
        )
    return scenarios[number]


class StudyArchives(StudyStore):
    def archive_study(self, study_id: str) -> dict[str, Any]:
        """The study and all its trials as a JSON-able document (``ARCHIVE_FORMAT``)."""
        with self.session() as s:
            row = self._study_row(s, study_id)
            trials = s.scalars(
                sa.select(TrialRow)
                .where(TrialRow.study_id == study_id)
                .options(undefer(TrialRow.scenario), undefer(TrialRow.result))
                .order_by(TrialRow.generation, TrialRow.individual, TrialRow.replicate, TrialRow.id)
            ).all()
            records = [_row_dict(t, TrialRow.__table__) for t in trials]
            scenarios: list[Any] = []
            index: dict[str, int] = {}
            for record in records:
                key = json.dumps(record["scenario"], sort_keys=True)
                if key not in index:
                    index[key] = len(scenarios)
                    scenarios.append(record["scenario"])
                record["scenario"] = index[key]
            return {
                "format": ARCHIVE_FORMAT,
                "study": _row_dict(row, StudyRow.__table__),
                "scenarios": scenarios,
                "trials": records,
            }

    def restore_study(self, archive: dict[str, Any]) -> str:
        """Insert an archived study under its own id; its id. A study that was running comes back
        paused, and its queued or running trials pending (see the module docstring)."""
        if not isinstance(archive, dict) or archive.get("format") not in READABLE_FORMATS:
            found = archive.get("format") if isinstance(archive, dict) else type(archive).__name__
            raise InvalidInputError(
                f"not a study archive (format {found!r}; expected {ARCHIVE_FORMAT!r}): "
                "make one with `demcal studies archive STUDY_ID`"
            )
        shared = archive.get("scenarios") if archive["format"] == ARCHIVE_FORMAT else None
        study = _columns_of(archive.get("study") or {}, StudyRow.__table__, "study")
        study_id = study.get("id")
        if not study_id:
            raise InvalidInputError("the archive's study has no id")
        definition = study.get("definition")
        if isinstance(definition, dict) and "common_seeds" not in definition:
            # An archive older than the setting (migration 0011): the seeds it ran on.
            study["definition"] = {**definition, "common_seeds": STUDY_WIDE_SEEDS}
        if study.get("status") == StudyStatus.RUNNING.value:
            study["status"] = StudyStatus.PAUSED.value
            study["message"] = "restored from an archive; continue it with demcal calibrate --resume"
        trials = []
        for record in archive.get("trials") or []:
            trial = _columns_of(record, TrialRow.__table__, "trial")
            if shared is not None:
                trial["scenario"] = _shared_scenario(shared, trial.get("scenario"), trial.get("id"))
            if trial.get("study_id") != study_id:
                raise InvalidInputError(f"trial {trial.get('id')!r} belongs to another study")
            if "full_load_factor" not in trial and isinstance(trial.get("result"), dict):
                # An archive older than the column (migration 0010): the factor its result holds.
                trial["full_load_factor"] = SimulationResult.model_validate(trial["result"]).full_load_factor
            if trial.get("state") in UNFINISHED:
                trial.update(state=TrialState.PENDING.value, worker=None, started_at=None)
            trials.append(trial)
        with self.session() as s:
            if s.get(StudyRow, study_id) is not None:
                raise ConflictError(
                    f"study {study_id} is already in this database; delete it first, or restore "
                    "into another database"
                )
            s.execute(sa.insert(StudyRow), [study])
            for chunk in chunks(trials, 500):
                s.execute(sa.insert(TrialRow), chunk)
        return study_id
