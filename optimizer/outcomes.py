"""How runs ended, counted and labelled the same way by every view: the CLI, ``summary.json``,
``trials.csv``, ``pareto.png``, the API and the dashboard.

A run (one simulation) either measured N_t (status ``ok``) or it did not (every other status of
:class:`dem.result.SimulationStatus`: ``invalid``, ``unstable``, ``timeout``, ``error``,
``cancelled``). A run that did not measure has no N_t, whatever count its result carries from the
moment it stopped, and an individual with such a replicate has no objectives to show: the search
ranks it on a penalty or a constraint violation, which is not a measurement. Views draw these runs
apart and count them with :func:`count_failures`, so that they agree; the failed statuses are read
from the enum, so a new status is one more entry here without touching any view.

Pure functions on plain values; this module must not read stores or change results.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from dem.result import SimulationStatus
from optimizer.objectives import Evaluation

FAILED_STATUSES: tuple[str, ...] = tuple(
    status.value for status in SimulationStatus if status is not SimulationStatus.OK
)


def is_failed(status: str | None) -> bool:
    """A finished run that measured nothing (``None``: not finished, so not failed either)."""
    return status is not None and status != SimulationStatus.OK.value


def measured_n(status: str | None, n_remaining: int | None) -> int | None:
    """N_t as a view may show it: the count of an ``ok`` run, else ``None``."""
    return n_remaining if status == SimulationStatus.OK.value else None


def failure_status(evaluation: Evaluation) -> str | None:
    """The status that failed an individual (its first failed replicate's), ``None`` if it measured."""
    return evaluation.failure.split(":", 1)[0] if evaluation.failure else None


@dataclass(frozen=True)
class FailureCounts:
    """Failed runs by status, in the enum's order, zero counts left out."""

    by_status: dict[str, int] = field(default_factory=dict)

    @property
    def total(self) -> int:
        return sum(self.by_status.values())

    def text(self) -> str:
        """``failed: 3 (invalid 1, unstable 2)``; ``failed: 0`` when every run measured."""
        if not self.total:
            return "failed: 0"
        parts = ", ".join(f"{status} {n}" for status, n in self.by_status.items())
        return f"failed: {self.total} ({parts})"

    def as_json(self) -> dict:
        return {"total": self.total, "by_status": dict(self.by_status)}


def count_failures(statuses: Iterable[str | None]) -> FailureCounts:
    """Count the failed runs among these statuses (``ok`` and unfinished ``None`` are not counted)."""
    counts: dict[str, int] = {}
    for status in statuses:
        counts[status] = counts.get(status, 0) + 1
    return failures_from_counts(counts)


def failures_from_counts(counts: Mapping[str | None, int]) -> FailureCounts:
    """The failed runs of a {status: runs} tally (a database's GROUP BY). A status this version
    does not know (written by a newer worker) is counted after the known ones."""
    failed = {status: n for status, n in counts.items() if is_failed(status) and n}
    known = [status for status in FAILED_STATUSES if status in failed]
    unknown = sorted(status for status in failed if status not in FAILED_STATUSES)
    return FailureCounts({status: failed[status] for status in known + unknown})


def individual_failures(runs: Iterable[tuple[int, int, str | None]]) -> dict[int, str]:
    """The status that failed each failed individual, from its runs' (individual, replicate,
    status): the first failed replicate's, as :func:`failure_status` reads an evaluation."""
    failures: dict[int, str] = {}
    for individual, _, status in sorted(runs, key=lambda run: (run[0], run[1])):
        if is_failed(status):
            failures.setdefault(individual, status)
    return failures


def shown_objectives(evaluations: Sequence[Evaluation]) -> dict[str, tuple[float | None, float | None]]:
    """(f1, f2) per trial id as views show them: ``None`` for every trial of a failed individual."""
    return {
        tid: (evaluation.f1, evaluation.f2) if evaluation.ok else (None, None)
        for evaluation in evaluations
        for tid in evaluation.trial_ids
    }
