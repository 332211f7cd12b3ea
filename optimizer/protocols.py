"""The seams of a calibration study: what the driver hands to an Executor and a Store.

The driver depends only on these protocols. Implementations live elsewhere: in-memory ones in
``optimizer/memory.py`` (tests), the SQL store in ``api/``, the local pool and the RQ executor in
``worker/``. A *trial* is one simulation: one parameter set (an *individual*), one replicate, one
seed. Its id is deterministic, so a re-sent result or a re-enqueued job maps to the same row.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Protocol

from dem.parameters import PARAMETER_NAMES  # noqa: F401 - re-exported: the names a trial carries
from dem.result import SimulationResult


class TrialState(StrEnum):
    PENDING = "pending"  # stored, not yet handed to an executor (or lost and to be re-sent)
    QUEUED = "queued"  # handed to an executor
    RUNNING = "running"  # a worker said it started
    DONE = "done"  # a result is recorded (whatever its SimulationStatus)
    CANCELLED = "cancelled"


class StudyStatus(StrEnum):
    CREATED = "created"
    RUNNING = "running"
    PAUSED = "paused"
    DONE = "done"
    CANCELLED = "cancelled"
    FAILED = "failed"


ACTIVE_STUDIES = (StudyStatus.CREATED, StudyStatus.RUNNING)  # a driver advances these
STOPPING_STUDIES = (StudyStatus.PAUSED, StudyStatus.CANCELLED)  # their in-flight work is withdrawn
FINISHED_STUDIES = (StudyStatus.DONE, StudyStatus.CANCELLED, StudyStatus.FAILED)  # ended; no pending check
IN_FLIGHT = (TrialState.QUEUED, TrialState.RUNNING)


def trial_id(study_id: str, individual: int, replicate: int) -> str:
    """The one place trial ids are made: stable across restarts and re-enqueues."""
    return f"{study_id}-i{individual:05d}-r{replicate:02d}"


def study_of(trial: str) -> str:
    """The study a trial id belongs to (``trial_id``'s inverse), without asking the store."""
    return trial.rpartition("-i")[0]


def is_trial_of(trial: str, study_id: str) -> bool:
    """Whether a trial id belongs to a study, without asking the store (it may be deleted)."""
    return bool(study_id) and trial.startswith(f"{study_id}-i")


@dataclass(frozen=True)
class TrialSpec:
    """Everything a worker needs to run one simulation; JSON-able, no database needed."""

    trial_id: str
    study_id: str
    individual: int
    generation: int
    replicate: int
    seed: int
    params: dict[str, float]
    scenario: dict[str, Any]
    timeout_s: float | None = None
    keep_snapshots: bool = False  # the worker keeps the run's snapshots for a replay
    engine: str = "numba"  # which engine runs it (dem/engines); a worker must have it
    engine_options: dict[str, Any] | None = None


@dataclass(frozen=True)
class TrialOutcome:
    """A finished trial as an executor reports it."""

    trial_id: str
    result: SimulationResult
    worker: str | None = None
    # Runs of this submission that failed before the one reported (the executor's own retries
    # of infrastructure failures: a worker killed or lost); the store adds them to ``attempts``.
    retries: int = 0


@dataclass
class TrialRecord:
    """A trial as the store keeps it."""

    spec: TrialSpec
    state: TrialState
    result: SimulationResult | None = None
    worker: str | None = None
    attempts: int = 0


@dataclass
class StudyRecord:
    """A study as the store keeps it. ``definition`` is the StudyDefinition as JSON."""

    study_id: str
    definition: dict[str, Any]
    status: StudyStatus
    generation: int = 0
    ga_state: bytes | None = None
    recommendation: dict[str, Any] | None = None
    message: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


class Executor(Protocol):
    """Runs trials somewhere (a local process pool, an RQ queue)."""

    def submit(self, specs: Sequence[TrialSpec]) -> None:
        """Start running these trials; submitting a trial already in flight is a no-op."""

    def poll(self, timeout: float = 0.0) -> list[TrialOutcome]:
        """Finished trials since the last call, each returned exactly once; waits up to timeout."""

    def in_flight(self, expected: Collection[str] = ()) -> set[str]:
        """Trial ids this executor still knows to be queued or running (for reconciliation).
        ``expected``: those the caller holds as queued or running; each of them still in flight
        is in the answer even if the executor cannot list it at that instant (RQ: a job a worker
        is taking, between its queue and the started registry)."""

    def cancel(self, trial_ids: Sequence[str]) -> None:
        """Stop these trials if possible; their outcomes are then never reported."""

    def close(self) -> None:
        """Release processes and connections."""

    # Optional: ``waiting() -> dict[engine, message]`` for engines no worker takes (RqExecutor).


class Store(Protocol):
    """Where a study's truth lives. Every method is one transaction."""

    def load_study(self, study_id: str) -> StudyRecord: ...

    def set_status(self, study_id: str, status: StudyStatus, message: str = "") -> None:
        """A study set to one of ``FINISHED_STUDIES`` keeps no ``pending`` validation: its
        recommendation is stored ``optimizer.validation.settled`` (the check will not come)."""

    def add_trials(self, specs: Sequence[TrialSpec]) -> None:
        """Store new trials as pending; a trial id already stored is left as it is."""

    def trials(self, study_id: str, states: Sequence[TrialState] | None = None) -> list[TrialRecord]: ...

    def changed_trials(self, study_id: str, since: Any = None) -> tuple[list[TrialRecord], Any]:
        """The study's trials written since the cursor ``since`` (all of them when None), and the
        cursor for the next call. A trial may come back again; the caller upserts by id."""

    def mark_queued(self, trial_ids: Sequence[str], message: str = "") -> None:
        """Trials handed to the executor, pending or sent again after it lost them (queued or
        running before): now queued, one more attempt; ``message`` says why they may wait (e.g.
        no worker has their engine). Done and cancelled trials stay as they are."""

    def mark_running(self, trial_id: str, worker: str | None = None) -> None: ...

    def record_result(self, outcome: TrialOutcome) -> bool:
        """Record a result once; returns False (and changes nothing) if one is already recorded."""

    def save_generation(
        self,
        study_id: str,
        generation: int,
        ga_state: bytes,
        pareto_trial_ids: Sequence[str],
        recommendation: dict[str, Any] | None,
        objectives: Mapping[str, Sequence[float | None]] | None = None,
    ) -> None:
        """Persist the GA after a generation, atomically with its Pareto ranking and the shown
        (f1, f2) of the trials whose objectives the generation changed (trial id -> values;
        ``optimizer/outcomes.shown_objectives``). The store computes nothing itself, except that a
        finished study's recommendation is stored ``settled``, as in ``set_status``."""
