"""Ranking a study's individuals: Pareto fronts, the recommendation and the equivalent sets.

- Fronts: pymoo's non-dominated sorting of (f1, f2), both minimised, over measured sets only
  (a failed or invalid set has no f1, only a penalty).
- Recommendation: the fastest (lowest f2) individual whose f1 is within the experiment's
  tolerance and that has its full replicates (``max_replicates``). Such an individual is always
  on the first front unless another one is exactly as fast and matches better, in which case
  that one is chosen: ties go to the lower f1, then the earlier individual. After the validation
  the driver replaces it with the fastest validated set (``optimizer/validation.py``).
- Equivalent sets: the other matching individuals, slower ones included, kept only when they are
  distinct in parameter space (normalised gene distance at least ``min_distance`` from every set
  already listed). The paper expects the calibration to be multimodal; an engineer picking a
  parameter set should see that other, different sets reproduce the experiment as well.

This module ranks what it is given; it must not read stores or decide when a study ends.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

from optimizer.objectives import Evaluation
from optimizer.space import ParameterSpace

DEFAULT_MIN_DISTANCE = 0.1


def fronts(evaluations: Sequence[Evaluation]) -> list[list[Evaluation]]:
    """Non-dominated fronts of the measured sets, best first; each sorted by f2 (fastest first).

    A failed or invalid set has no measured f1 (its objectives are a penalty), so it is on no
    front: it is a constraint violation for the search and a failure for the views.
    """
    evaluations = [evaluation for evaluation in evaluations if evaluation.ok]
    if not evaluations:
        return []
    objectives = np.array([[evaluation.f1, evaluation.f2] for evaluation in evaluations], dtype=float)
    ranked = NonDominatedSorting().do(objectives)
    return [sorted((evaluations[i] for i in front), key=lambda ev: (ev.f2, ev.f1)) for front in ranked]


@dataclass(frozen=True)
class Ranking:
    pareto: list[Evaluation]
    recommendation: Evaluation | None
    equivalent: list[Evaluation]
    best_f1: float | None


def gene_distance(space: ParameterSpace, a: Evaluation, b: Evaluation) -> float:
    """Euclidean distance of the genes, divided by sqrt(n) so that it is 1 across the whole box."""
    difference = space.genes(a.params) - space.genes(b.params)
    return float(np.linalg.norm(difference) / math.sqrt(max(space.n_genes, 1)))


def distinct(
    ordered: Sequence[Evaluation],
    space: ParameterSpace,
    min_distance: float = DEFAULT_MIN_DISTANCE,
    *,
    stand_in: Callable[[Evaluation, list[Evaluation]], Evaluation] | None = None,
    limit: int | None = None,
) -> list[Evaluation]:
    """One set per region of parameter space, so that a list of alternatives does not repeat one
    set: walking ``ordered``, best first, a set at least ``min_distance`` (``gene_distance``)
    from every set listed so far opens a region, any other is passed over. The region is listed
    as ``stand_in(first, region)`` (by default its first set): ``region`` holds the sets of
    ``ordered`` within ``min_distance`` of the first, ``ordered``'s order kept, and only those
    at least that far from every set listed before, so the listed sets lie apart from each other
    whichever of them stands in. The first ``limit`` regions at most (all by default). Both the
    equivalent sets (``rank``) and the validation's candidates (``optimizer.validation``) walk
    their sets so."""
    listed: list[Evaluation] = []
    for first in ordered:
        if limit is not None and len(listed) == limit:
            break
        if not all(gene_distance(space, first, kept) >= min_distance for kept in listed):
            continue
        if stand_in is None:
            listed.append(first)
            continue
        region = [
            evaluation
            for evaluation in ordered
            if gene_distance(space, evaluation, first) < min_distance
            and all(gene_distance(space, evaluation, kept) >= min_distance for kept in listed)
        ]
        listed.append(stand_in(first, region))
    return listed


def rank(
    evaluations: Sequence[Evaluation],
    tolerance: float,
    space: ParameterSpace,
    min_distance: float = DEFAULT_MIN_DISTANCE,
    min_replicates: int = 1,
) -> Ranking:
    matching = sorted(
        (
            evaluation
            for evaluation in evaluations
            if evaluation.matches(tolerance) and evaluation.n_replicates >= min_replicates
        ),
        key=lambda ev: (ev.f2, ev.f1, ev.individual),
    )
    listed = distinct(matching, space, min_distance)
    all_fronts = fronts(evaluations)
    return Ranking(
        pareto=all_fronts[0] if all_fronts else [],
        recommendation=listed[0] if listed else None,
        equivalent=listed[1:],
        best_f1=min((evaluation.f1 for evaluation in evaluations if evaluation.ok), default=None),
    )


def summary(evaluation: Evaluation) -> dict:
    """An individual as JSON: what the store keeps as the recommendation and the CLI prints."""
    return {
        "individual": evaluation.individual,
        "generation": evaluation.generation,
        "params": evaluation.params,
        "f1": evaluation.f1,
        "f1_interval": list(evaluation.f1_interval),
        "f2": evaluation.f2,
        "status": evaluation.status,
        "violation": evaluation.violation,
        "replicates": evaluation.n_replicates,
        "n_remaining": evaluation.n_remaining,
        "responses": evaluation.responses,
        "wall_time_s": evaluation.wall_time_s,
        "cost": evaluation.cost,
        "trial_ids": evaluation.trial_ids,
        "failure": evaluation.failure,
    }


def recommendation_json(
    ranking: Ranking, target: float, tolerance: float, objective_time: str
) -> dict | None:
    """The stored recommendation: the chosen set, how it was chosen, and its equivalents."""
    if ranking.recommendation is None:
        return None
    return {
        **summary(ranking.recommendation),
        "target": target,
        "tolerance": tolerance,
        "objective_time": objective_time,
        "equivalent": [summary(evaluation) for evaluation in ranking.equivalent],
    }
