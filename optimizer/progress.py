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

from collections.abc import Sequence
from dataclasses import asdict, dataclass

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


def study_progress(
    records: Sequence[TrialRecord],
    definition: StudyDefinition,
    completed_batches: int,
    validation: Sequence[dict] = (),
) -> StudyProgress:
    """One point per completed batch (``StudyRecord.generation`` counts them). ``validation`` is
    the stored validation table (rows with ``f1`` and ``verdict``), empty before it ran."""
    finished = [record for record in records if record.result is not None]
    batches = sorted(
        {record.spec.generation for record in finished if record.spec.generation < completed_batches}
    )
    n_items = definition.n_items()
    reference = None
    points = []
    for batch in batches:
        known = [record for record in finished if record.spec.generation <= batch]
        evaluations = evaluate(known, definition, n_items)
        if reference is None:
            reference = reference_point([ev for ev in evaluations if ev.generation == batches[0]], n_items)
        measured = [ev.f1 for ev in evaluations if ev.ok]
        last = batch == batches[-1]
        confirmed = [row["f1"] for row in validation if last and row.get("verdict") == VALIDATED]
        points.append(
            ProgressPoint(
                batch=batch,
                simulations=len(known),
                failed=sum(not record.result.ok for record in known),
                hypervolume=None if reference is None else hypervolume(evaluations, reference),
                best_f1=min(measured, default=None),
                best_validated_f1=min((f1 for f1 in confirmed if f1 is not None), default=None),
            )
        )
    return StudyProgress(reference, points)
