"""In-memory Store and a synthetic Executor, for unit tests of the optimiser only.

``MemoryStore`` keeps the same promises as the SQL store (``api/store/``): a result is recorded
once, a stored trial is never overwritten by ``add_trials``, records handed out are copies.
``SyntheticExecutor`` computes a result from a formula instead of a DEM simulation, so the GA,
the ranking and the driver can be tested in milliseconds; it must never be used for a real study,
and nothing outside ``tests/`` may import it for that.
"""

from __future__ import annotations

import copy
import math
import threading
import uuid
from collections import deque
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Any

import numpy as np

from dem.result import SimulationResult, SimulationStatus
from optimizer.protocols import (
    FINISHED_STUDIES,
    StudyRecord,
    StudyStatus,
    TrialOutcome,
    TrialRecord,
    TrialSpec,
    TrialState,
)
from optimizer.validation import settled


class UnknownStudyError(KeyError):
    """No study with this id."""


class MemoryStore:
    """A dict-backed Store; every method holds one lock, like a transaction."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._studies: dict[str, StudyRecord] = {}
        self._trials: dict[str, TrialRecord] = {}
        # A write counter stands in for the SQL store's ``updated_at``: trial id -> its last write.
        self._writes = 0
        self._written: dict[str, int] = {}
        self.generations: list[tuple[str, int, list[str]]] = []
        self.objectives: dict[str, tuple[float | None, ...]] = {}

    def create_study(self, definition: dict[str, Any], owner: str | None = None) -> str:
        study_id = uuid.uuid4().hex[:12]
        with self._lock:
            self._studies[study_id] = StudyRecord(
                study_id, copy.deepcopy(definition), StudyStatus.CREATED, extra={"owner": owner}
            )
        return study_id

    def load_study(self, study_id: str) -> StudyRecord:
        with self._lock:
            if study_id not in self._studies:
                raise UnknownStudyError(study_id)
            return copy.deepcopy(self._studies[study_id])

    def set_status(self, study_id: str, status: StudyStatus, message: str = "") -> None:
        with self._lock:
            study = self._studies[study_id]
            study.status, study.message = status, message
            if status in FINISHED_STUDIES:
                study.recommendation = settled(study.recommendation)

    def add_trials(self, specs: Sequence[TrialSpec]) -> None:
        with self._lock:
            for spec in specs:
                if spec.trial_id not in self._trials:
                    self._trials[spec.trial_id] = TrialRecord(spec, TrialState.PENDING)
                    self._touch(spec.trial_id)

    def _touch(self, trial: str) -> None:
        self._writes += 1
        self._written[trial] = self._writes

    def trials(self, study_id: str, states: Sequence[TrialState] | None = None) -> list[TrialRecord]:
        with self._lock:
            return [
                copy.deepcopy(record)
                for record in self._trials.values()
                if record.spec.study_id == study_id and (states is None or record.state in states)
            ]

    def changed_trials(self, study_id: str, since: int | None = None) -> tuple[list[TrialRecord], int | None]:
        with self._lock:
            changed = [
                copy.deepcopy(record)
                for tid, record in self._trials.items()
                if record.spec.study_id == study_id and (since is None or self._written[tid] > since)
            ]
            return changed, self._writes

    def mark_queued(self, trial_ids: Sequence[str], message: str = "") -> None:
        with self._lock:
            for tid in trial_ids:
                record = self._trials[tid]
                if record.state not in (TrialState.DONE, TrialState.CANCELLED):  # as the SQL store
                    record.state = TrialState.QUEUED
                    record.attempts += 1
                    self._touch(tid)

    def mark_running(self, trial_id: str, worker: str | None = None) -> None:
        with self._lock:
            record = self._trials[trial_id]
            if record.state is not TrialState.DONE:
                record.state = TrialState.RUNNING
                record.worker = worker
                self._touch(trial_id)

    def record_result(self, outcome: TrialOutcome) -> bool:
        with self._lock:
            record = self._trials.get(outcome.trial_id)
            if record is None or record.result is not None:
                return False
            record.result = outcome.result
            record.state = TrialState.DONE
            record.worker = outcome.worker
            record.attempts += outcome.retries
            self._touch(outcome.trial_id)
            return True

    def save_generation(
        self,
        study_id: str,
        generation: int,
        ga_state: bytes,
        pareto_trial_ids: Sequence[str],
        recommendation: dict[str, Any] | None,
        objectives: Mapping[str, Sequence[float | None]] | None = None,
    ) -> None:
        with self._lock:
            study = self._studies[study_id]
            study.generation = generation
            study.ga_state = ga_state
            study.recommendation = copy.deepcopy(recommendation)
            if study.status in FINISHED_STUDIES:
                study.recommendation = settled(study.recommendation)
            self.generations.append((study_id, generation, list(pareto_trial_ids)))
            self.objectives.update({tid: tuple(values) for tid, values in (objectives or {}).items()})


def synthetic_result(spec: TrialSpec, n_items: int = 30) -> SimulationResult:
    """A stand-in for the feeder: N_t falls with log E and rises with mu, plus seeded noise;
    cost grows as sqrt(E) like a DEM step count. A smooth, noisy, two-objective landscape."""
    params = spec.params
    drive = 2.5 * (math.log10(params["E"]) - 7.0) - 6.0 * (params["mu"] - 0.4) - 2.0 * (params["e"] - 0.5)
    expected = n_items / (1.0 + math.exp(drive))
    noise = np.random.default_rng(spec.seed).normal(0.0, 1.0)
    n_remaining = int(min(max(round(expected + noise), 0), n_items))
    steps = int(1000 * math.sqrt(params["E"] / 1e5))
    return SimulationResult(
        status=SimulationStatus.OK,
        n_items=n_items,
        n_remaining=n_remaining,
        wall_time_s=steps * 1e-4,
        steps=steps,
        cost=float(steps * (n_items + 10)),
        params=params,
        seed=spec.seed,
    )


def synthetic_with_failures(spec: TrialSpec, n_items: int = 30) -> SimulationResult:
    """:func:`synthetic_result`, except that soft sets (E < 1e6 Pa) blow up and every seventh
    individual from the fourth on times out. Both report the count where they stopped, which
    no view may show as N_t: tests of how failures are shown and counted use it."""
    result = synthetic_result(spec, n_items)
    if spec.params["E"] < 1e6:
        return result.model_copy(update={
            "status": SimulationStatus.UNSTABLE, "n_remaining": n_items,
            "message": "unstable at t=0.1 s: overlap beyond overlap_limit of a sphere radius",
        })
    if spec.individual % 7 == 3:
        return result.model_copy(update={
            "status": SimulationStatus.TIMEOUT, "n_remaining": n_items // 2,
            "message": "timeout after 120 s of wall time",
        })
    return result


class SyntheticExecutor:
    """Runs trials with a formula. ``per_poll`` limits how many finish per poll, to exercise
    partial batches; ``respond`` may return a failing result to exercise penalties."""

    def __init__(
        self,
        respond: Callable[[TrialSpec], SimulationResult] = synthetic_result,
        per_poll: int | None = None,
    ):
        self.respond = respond
        self.per_poll = per_poll
        self.queue: deque[TrialSpec] = deque()
        self.submitted: list[str] = []
        self.cancelled: list[str] = []

    def submit(self, specs: Sequence[TrialSpec]) -> None:
        queued = {spec.trial_id for spec in self.queue}
        for spec in specs:
            if spec.trial_id not in queued:
                self.queue.append(spec)
                self.submitted.append(spec.trial_id)
                queued.add(spec.trial_id)

    def poll(self, timeout: float = 0.0) -> list[TrialOutcome]:
        count = len(self.queue) if self.per_poll is None else min(self.per_poll, len(self.queue))
        return [
            TrialOutcome(spec.trial_id, self.respond(spec), worker="synthetic")
            for spec in (self.queue.popleft() for _ in range(count))
        ]

    def in_flight(self, expected: Collection[str] = ()) -> set[str]:
        return {spec.trial_id for spec in self.queue}

    def cancel(self, trial_ids: Sequence[str]) -> None:
        doomed = set(trial_ids)
        self.cancelled.extend(spec.trial_id for spec in self.queue if spec.trial_id in doomed)
        self.queue = deque(spec for spec in self.queue if spec.trial_id not in doomed)

    def close(self) -> None:
        self.queue.clear()
