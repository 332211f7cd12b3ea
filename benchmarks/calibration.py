"""Synthetic-truth calibration benchmark: can the GA find parameters we hid, and does it beat
random search with the same budget?

1. Hidden parameters -> the quick feeder (examples/feeder-quick.toml) with 10 seeds -> a
   synthetic experiment (ten N_t values).
2. Calibrate against it with the study's GA (nsga2), and, beside it, with random search on the
   same budget (same seeds for the first batch's size, same objectives).
3. Re-simulate each recommended set with 10 fresh seeds and compare the N_t distribution with
   the synthetic experiment.

Prints: simulations until f1 first fell within tolerance, the recommended set vs the truth, the
fresh-seed N_t distribution vs the experiment. Runs on the embedded path: a temporary SQLite
store (the same SqlStore ``demcal calibrate`` uses) and the local process pool.

    python benchmarks/calibration.py [--workers 2] [--population 8 --offspring 4 --generations 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from api.db import create_db_engine, upgrade_database
from api.store import SqlStore
from optimizer.driver import Driver
from optimizer.protocols import TrialSpec
from optimizer.report import build_summary
from optimizer.study import load_study_file
from worker.local import LocalPoolExecutor

ROOT = Path(__file__).resolve().parent.parent
TRUTH = {"E": 3.0e6, "nu": 0.3, "e": 0.5, "mu": 0.6}


def simulate(executor, scenario, params, seeds, label):
    specs = [TrialSpec(f"{label}-{seed}", label, 0, 0, 0, seed, params, scenario) for seed in seeds]
    executor.submit(specs)
    results = {}
    while len(results) < len(specs):
        for outcome in executor.poll(timeout=1.0):
            results[outcome.trial_id] = outcome.result
    return [results[spec.trial_id] for spec in specs]


def calibrate(store, executor, definition):
    study_id = store.create_study(definition.model_dump(mode="json"), None)
    started = time.monotonic()
    Driver(store, executor).run_to_completion(study_id)
    summary = build_summary(store.load_study(study_id), store.trials(study_id))
    summary["elapsed_s"] = time.monotonic() - started
    return summary


def describe(values):
    return (
        f"median {statistics.median(values):g}, mean {statistics.mean(values):.2f}, values {sorted(values)}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--population", type=int, default=8)
    parser.add_argument("--offspring", type=int, default=4)
    parser.add_argument("--generations", type=int, default=3)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument(
        "--truth", default="", help=f"Hidden parameters to change, e.g. 'mu=0.9,e=0.2' (default: {TRUTH})"
    )
    parser.add_argument(
        "--dt", type=float, default=None, help="Force the feeder's time step (run.dt), s; default: from E."
    )
    args = parser.parse_args()
    for item in filter(None, args.truth.split(",")):
        name, _, value = item.partition("=")
        TRUTH[name.strip()] = float(value)

    base = load_study_file(ROOT / "examples" / "study-quick.toml")
    if args.dt is not None:
        scenario = {**base.scenario, "run": {**base.scenario["run"], "dt": args.dt}}
        base = base.model_copy(update={"scenario": scenario})
    executor = LocalPoolExecutor(args.workers)
    try:
        started = time.monotonic()
        truth_results = simulate(executor, base.scenario, TRUTH, range(1000, 1010), "truth")
        measured = [r.n_remaining for r in truth_results if r.ok]
        truth_wall = statistics.mean(r.wall_time_s for r in truth_results)
        print(
            f"truth {TRUTH}: synthetic experiment N_t {describe(measured)}; "
            f"{truth_wall:.1f} s wall per simulation ({time.monotonic() - started:.0f} s for 10)"
        )

        ga = {"population": args.population, "offspring": args.offspring, "generations": args.generations}
        with tempfile.TemporaryDirectory() as folder:
            url = f"sqlite:///{folder}/bench.db"
            upgrade_database(url)
            store = SqlStore(create_db_engine(url))
            rows = []
            for algorithm in ("nsga2", "random"):
                definition = base.model_copy(
                    update={
                        "name": f"bench-{algorithm}",
                        "seed": args.seed,
                        "experiment": base.experiment.model_copy(update={"measured": measured}),
                        "ga": base.ga.model_copy(update={**ga, "algorithm": algorithm}),
                    }
                )
                summary = calibrate(store, executor, definition)
                chosen = summary["recommendation"]
                fresh = None
                if chosen is not None:
                    fresh_results = simulate(
                        executor, base.scenario, chosen["params"], range(5000, 5010), algorithm
                    )
                    fresh = [r.n_remaining for r in fresh_results if r.ok]
                rows.append((algorithm, definition, summary, chosen, fresh))
    finally:
        executor.close()

    target = rows[0][1].experiment.target()
    print(
        f"target N_t = {target:g} (median of the synthetic experiment, half-up), tolerance "
        f"{rows[0][1].experiment.tolerance:g}; budget {rows[0][1].total_simulations()} simulations each"
    )
    for algorithm, _definition, summary, chosen, fresh in rows:
        print(
            f"\n[{algorithm}] {summary['simulations']} simulations in {summary['elapsed_s']:.0f} s; "
            f"first match after {summary['simulations_until_first_match']} simulations; "
            f"best f1 {summary['best_f1']}; matching sets: "
            f"{(1 + len(summary['equivalent'])) if chosen else 0}"
        )
        if chosen is None:
            print("  no recommendation")
            continue
        for name in ("E", "nu", "e", "mu"):
            print(f"  {name:>2}: recommended {chosen['params'][name]:.4g}  truth {TRUTH[name]:.4g}")
        print(f"  recommended set's cost {chosen['cost']:.3g} ({chosen['wall_time_s']:.1f} s wall)")
        print(f"  fresh seeds N_t: {describe(fresh)}")
        print(f"  experiment  N_t: {describe(measured)}")


if __name__ == "__main__":
    main()
