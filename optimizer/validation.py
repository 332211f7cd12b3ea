"""The validation that ends every study: the recommendation and the next fastest matching sets
re-simulated on fresh seeds never used in the search (``optimizer/seeds.py``).

A set was selected because its few search replicates matched; with the feeder's noise some of
that is luck (selection on noise), so the only honest evidence is new draws. Per candidate the
fresh N_t are compared with the experiment as the search compared them (f1 with the study's
distance), with a bootstrap interval, the Wasserstein-1 distance to all measured values and the
fresh median with its interval.

Verdict: ``validated`` when every fresh run is a measurement (none invalid or failed) and the
fresh f1 interval reaches the tolerance (its lower end <= tolerance: the fresh runs do not rule
out the match); otherwise ``not reproduced``. The recommendation becomes the fastest validated
set; when none validates, the fastest matching set stays, labelled ``not reproduced``; a study
without validation (``validation.seeds = 0``) labels it ``not validated``.

Pure arithmetic on records, like ``optimizer/objectives.py``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from scipy.stats import wasserstein_distance

from optimizer.noise import bootstrap_interval, median_many
from optimizer.objectives import Evaluation, match_distance, match_interval
from optimizer.protocols import TrialRecord
from optimizer.study import StudyDefinition, aggregate

VALIDATED = "validated"
NOT_REPRODUCED = "not reproduced"
NOT_VALIDATED = "not validated"


def candidates(ranked_matches: Sequence[Evaluation], definition: StudyDefinition) -> list[Evaluation]:
    """The sets to validate: the recommendation and the next fastest distinct matching sets."""
    return list(ranked_matches)[: definition.validation.candidates]


def check(evaluation: Evaluation, fresh: Sequence[TrialRecord], definition: StudyDefinition) -> dict:
    """One candidate's validation row (JSON), from its fresh-seed trials."""
    experiment = definition.experiment
    results = [record.result for record in sorted(fresh, key=lambda r: r.spec.replicate) if record.result]
    response = definition.experiment.response
    measured = [
        result
        for result in results
        if result.ok and all(result.responses.get(x.response) is not None for x in definition.experiments)
    ]
    values = {
        x.response: [result.responses[x.response] for result in measured] for x in definition.experiments
    }
    counts = values[response]
    failures = [
        f"{result.status.value}: {result.message}".rstrip(": ") for result in results if not result.ok
    ]
    row = {
        "individual": evaluation.individual,
        "params": evaluation.params,
        "search_f1": evaluation.f1,
        "search_replicates": evaluation.n_replicates,
        "f2": evaluation.f2,
        "seeds": [record.spec.seed for record in fresh],
        "n_remaining": counts,
        "failures": failures,
        "w1": None,
        "median": None,
        "median_interval": None,
        "f1": None,
        "f1_interval": None,
        "verdict": NOT_REPRODUCED,
    }
    if counts:
        f1_interval = match_interval(values, definition, seed=evaluation.individual)
        row.update(
            w1=float(wasserstein_distance(counts, experiment.measured)),
            median=aggregate(counts, "median"),
            median_interval=list(bootstrap_interval(counts, median_many, seed=evaluation.individual)),
            f1=match_distance(values, definition),
            f1_interval=list(f1_interval),
        )
        complete = len(counts) == len(fresh) and not failures
        if complete and f1_interval[0] <= definition.match_tolerance() + 1e-9:
            row["verdict"] = VALIDATED
    return row


def table(
    checked: Sequence[Evaluation], records: Iterable[TrialRecord], definition: StudyDefinition
) -> list[dict]:
    """Validation rows of the candidates, in their order (fastest first)."""
    batch = definition.validation_batch()
    fresh: dict[int, list[TrialRecord]] = {}
    for record in records:
        if record.spec.generation == batch:
            fresh.setdefault(record.spec.individual, []).append(record)
    return [check(evaluation, fresh.get(evaluation.individual, []), definition) for evaluation in checked]
