"""The two objectives of an individual (one parameter set), from its trials' results.

f1 (match), per experiment: ``|aggregate(simulated response over replicates) - target|`` where the
response is the one the experiment names (the feeder's N_t, a heap's angle) and the target is the
experiment's aggregate with its rounding rule (the paper: median 3.5 used as 4); or, with
``experiment.distance = "wasserstein"``, the Wasserstein-1 distance between the replicates' values
and all measured values, which also rewards reproducing the spread of the experiment. With one
experiment f1 is that distance, in the response's unit. With several (the rule, documented in
``StudyDefinition.experiments``): f1 = max over experiments of distance / tolerance, so f1 <= 1
exactly when every experiment matches, and the GA improves the worst-matched one first.

f2 (speed): the mean over replicates of either the wall seconds T (``objective_time = "wall"``,
the paper's choice) or the machine-independent cost (``"cost"``: sum over steps of spheres +
contacts), each of the whole protocol: the paper's T is the time of the full 65 s simulation,
while a run that empties the tray stops early and, with fewer items, does less work a step. Its
T is scaled by the result's ``full_load_factor`` (the protocol's body-seconds over the run's), so
that f2 prices the parameters (the step E sets, the contacts mu and e make) and not the outcome:
unscaled, a set whose tray empties cost 1.5x less than one that clogs with four items at the same
E, and among matching sets the search was pulled to the emptying edge (benchmarks/README:
calibration 16). Cost is the default: with workers on different hardware, or two simulations sharing a
core, wall time ranks the machine rather than the parameters; cost depends only on the
parameters and the seed, so the GA stays deterministic for a given study seed.

The match comes first (the paper's problem: "equate N_t with the experiment, then minimise T"),
so the search also gets two constraints, each satisfied when <= 0 (pymoo's convention):

- ``g_match = f1 - match tolerance``: the set reproduces the experiment(s);
- ``g_validity``: 0 when every replicate is a measurement; otherwise the mean over replicates of
  how far each left the model: an ``invalid`` run's ``max_overlap / overlap limit`` (>= 1, the
  overlap its impact was heading for), and 1 for any other failure (``unstable``, ``timeout``,
  ``error``, ``cancelled``: no distance is known).

A failed individual is never a measurement: its f1 is the worst possible (with one experiment the
first response's failed value or the largest measured value; with several, the combined distance
of every response's failed value), so ``g_match`` is as large as it can be; among failed sets the
deeper overlap ranks worse. Its f2 is the largest f2 of any successful individual (or its own, if
larger), and it keeps the reason. The study goes on. Every f1 of a measured set carries a
bootstrap interval over its replicates (``f1_interval``): with the feeder's noise, f1 of a few
runs is an estimate. ``distance = "auto"`` (resolved by the study) is Wasserstein-1 from 3
replicates on.

This module is pure arithmetic on results: it must not read stores or call simulations.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.stats import wasserstein_distance

from dem.result import OVERLAP_LIMIT, SimulationResult, SimulationStatus
from optimizer.noise import bootstrap_interval, median_many, wasserstein_many
from optimizer.protocols import TrialRecord
from optimizer.study import Experiment, StudyDefinition, aggregate
from optimizer.surrogate import MatchRule, Observation


def _measured(result: SimulationResult, definition: StudyDefinition) -> list:
    return [result.responses.get(experiment.response) for experiment in definition.experiments]


@dataclass(frozen=True)
class Evaluation:
    """One individual's objectives and what they came from."""

    individual: int
    generation: int
    params: dict[str, float]
    f1: float
    f2: float
    n_remaining: list[float]  # the first experiment's response over the replicates (N_t for the feeder)
    wall_time_s: float  # of the whole protocol (protocol_wall_time), mean over replicates
    cost: float  # of the whole protocol (protocol_cost), mean over replicates
    trial_ids: list[str] = field(default_factory=list)
    failure: str = ""  # "" when every replicate ended ok; else "<status>: <message>"
    responses: dict[str, list[float]] = field(default_factory=dict)  # every experiment's response
    status: str = "ok"  # "ok", or the status of the first failed replicate ("invalid", ...)
    g_match: float = 0.0  # f1 - match tolerance; <= 0 when the set matches
    g_validity: float = 0.0  # 0 when every replicate is a measurement; > 0 otherwise
    f1_interval: tuple[float, float] = (0.0, 0.0)  # bootstrap interval over the replicates

    @property
    def n_replicates(self) -> int:
        return len(self.trial_ids)

    @property
    def violation(self) -> float:
        """pymoo's constraint violation (the sum of the positive parts): 0 for a feasible set."""
        return max(self.g_match, 0.0) + max(self.g_validity, 0.0)

    @property
    def ok(self) -> bool:
        return not self.failure

    def matches(self, tolerance: float) -> bool:
        # The float slack keeps a median of exactly target +- tolerance inside.
        return self.ok and self.f1 <= tolerance + 1e-9


