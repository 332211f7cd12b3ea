"""Progress that means something: the hypervolume of what a study has measured and its best f1,
against the number of simulations, one point per batch.

Hypervolume: pymoo's HV indicator over the measured individuals' (f1, f2), both minimised, divided
by the area of the reference box, so that it reads as the fraction of the box [0, r1] x [0, r2]
the measured sets dominate (0: nothing better than the reference corner; 1 would be a perfect
match at no cost). The reference point is fixed per study:

- r1 = the number of items: f1 (|N_t - target|, or W1 between N_t distributions) never exceeds it;
- r2 = 1.1 x the largest f2 measured in the initial population (batch 0): the worst cost the
  search saw before it chose anything, with room so that the slowest set still counts.

Once batch 0 is complete the reference never moves, so values of one study compare across its
batches; across studies they do not (their costs differ). A set beyond the reference adds nothing,
and so does a failed individual: it measured nothing (``optimizer/outcomes.py``).

The best validated f1 is the lowest fresh-seed f1 among the sets the validation that ends a study
called ``validated`` (``optimizer/validation.py``, stored with the recommendation); the validation
is the last batch, so it is given at the last point and is null before.

Each point is what was known when a batch was complete: the records of that batch and the earlier
ones, evaluated together (a later re-evaluation does not rewrite history). A batch still running
has no point yet, so a point never changes once given.

Pure arithmetic on records; it must not read stores or run anything.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np
from pymoo.indicators.hv import HV

from optimizer.objectives import Evaluation, evaluate
from optimizer.protocols import TrialRecord
from optimizer.study import StudyDefinition

REFERENCE_MARGIN = 1.1
VALIDATED = "validated"  # the verdict of optimizer/validation.py


@dataclass(frozen=True)
class ProgressPoint:
    batch: int
    simulations: int  # finished simulations of this batch and the earlier ones
    failed: int  # of them, runs that measured nothing
    hypervolume: float | None  # None before batch 0 has a measured individual
    best_f1: float | None
    best_validated_f1: float | None


@dataclass(frozen=True)
class StudyProgress:
    reference: tuple[float, float] | None  # (r1 in items, r2 in f2's unit); None before batch 0
    points: list[ProgressPoint]

    def as_json(self) -> dict:
        return {
            "reference": None
            if self.reference is None
            else {"f1": self.reference[0], "f2": self.reference[1]},
            "points": [asdict(point) for point in self.points],
        }


def reference_point(initial: Sequence[Evaluation], n_items: int) -> tuple[float, float] | None:
    """(n_items, 1.1 x the largest measured f2 of the initial population); None if none measured."""
    measured = [evaluation.f2 for evaluation in initial if evaluation.ok]
    if not measured or n_items <= 0:
        return None
    return float(n_items), REFERENCE_MARGIN * max(measured)


def hypervolume(evaluations: Sequence[Evaluation], reference: tuple[float, float]) -> float:
    """The dominated fraction of the reference box by the measured individuals."""
    points = np.array([[ev.f1, ev.f2] for ev in evaluations if ev.ok], dtype=float).reshape(-1, 2)
    if not len(points) or reference[1] <= 0:
        return 0.0
    scaled = points / np.asarray(reference)
    inside = scaled[np.all(scaled < 1.0, axis=1)]
    if not len(inside):
        return 0.0
    return float(HV(ref_point=np.ones(2))(inside))


class ProgressTracker:
    """The progress of a study folded in one completed batch at a time, kept between calls.

    An individual's evaluation depends only on its own records (the penalty f2 of a failed one
    depends on the others, but failed individuals count in no point), so a batch re-evaluates only
    the individuals it gave results to: N batches cost O(N) evaluations. Evaluating every earlier
    batch again for each point was quadratic (129 s for 100 batches of 100), and a server keeping
    a tracker per study folds only the batches completed since its last read.
    """

    def __init__(self, definition: StudyDefinition) -> None:
        self.definition = definition
        self.n_items = definition.n_items()
        self.next_batch = 0  # batches before it are folded
        self.reference: tuple[float, float] | None = None
        self.points: list[ProgressPoint] = []  # best_validated_f1 is None: given at the last point only
        self._first_batch: int | None = None
        self._records: dict[int, list[TrialRecord]] = {}  # finished records by individual
        self._current: dict[int, Evaluation] = {}  # each individual's evaluation on its records so far
        self._simulations = 0
        self._failed = 0

    def advance(self, records: Iterable[TrialRecord], completed_batches: int) -> None:
        """Fold the batches from ``next_batch`` up to ``completed_batches`` (exclusive), given
        their records (others are ignored; unfinished ones count for nothing)."""
        by_batch: dict[int, list[TrialRecord]] = {}
        for record in records:
            if record.result is not None and self.next_batch <= record.spec.generation < completed_batches:
                by_batch.setdefault(record.spec.generation, []).append(record)
        for batch in sorted(by_batch):
            self._fold(batch, by_batch[batch])
        self.next_batch = max(self.next_batch, completed_batches)

    def _fold(self, batch: int, records: list[TrialRecord]) -> None:
        changed = {record.spec.individual for record in records}
        for record in records:
            self._records.setdefault(record.spec.individual, []).append(record)
        for individual in changed:
            self._current.pop(individual, None)
        group = [record for individual in sorted(changed) for record in self._records[individual]]
        evaluated = evaluate(group, self.definition, self.n_items, intervals=False)  # no interval is drawn
        self._current.update((ev.individual, ev) for ev in evaluated)
        self._simulations += len(records)
        self._failed += sum(not record.result.ok for record in records)
        if self._first_batch is None:
            self._first_batch = batch
        evaluations = [self._current[individual] for individual in sorted(self._current)]
        if self.reference is None:
            self.reference = reference_point(
                [ev for ev in evaluations if ev.generation == self._first_batch], self.n_items
            )
        self.points.append(
            ProgressPoint(
                batch=batch,
                simulations=self._simulations,
                failed=self._failed,
                hypervolume=None if self.reference is None else hypervolume(evaluations, self.reference),
                best_f1=min((ev.f1 for ev in evaluations if ev.ok), default=None),
                best_validated_f1=None,
            )
        )

    def progress(self, validation: Sequence[dict] = ()) -> StudyProgress:
        """The points so far; ``validation`` (the stored validation table: rows with ``f1`` and
        ``verdict``, empty before it ran) gives the last point its best validated f1."""
        points = list(self.points)
        confirmed = [row["f1"] for row in validation if row.get("verdict") == VALIDATED]
        confirmed = [f1 for f1 in confirmed if f1 is not None]
        if points and confirmed:
            points[-1] = replace(points[-1], best_validated_f1=min(confirmed))
        return StudyProgress(self.reference, points)


def study_progress(
    records: Sequence[TrialRecord],
    definition: StudyDefinition,
    completed_batches: int,
    validation: Sequence[dict] = (),
) -> StudyProgress:
    """One point per completed batch (``StudyRecord.generation`` counts them). ``validation`` is
    the stored validation table (rows with ``f1`` and ``verdict``), empty before it ran."""
    tracker = ProgressTracker(definition)
    tracker.advance(records, completed_batches)
    return tracker.progress(validation)
