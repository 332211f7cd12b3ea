"""Adaptive replicates: which sets earn more seeds, inside the study's budget.

With the feeder's noise, f1 of a few replicates is an estimate; the search should not recommend
a set because of one lucky seed. So after every batch the sets that could be recommended earn
replicates up to ``max_replicates`` (all at once, so a set is either fully replicated or not),
and only a fully replicated set can be recommended (``optimizer/pareto.py``):

- who: measured sets (never invalid or failed ones) that match (f1 <= tolerance) or whose f1
  interval reaches the tolerance (the match is within their noise): the feasible front and its
  neighbourhood. Matching sets first, fastest first (the recommendation is the fastest match);
  then the near ones, closest first.
- how many: the pool (``StudyDefinition.replicate_pool()``) is spread over the batches still to
  come, so the first generations cannot spend what the last ones need; the last extra-replicate
  batch may spend all that is left.

Pure: it decides from evaluations and counts; the driver turns the decisions into trials.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from optimizer.objectives import Evaluation
from optimizer.study import StudyDefinition


def promising(evaluations: Sequence[Evaluation], tolerance: float) -> list[Evaluation]:
    """Measured sets on or near the feasible front, in the order they earn replicates."""
    slack = tolerance + 1e-9
    matching = sorted(
        (ev for ev in evaluations if ev.ok and ev.f1 <= slack), key=lambda ev: (ev.f2, ev.individual)
    )
    near = sorted(
        (ev for ev in evaluations if ev.ok and ev.f1 > slack and ev.f1_interval[0] <= slack),
        key=lambda ev: (ev.f1_interval[0], ev.f2, ev.individual),
    )
    return matching + near


def allocate(
    evaluations: Sequence[Evaluation], definition: StudyDefinition, spent: int, batch: int
) -> dict[int, list[int]]:
    """Individual -> the new replicate numbers it earns in ``batch``; ``spent`` extra replicates
    were already created by earlier batches."""
    cap = definition.max_replicates
    left = definition.replicate_pool() - spent
    batches_left = definition.replicate_batch() - batch + 1
    if left <= 0 or batches_left <= 0 or cap <= definition.replicates:
        return {}
    share = left if batches_left == 1 else math.ceil(left / batches_left)
    earned: dict[int, list[int]] = {}
    for evaluation in promising(evaluations, definition.match_tolerance()):
        have = evaluation.n_replicates
        need = cap - have
        if need <= 0:
            continue
        if need > share:
            break
        earned[evaluation.individual] = list(range(have, cap))
        share -= need
    return earned