def experiment_distance(values: Sequence[float], experiment: Experiment) -> float:
    """One experiment's distance between simulated values (replicates) and its measurement."""
    if _wasserstein(experiment, len(values)):
        return float(wasserstein_distance(list(values), experiment.measured))
    return abs(aggregate(list(values), experiment.aggregate) - experiment.target())


def _wasserstein(experiment: Experiment, n: int) -> bool:
    return experiment.distance == "wasserstein" or (experiment.distance == "auto" and n >= 3)


def f1_rule(definition: StudyDefinition) -> str:
    """f1 in words, as the study defines it (for titles and axis labels): what the views print
    must be the formula the search used, W1 or the aggregate, never a guess."""
    if len(definition.experiments) > 1:
        names = ", ".join(experiment.response for experiment in definition.experiments)
        return f"max over experiments ({names}) of distance / tolerance"
    experiment = definition.experiment
    if _wasserstein(experiment, definition.replicates):
        return f"W1({experiment.response} of the replicates, {len(experiment.measured)} measured values)"
    return f"|{experiment.aggregate}({experiment.response}) - {experiment.target():g}|"


def match_interval(
    values: dict[str, Sequence[float]], definition: StudyDefinition, seed: int
) -> tuple[float, float]:
    """The bootstrap interval of f1 over the replicates (``optimizer/noise.py``); with several
    experiments the replicates are resampled jointly."""
    if len(definition.experiments) == 1:
        experiment = definition.experiment
        own = values[experiment.response]
        if _wasserstein(experiment, len(own)):
            return bootstrap_interval(own, lambda d: wasserstein_many(d, experiment.measured), seed)
        centre = (lambda d: d.mean(axis=1)) if experiment.aggregate == "mean" else median_many
        return bootstrap_interval(own, lambda d: np.abs(centre(d) - experiment.target()), seed)
    n = len(next(iter(values.values())))
    rng = np.random.default_rng(seed)
    draws = [rng.integers(0, n, size=n) for _ in range(200)]
    stats = [match_distance({k: [v[i] for i in d] for k, v in values.items()}, definition) for d in draws]
    return float(np.quantile(stats, 0.05)), float(np.quantile(stats, 0.95))


def worst_f1(definition: StudyDefinition, n_items: int) -> float:
    """The largest f1 a measured set can have: the response's failed value or the largest
    measured value (one experiment), or the combined distance of the failed values (several)."""
    if len(definition.experiments) == 1:
        return float(max([n_items, *definition.experiment.measured]))
    worst = definition.failed_responses()
    return match_distance({name: [worst[name]] for name in worst}, definition)


def replicate_violation(result: SimulationResult, overlap_limit: float = OVERLAP_LIMIT) -> float:
    """How far one run is from being a measurement: 0 if ok, >= 1 otherwise (see the docstring)."""
    if result.ok:
        return 0.0
    if result.status is SimulationStatus.INVALID and result.max_overlap:
        return max(1.0, result.max_overlap / overlap_limit)
    return 1.0


def match_distance(
    values: Sequence[float] | dict[str, Sequence[float]], definition: StudyDefinition
) -> float:
    """f1 of a successful individual from each response's replicate values (a bare sequence is
    the first experiment's response)."""
    if not isinstance(values, dict):
        values = {definition.experiment.response: values}
    if len(definition.experiments) == 1:
        return experiment_distance(values[definition.experiment.response], definition.experiment)
    return max(
        experiment_distance(values[experiment.response], experiment) / max(experiment.tolerance, 1e-12)
        for experiment in definition.experiments
    )


def response_values(
    results: Sequence[SimulationResult], definition: StudyDefinition
) -> dict[str, list[float]]:
    """Each experiment's response over the replicates."""
    return {
        experiment.response: [result.responses.get(experiment.response) for result in results]
        for experiment in definition.experiments
    }


class RunTimes(Protocol):
    """What the protocol's times are made of: a ``SimulationResult``, or a stored trial's columns
    (``api/store/reads.py``), so that the views price a run as the search does."""

    wall_time_s: float
    cost: float
    full_load_factor: float


def protocol_wall_time(result: RunTimes) -> float:
    """The wall seconds the whole protocol would take at this run's pace (``full_load_factor``)."""
    return result.wall_time_s * result.full_load_factor


def protocol_cost(result: RunTimes) -> float:
    """The cost the whole protocol would take at this run's work per body-second."""
    return result.cost * result.full_load_factor


