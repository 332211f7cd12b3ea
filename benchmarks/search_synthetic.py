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

``--fig5`` asks another question of the same landscape: the paper's Fig. 5, the median N_t of
each generation's runs, against the median of the same sets' *true* medians (what fresh seeds
would give). With one run per set, the first can stay off the target while the population sits
on it; the second says where the search is.

    python -m benchmarks.search_synthetic --fig5 --algorithms nsga2 --budget 185 \
        --population 50 --offspring 15
"""

from __future__ import annotations

import argparse
import functools
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


def draw(genes: np.ndarray, rng: np.random.Generator, size=None, jam: float = 0.0):
    """N_t of the synthetic feeder: 0 (emptied) or a clog that keeps 1 + Poisson(lam + jam) items
    (``jam = 6`` makes jams keep 7-27 items, as the full feeder's do)."""
    p_clog = 1.0 / (
        1.0 + np.exp(-(9.0 * (genes[3] - 0.55) - 5.0 * (genes[2] - 0.4) + 1.5 * (genes[0] - 0.5)))
    )
    lam = 1.0 + 12.0 * genes[3] ** 2 * (1.2 - genes[2]) + jam
    clogged = rng.random(size) < p_clog
    return np.where(clogged, np.minimum(1 + rng.poisson(lam, size), N_ITEMS), 0)


def true_median(genes: np.ndarray, jam: float = 0.0) -> float:
    return float(np.median(draw(genes, np.random.default_rng(12345), 4001, jam)))


def respond(spec, jam: float = 0.0) -> SimulationResult:
    genes = genes_of(spec.params)
    steps = int(1000 * math.sqrt(spec.params["E"] / 1e5))
    if genes[0] < 0.2:
        return SimulationResult(status=SimulationStatus.UNSTABLE, message="overlap", n_items=N_ITEMS)
    n_t = int(draw(genes, np.random.default_rng(spec.seed), jam=jam))
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


def searched(
    algorithm: str, seed: int, args, validation: dict | None = None
) -> tuple[StudyDefinition, MemoryStore, str, float]:
    """One study on the synthetic feeder, driven to its end: its definition, store, id and CPU s."""
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
                "match_estimate": args.estimate,
                **({"survivors": args.survivors} if args.survivors else {}),
            },
            **({"validation": validation} if validation is not None else {}),
        }
    )
    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"), None)
    started = time.process_time()
    executor = SyntheticExecutor(functools.partial(respond, jam=args.jam))
    Driver(store, executor).run_to_completion(study_id, poll_timeout=0)
    return definition, store, study_id, time.process_time() - started


def fig5(algorithm: str, seed: int, args) -> list[tuple[float, float]]:
    """Per generation: (median N_t of its runs, median of its sets' true medians)."""
    definition, store, study_id, _ = searched(algorithm, seed, args, validation={"seeds": 0})
    space = ParameterSpace(definition.parameters)
    rows: dict[int, list[tuple[int, float]]] = {}
    for record in store.trials(study_id):
        result = record.result
        if result is not None and result.ok and record.spec.generation <= definition.ga.generations:
            truth = true_median(space.genes(record.spec.params), args.jam)
            rows.setdefault(record.spec.generation, []).append((result.n_remaining, truth))
    out = []
    for generation in sorted(rows):
        observed, true = zip(*rows[generation], strict=True)
        out.append((statistics.median(observed), statistics.median(true)))
    return out


def run(algorithm: str, seed: int, args) -> dict:
    definition, store, study_id, cpu = searched(algorithm, seed, args)
    evaluations = sorted(evaluate(store.trials(study_id), definition, N_ITEMS), key=lambda ev: ev.individual)
    tolerance, target = definition.experiment.tolerance, definition.experiment.target()
    space = ParameterSpace(definition.parameters)
    first = validated = None
    for ev in evaluations:
        if ev.matches(tolerance):
            first = first or ev.individual + 1
            if abs(true_median(space.genes(ev.params), args.jam) - target) <= tolerance:
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
    parser.add_argument("--fig5", action="store_true", help="Median N_t per generation, observed and true.")
    parser.add_argument("--jam", type=float, default=0.0, help="Added to a jam's mean (6: 7-27 items).")
    parser.add_argument("--estimate", choices=("own", "neighbours"), default="own", help="ga.match_estimate")
    parser.add_argument("--survivors", type=int, help="ga.survivors (default: the whole population)")
    args = parser.parse_args()
    if args.fig5:
        for algorithm in args.algorithms.split(","):
            per_seed = [fig5(algorithm, seed, args) for seed in range(args.seeds)]
            print(f"{algorithm}: per generation, median N_t of its runs / median of its sets' true medians")
            for seed, rows in enumerate(per_seed):
                print(f"  seed {seed}: " + "  ".join(f"{n:g}/{t:g}" for n, t in rows), flush=True)
            last = [rows[-1] for rows in per_seed]
            print(
                f"  last generation, over seeds: runs' median {statistics.median(n for n, _ in last):g}, "
                f"true medians' median {statistics.median(t for _, t in last):g} (target 4)"
            )
        return
    box = np.random.default_rng(0).random((20000, 4))
    share = np.mean([abs(true_median(g, args.jam) - 4) <= 0.5 for g in box[:2000]])
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
