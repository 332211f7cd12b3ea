"""The GA's neighbours' estimate (``optimizer/neighbours.py``) read off a finished study: every
measured set of the search ranked by the pooled W1 of the whole history, beside its own run and,
for the sets the study validated, the W1 of their fresh runs. No simulation: it asks whether the
pooled estimate would have pointed where the fresh seeds later confirmed.

    python -m benchmarks.pooled_history benchmarks/paper-study-res24.archive.json [--top 12]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict

import numpy as np
from scipy.stats import wasserstein_distance

from optimizer.neighbours import NeighbourEstimate
from optimizer.objectives import match_rule
from optimizer.space import ParameterSpace
from optimizer.study import StudyDefinition
from optimizer.surrogate import Observation


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("archive", help="a study archive (demcal studies archive)")
    parser.add_argument("--top", type=int, default=12)
    args = parser.parse_args()
    with open(args.archive) as handle:
        archive = json.load(handle)
    definition = StudyDefinition.model_validate(archive["study"]["definition"])
    space = ParameterSpace(definition.parameters)
    validation = definition.validation_batch()
    done = [t for t in archive["trials"] if t["state"] == "done"]
    search = [t for t in done if t["generation"] < validation and t["replicate"] == 0]
    fresh: dict[int, list[float]] = defaultdict(list)
    for trial in done:
        if trial["generation"] == validation and trial["status"] == "ok":
            fresh[trial["individual"]].append(trial["n_remaining"])

    rule = match_rule(definition, 30)
    estimate = NeighbourEstimate(rule if isinstance(rule, tuple) else (rule,))
    genes = np.array([space.genes(t["params"]) for t in search])
    runs = [
        Observation((t["n_remaining"],), 1.0, True) if t["status"] == "ok" else Observation((), 1.0, False)
        for t in search
    ]
    estimate.remember(genes, runs)
    measured = [i for i, t in enumerate(search) if t["status"] == "ok"]
    pooled, violation = estimate.distances(genes[measured])
    order = np.argsort(pooled, kind="stable")
    rank = {search[measured[k]]["individual"]: position + 1 for position, k in enumerate(order)}
    feasible = int((violation <= 0).sum())
    print(f"{len(search)} search runs, {len(measured)} measured; feasible by the pooled W1: {feasible}")
    print("| rank | set | generation | own N_t | pooled W1 | E, Pa | nu | e | mu |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for position, k in enumerate(order[: args.top]):
        trial = search[measured[k]]
        p = trial["params"]
        print(
            f"| {position + 1} | #{trial['individual']} | {trial['generation']} | {trial['n_remaining']} | "
            f"{pooled[k]:.2f} | {p['E']:.2g} | {p['nu']:.2f} | {p['e']:.2f} | {p['mu']:.2f} |"
        )
    if fresh:
        print("\nvalidated sets: | set | pooled W1 (rank) | fresh W1 | fresh median |")
        by_individual = {search[measured[k]]["individual"]: pooled[k] for k in range(len(measured))}
        for individual, values in sorted(fresh.items()):
            w1 = wasserstein_distance(values, definition.experiment.measured)
            print(
                f"| #{individual} | {by_individual[individual]:.2f} ({rank[individual]} of {len(measured)}) "
                f"| {w1:.2f} | {np.median(values):g} |"
            )


if __name__ == "__main__":
    main()