def protocol_times(run: RunTimes) -> dict[str, float | None]:
    """A run's whole-protocol T and cost, as the views name them: what f2 is made of (a run that
    emptied the tray stopped early); None where the run has no time of its own (no result yet)."""
    return {
        "protocol_wall_time_s": None if run.wall_time_s is None else protocol_wall_time(run),
        "protocol_cost": None if run.cost is None else protocol_cost(run),
    }


def _time(result: SimulationResult, objective_time: str) -> float:
    return protocol_wall_time(result) if objective_time == "wall" else protocol_cost(result)


def evaluate(
    records: Iterable[TrialRecord], definition: StudyDefinition, n_items: int, *, intervals: bool = True
) -> list[Evaluation]:
    """Objectives of every individual whose trials all have results, sorted by individual.

    The penalty's f2 is taken over the successful individuals in ``records``, so pass all of a
    study's trials, not one batch, to penalise consistently. ``intervals=False`` leaves each
    ``f1_interval`` at (nan, nan): its bootstrap is most of the cost, and views that never show
    it (progress, identifiability) skip it.
    """
    by_individual: dict[int, list[TrialRecord]] = {}
    validation = definition.validation_batch()
    for record in records:
        if record.spec.generation < validation:
            by_individual.setdefault(record.spec.individual, []).append(record)

    raw = []
    for individual, group in sorted(by_individual.items()):
        first = min(record.spec.generation for record in group)
        if any(record.result is None for record in group if record.spec.generation == first):
            continue  # its own batch is still running; extra replicates may still be running
        group = [record for record in group if record.result is not None]
        group.sort(key=lambda record: record.spec.replicate)
        results = [record.result for record in group]
        failed = [result for result in results if not result.ok]
        f2 = sum(_time(result, definition.objective_time) for result in results) / len(results)
        missing = [r for r in results if any(v is None for v in _measured(r, definition))]
        if failed or missing:
            bad = (failed or missing)[0]
            failure = f"{bad.status.value}: {bad.message or 'a response was not measured'}".rstrip(": ")
            f1 = worst_f1(definition, n_items)
        else:
            failure = ""
            f1 = match_distance(response_values(results, definition), definition)
        raw.append((individual, group, results, f1, f2, failure))

    worst_f2 = max((f2 for *_, f2, failure in raw if not failure), default=0.0)
    tolerance = definition.match_tolerance()
    evaluations = []
    for individual, group, results, f1, f2, failure in raw:
        # Only runs that measured: a failed run's values are where it stopped.
        measured = response_values([result for result in results if result.ok], definition)
        failed = next((result for result in results if not result.ok), None)
        if not intervals:
            interval = (math.nan, math.nan)
        elif failure:
            interval = (f1, f1)
        else:
            interval = match_interval(measured, definition, seed=individual)
        evaluations.append(
            Evaluation(
                individual=individual,
                generation=min(record.spec.generation for record in group),
                params=dict(group[0].spec.params),
                f1=f1,
                f2=max(f2, worst_f2) if failure else f2,
                n_remaining=[v for v in measured[definition.experiment.response] if v is not None],
                responses={k: [v for v in vs if v is not None] for k, vs in measured.items()},
                wall_time_s=sum(protocol_wall_time(result) for result in results) / len(results),
                cost=sum(protocol_cost(result) for result in results) / len(results),
                trial_ids=[record.spec.trial_id for record in group],
                failure=failure,
                status=failed.status.value if failed is not None else ("error" if failure else "ok"),
                f1_interval=interval,
                g_match=f1 - tolerance,
                g_validity=sum(replicate_violation(result) for result in results) / len(results)
                or (1.0 if failure else 0.0),
            )
        )
    return evaluations


def match_rule(definition: StudyDefinition, n_items: int) -> MatchRule | tuple[MatchRule, ...]:
    """How f1 is formed, as the surrogate search models it (the same rule as match_distance):
    one rule per experiment when there are several (the study's f1 combines them)."""
    failed = definition.failed_responses() if len(definition.experiments) > 1 else {}
    rules = tuple(
        MatchRule(
            measured=tuple(experiment.measured),
            target=experiment.target(),
            tolerance=experiment.tolerance,
            aggregate=experiment.aggregate,
            distance=experiment.distance,
            n_items=failed.get(experiment.response, n_items),
            response=experiment.response,
        )
        for experiment in definition.experiments
    )
    return rules[0] if len(rules) == 1 else rules


def observation(evaluation: Evaluation) -> Observation:
    """What a search that models the response needs beyond (f1, f2): every experiment's values
    over the replicates and the failure."""
    if not evaluation.ok:
        return Observation((), evaluation.f2, False)
    responses = {name: tuple(values) for name, values in evaluation.responses.items()}
    return Observation(tuple(evaluation.n_remaining), evaluation.f2, True, responses)
