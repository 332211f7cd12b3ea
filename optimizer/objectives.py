"""The two objectives of an individual (one parameter set), from its trials' results.

f1 (match): ``|aggregate(simulated N_t over replicates) - target|`` where the target is the
experiment's aggregate with the study's rounding rule (the paper: median 3.5 used as 4); or, with
``experiment.distance = "wasserstein"``, the Wasserstein-1 distance between the replicates' N_t and
all measured values, which also rewards reproducing the spread of the experiment.

f2 (speed): the mean over replicates of either the wall seconds T (``objective_time = "wall"``,
the paper's choice) or the machine-independent cost (``"cost"``: sum over steps of spheres +
contacts). Cost is the default: with workers on different hardware, or two simulations sharing a
core, wall time ranks the machine rather than the parameters; cost depends only on the
parameters and the seed, so the GA stays deterministic for a given study seed.

A failed individual (any replicate ``unstable``, ``timeout``, ``error`` or ``cancelled``) gets
worst-case objectives, f1 = the number of items and f2 = the largest f2 of any successful
individual (or its own, if larger), and keeps the reason. The study goes on.

This module is pure arithmetic on results: it must not read stores or call simulations.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from scipy.stats import wasserstein_distance

from dem.result import SimulationResult
from optimizer.protocols import TrialRecord
from optimizer.study import StudyDefinition, aggregate


@dataclass(frozen=True)
class Evaluation:
    """One individual's objectives and what they came from."""

    individual: int
    generation: int
    params: dict[str, float]
    f1: float
    f2: float
    n_remaining: list[int]
    wall_time_s: float
    cost: float
    trial_ids: list[str] = field(default_factory=list)
    failure: str = ""  # "" when every replicate ended ok; else "<status>: <message>"

    @property
    def ok(self) -> bool:
        return not self.failure

    def matches(self, tolerance: float) -> bool:
        # The float slack keeps a median of exactly target +- tolerance inside.
        return self.ok and self.f1 <= tolerance + 1e-9


def match_distance(n_remaining: Sequence[float], definition: StudyDefinition) -> float:
    """f1 of a successful individual."""
    experiment = definition.experiment
    if experiment.distance == "wasserstein":
        return float(wasserstein_distance(list(n_remaining), experiment.measured))
    return abs(aggregate(list(n_remaining), experiment.aggregate) - experiment.target())


def _time(result: SimulationResult, objective_time: str) -> float:
    return result.wall_time_s if objective_time == "wall" else result.cost


def evaluate(records: Iterable[TrialRecord], definition: StudyDefinition, n_items: int) -> list[Evaluation]:
    """Objectives of every individual whose trials all have results, sorted by individual.

    The penalty's f2 is taken over the successful individuals in ``records``, so pass all of a
    study's trials, not one batch, to penalise consistently.
    """
    by_individual: dict[int, list[TrialRecord]] = {}
    for record in records:
        by_individual.setdefault(record.spec.individual, []).append(record)

    raw = []
    for individual, group in sorted(by_individual.items()):
        if any(record.result is None for record in group):
            continue
        group.sort(key=lambda record: record.spec.replicate)
        results = [record.result for record in group]
        failed = [result for result in results if not result.ok]
        f2 = sum(_time(result, definition.objective_time) for result in results) / len(results)
        if failed:
            failure = f"{failed[0].status.value}: {failed[0].message}".rstrip(": ")
            f1 = float(n_items)
        else:
            failure = ""
            f1 = match_distance([result.n_remaining for result in results], definition)
        raw.append((individual, group, results, f1, f2, failure))

    worst_f2 = max((f2 for *_, f2, failure in raw if not failure), default=0.0)
    evaluations = []
    for individual, group, results, f1, f2, failure in raw:
        evaluations.append(
            Evaluation(
                individual=individual,
                generation=min(record.spec.generation for record in group),
                params=dict(group[0].spec.params),
                f1=f1,
                f2=max(f2, worst_f2) if failure else f2,
                n_remaining=[result.n_remaining for result in results if result.n_remaining is not None],
                wall_time_s=sum(result.wall_time_s for result in results) / len(results),
                cost=sum(result.cost for result in results) / len(results),
                trial_ids=[record.spec.trial_id for record in group],
                failure=failure,
            )
        )
    return evaluations
