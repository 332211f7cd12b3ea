"""Search methods on a synthetic feeder: simulations until the first *validated* match, over
many study seeds, through the real driver (in-memory store, synthetic executor).

The synthetic response imitates what the full feeder showed (benchmarks/README.md): a run either
empties the tray (N_t = 0) or clogs, and then keeps several items; the chance of clogging grows
with friction and falls with restitution; soft sets (log E gene < 0.2) end ``unstable``; cost
grows as sqrt(E). A set is a validated match when its single search run matched *and* the true
median of its N_t distribution (Monte Carlo, 4001 draws) is within the tolerance: what fresh
seeds would confirm. Cheap (no DEM), so the comparison can be repeated over seeds; it says
nothing about the feeder itself, only about the searches on a landscape of its kind.

    python -m benchmarks.search_synthetic [--seeds 10] [--budget 60] [--population 10 --offspring 5]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from dem.result import SimulationResult, SimulationStatus
from optimizer.driver import Driver
from optimizer.memory import MemoryStore, SyntheticExecutor
from optimizer.objectives import evaluate
from optimizer.space import ParameterSpace
from optimizer.study import StudyDefinition

N_ITEMS = 30
MEASURED = [0, 0, 1, 2, 3, 4, 4, 12, 15, 16]  # the paper's ten experiments: target 4


def genes_of(params) -> np.ndarray:
    return np.array(
        [(math.log10(params["E"]) - 5.0) / 4.0, params["nu"] / 0.49, (params["e"] - 0.05) / 0.9, params["mu"]]
    )


def draw(genes: np.ndarray, rng: np.random.Generator, size=None):
    """N_t of the synthetic feeder: 0 (emptied) or a clog that keeps 1 + Poisson(lam) items."""
    p_clog = 1.0 / (
        1.0 + np.exp(-(9.0 * (genes[3] - 0.55) - 5.0 * (genes[2] - 0.4) + 1.5 * (genes[0] - 0.5)))
    )
    lam = 1.0 + 12.0 * genes[3] ** 2 * (1.2 - genes[2])
    clogged = rng.random(size) < p_clog
    return np.where(clogged, np.minimum(1 + rng.poisson(lam, size), N_ITEMS), 0)


def true_median(genes: np.ndarray) -> float:
    return float(np.median(draw(genes, np.random.default_rng(12345), 4001)))


def respond(spec) -> SimulationResult:
    genes = genes_of(spec.params)
    steps = int(1000 * math.sqrt(spec.params["E"] / 1e5))
    if genes[0] < 0.2:
        return SimulationResult(status=SimulationStatus.UNSTABLE, message="overlap", n_items=N_ITEMS)
    n_t = int(draw(genes, np.random.default_rng(spec.seed)))
    return SimulationResult(
        status=SimulationStatus.OK,
        n_items=N_ITEMS,
        n_remaining=n_t,
        steps=steps,
        cost=float(steps * 40),
        wall_time_s=steps * 1e-4,
        params=spec.params,
        seed=spec.seed,
    )


def run(algorithm: str, seed: int, args) -> dict:
    generations = (args.budget - args.population) // args.offspring
    definition = StudyDefinition.model_validate(
        {
            "scenario": {},
            "experiment": {"measured": MEASURED},
            "seed": seed,
            "ga": {
                "algorithm": algorithm,
                "population": args.population,
                "offspring": args.offspring,
                "generations": generations,
            },
        }
    )
    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"), None)
    started = time.process_time()
    Driver(store, SyntheticExecutor(respond)).run_to_completion(study_id, poll_timeout=0)
    cpu = time.process_time() - started
    evaluations = sorted(evaluate(store.trials(study_id), definition, N_ITEMS), key=lambda ev: ev.individual)
    tolerance, target = definition.experiment.tolerance, definition.experiment.target()
    space = ParameterSpace(definition.parameters)
    first = validated = None
    for ev in evaluations:
        if ev.matches(tolerance):
            first = first or ev.individual + 1
            if abs(true_median(space.genes(ev.params)) - target) <= tolerance:
                validated = ev.individual + 1
                break
    failed = sum(not ev.ok for ev in evaluations)
    return {"first": first, "validated": validated, "failed": failed, "cpu": cpu}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--budget", type=int, default=60)
    parser.add_argument("--population", type=int, default=10)
    parser.add_argument("--offspring", type=int, default=5)
    parser.add_argument("--algorithms", default="surrogate,nsga2,random")
    args = parser.parse_args()
    box = np.random.default_rng(0).random((20000, 4))
    share = np.mean([abs(true_median(g) - 4) <= 0.5 for g in box[:2000]])
    print(f"share of the box whose true median N_t is 4: {share:.3f} (2000 uniform points)")
    print("| method | validated found | sims to first validated match (median; each seed) | failed | CPU s |")
    print("| --- | --- | --- | --- | --- |")
    for algorithm in args.algorithms.split(","):
        rows = [run(algorithm, seed, args) for seed in range(args.seeds)]
        found = [row["validated"] for row in rows if row["validated"] is not None]
        values = [row["validated"] if row["validated"] is not None else f">{args.budget}" for row in rows]
        median = statistics.median([row["validated"] or args.budget + 1 for row in rows])
        print(
            f"| {algorithm} | {len(found)} of {len(rows)} | {median:g} ({', '.join(map(str, values))}) | "
            f"{statistics.mean(row['failed'] for row in rows):.1f} | "
            f"{statistics.mean(row['cpu'] for row in rows):.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
