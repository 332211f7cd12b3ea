"""Synthetic-truth calibration benchmark: can a search find parameters we hid, how many
simulations does it need, and does its recommendation reproduce the experiment on fresh seeds?

1. A synthetic experiment: hidden parameters (the truth) simulated with 10 seeds. On the full
   feeder this is expensive, so it is read from the cache ``benchmarks/truth_pilot.py`` writes
   (``--truth-file``), which also holds the truth re-simulated on fresh seeds. Without a truth
   file, the quick feeder's truth (``--truth``) is simulated here.
2. Calibrate against it with each ``--algorithms`` entry (nsga2 = the paper's GA, surrogate,
   random) at the same budget, batch sizes and study seed.
3. Re-simulate each method's first matching set and its recommendation on the fresh seeds and
   compare with the experiment: Wasserstein-1 distance (W1) beside the truth's own W1 on the
   same fresh seeds (the best any parameter set can be expected to do), and the fresh median
   against the target. A set is *validated* when its fresh median is within the tolerance.

Prints, per method: simulations until the first match, until the first validated match (when
the first match or the recommendation validated), the fresh-seed W1 and wall time; writes
everything to ``--out`` (JSON). Embedded path: a temporary SQLite ``SqlStore`` and the local
process pool, as ``demcal calibrate``.

    python -m benchmarks.calibration                       # quick feeder (examples/study-quick.toml)
    NUMBA_NUM_THREADS=1 nice -n 10 python -m benchmarks.calibration --study examples/study.toml \\
        --truth-file benchmarks/full-feeder-truth.json --budget 24 --population 8 --offspring 4 \\
        --E-bounds 1e6,5e7 --fresh 5 --out /tmp/full-feeder-calibration.json

Run it as a module (``python -m``): ``benchmarks/queue.py`` would shadow the standard library's
``queue`` when the script's folder is first on the path.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from scipy.stats import wasserstein_distance

from api.db import create_db_engine, upgrade_database
from api.store import SqlStore
from optimizer.driver import Driver
from optimizer.objectives import evaluate
from optimizer.pareto import summary as pareto_summary
from optimizer.protocols import StudyStatus, TrialSpec
from optimizer.report import build_summary
from optimizer.study import load_study_file
from worker.local import LocalPoolExecutor

ROOT = Path(__file__).resolve().parent.parent
QUICK_TRUTH = {"E": 3.0e6, "nu": 0.3, "e": 0.5, "mu": 0.6}
EXPERIMENT_SEEDS = range(1000, 1010)
FRESH_SEEDS = range(5000, 5010)


def simulate(executor, scenario, params, seeds, label, timeout_s=None):
    specs = [
        TrialSpec(f"{label}-{seed}", label, 0, 0, 0, seed, params, scenario, timeout_s) for seed in seeds
    ]
    executor.submit(specs)
    results = {}
    while len(results) < len(specs):
        for outcome in executor.poll(timeout=1.0):
            results[outcome.trial_id] = outcome.result
    return [results[spec.trial_id] for spec in specs]


def describe(values):
    if not values:
        return "no successful run"
    return (
        f"median {statistics.median(values):g}, mean {statistics.mean(values):.2f}, values {sorted(values)}"
    )


def truth_from_file(path: Path, fresh: int):
    data = json.loads(path.read_text())
    results = data["results"]
    experiment = [results[str(seed)]["n_remaining"] for seed in EXPERIMENT_SEEDS]
    fresh_seeds = [seed for seed in FRESH_SEEDS[:fresh] if str(seed) in results]
    truth_fresh = [results[str(seed)]["n_remaining"] for seed in fresh_seeds]
    return data["truth"], experiment, fresh_seeds, truth_fresh


def validate(executor, scenario, evaluation, seeds, experiment, target, tolerance, label, timeout_s):
    results = simulate(executor, scenario, evaluation["params"], seeds, label, timeout_s)
    values = [r.n_remaining for r in results if r.ok]
    failed = len(results) - len(values)
    w1 = wasserstein_distance(values, experiment) if values else None
    median = statistics.median(values) if values else None
    return {
        "individual": evaluation["individual"],
        "params": evaluation["params"],
        "search_n_remaining": evaluation["n_remaining"],
        "fresh_n_remaining": values,
        "fresh_failed": failed,
        "fresh_median": median,
        "fresh_w1": w1,
        "validated": bool(median is not None and not failed and abs(median - target) <= tolerance + 1e-9),
    }


def first_matching(definition, records):
    """The earliest individual (creation order) whose f1 was within tolerance, as JSON."""
    evaluations = evaluate(records, definition, definition.n_items())
    for evaluation in sorted(evaluations, key=lambda ev: ev.individual):
        if evaluation.matches(definition.experiment.tolerance):
            return pareto_summary(evaluation)
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="examples/study-quick.toml")
    parser.add_argument("--truth-file", default=None, help="Cached truth (benchmarks/truth_pilot.py).")
    parser.add_argument("--truth", default="", help=f"Quick mode: parameters to change in {QUICK_TRUTH}")
    parser.add_argument("--algorithms", default="nsga2,surrogate,random")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--population", type=int, default=8)
    parser.add_argument("--offspring", type=int, default=4)
    parser.add_argument("--budget", type=int, default=20, help="Simulations per method (rounded down).")
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--fresh", type=int, default=10, help="Fresh seeds per validated set.")
    parser.add_argument("--E-bounds", default="", help="'low,high' in Pa (default: the study's).")
    parser.add_argument("--timeout", type=float, default=None, help="Per simulation, wall s.")
    parser.add_argument("--out", default=None, help="Write every figure as JSON here.")
    parser.add_argument(
        "--search-minutes", type=float, default=0.0, help="Stop the searches after this long (0: the budget)."
    )
    args = parser.parse_args()

    base = load_study_file(ROOT / args.study)
    if args.E_bounds:
        low, high = (float(v) for v in args.E_bounds.split(","))
        parameters = base.parameters.model_copy(
            update={"E": base.parameters.E.model_copy(update={"low": low, "high": high})}
        )
        base = base.model_copy(update={"parameters": parameters})
    generations = max(0, (args.budget - args.population) // args.offspring)
    budget = args.population + generations * args.offspring
    executor = LocalPoolExecutor(args.workers)
    report: dict = {"command": vars(args), "budget": budget, "methods": {}}
    try:
        started = time.monotonic()
        if args.truth_file:
            truth, experiment, fresh_seeds, truth_fresh = truth_from_file(ROOT / args.truth_file, args.fresh)
            if len(fresh_seeds) < args.fresh:
                fresh_seeds = list(FRESH_SEEDS[: args.fresh])
                truth_fresh = [
                    r.n_remaining
                    for r in simulate(
                        executor, base.scenario, truth, fresh_seeds, "truth-fresh", args.timeout
                    )
                ]
        else:
            truth = dict(QUICK_TRUTH)
            for item in filter(None, args.truth.split(",")):
                name, _, value = item.partition("=")
                truth[name.strip()] = float(value)
            experiment = [
                r.n_remaining for r in simulate(executor, base.scenario, truth, EXPERIMENT_SEEDS, "truth")
            ]
            fresh_seeds = list(FRESH_SEEDS[: args.fresh])
            truth_fresh = [r.n_remaining for r in simulate(executor, base.scenario, truth, fresh_seeds, "tf")]
        truth_w1 = wasserstein_distance(truth_fresh, experiment)
        report.update(
            truth=truth,
            experiment=experiment,
            fresh_seeds=fresh_seeds,
            truth_fresh=truth_fresh,
            truth_w1=truth_w1,
        )
        print(f"truth {truth}\n  experiment N_t (seeds 1000-1009): {describe(experiment)}", flush=True)
        print(f"  truth on fresh seeds {fresh_seeds}: {describe(truth_fresh)}; W1 {truth_w1:.2f}", flush=True)
        print(f"  ({time.monotonic() - started:.0f} s)", flush=True)

        with tempfile.TemporaryDirectory() as folder:
            url = f"sqlite:///{folder}/bench.db"
            upgrade_database(url)
            store = SqlStore(create_db_engine(url))
            studies = {}
            for algorithm in args.algorithms.split(","):
                definition = base.model_copy(
                    update={
                        "name": f"bench-{algorithm}",
                        "seed": args.seed,
                        "trial_timeout_s": args.timeout,
                        "experiment": base.experiment.model_copy(update={"measured": experiment}),
                        "ga": base.ga.model_copy(
                            update={
                                "algorithm": algorithm,
                                "population": args.population,
                                "offspring": args.offspring,
                                "generations": generations,
                            }
                        ),
                    }
                )
                studies[algorithm] = (
                    definition,
                    store.create_study(definition.model_dump(mode="json"), None),
                )
            # The methods advance together (one driver, round-robin, as the service steps its
            # studies), so that a run cut short by --search-minutes compares them at equal effort.
            driver, clock = Driver(store, executor), time.monotonic()
            stop_at = clock + 60.0 * args.search_minutes if args.search_minutes else float("inf")
            active = dict(studies)
            while active and time.monotonic() < stop_at:
                for algorithm, (_definition, study_id) in list(active.items()):
                    progress = driver.step(study_id, timeout=0.2)
                    if progress.recorded:
                        print(
                            f"  [{time.monotonic() - clock:5.0f} s] {algorithm}: {progress.trials_done} of "
                            f"{progress.trials_planned} done, best f1 {progress.best_f1}",
                            flush=True,
                        )
                    if not progress.active:
                        del active[algorithm]
            for _definition, study_id in active.values():
                store.set_status(study_id, StudyStatus.CANCELLED, "benchmark search time over")
                driver.step(study_id, timeout=0)  # withdraws its trials in flight
            search_wall = time.monotonic() - clock
            report["search_wall_s"] = search_wall
            print(f"searches: {search_wall:.0f} s wall; unfinished: {sorted(active) or 'none'}", flush=True)

            for algorithm, (definition, study_id) in studies.items():
                clock = time.monotonic()
                target, tolerance = definition.experiment.target(), definition.experiment.tolerance
                records = store.trials(study_id)
                summary = build_summary(store.load_study(study_id), records)
                done = [r for r in records if r.result is not None]
                row = {
                    "simulations": summary["simulations"],
                    "failed": sum(g["failed"] for g in summary["generations"]),
                    "finished": algorithm not in active,
                    "first_match": summary["simulations_until_first_match"],
                    "best_f1": summary["best_f1"],
                    "simulation_wall_s": sum(r.result.wall_time_s for r in done),
                    "identifiability": summary.get("identifiability"),
                    "generations": summary["generations"],
                    "validated": [],
                }
                print(
                    f"\n[{algorithm}] {row['simulations']} simulations ({row['failed']} failed, "
                    f"{row['simulation_wall_s']:.0f} s of simulation wall); first match after "
                    f"{row['first_match']}; best f1 {row['best_f1']}",
                    flush=True,
                )
                candidates = []
                first = first_matching(definition, records)
                if first is not None:
                    candidates.append(("first match", first))
                if summary["recommendation"] and (
                    first is None or summary["recommendation"]["individual"] != first["individual"]
                ):
                    candidates.append(("recommendation", summary["recommendation"]))
                for role, evaluation in candidates:
                    checked = validate(
                        executor,
                        base.scenario,
                        evaluation,
                        fresh_seeds,
                        experiment,
                        target,
                        tolerance,
                        f"{algorithm}-{evaluation['individual']}",
                        args.timeout,
                    )
                    checked["role"] = role
                    checked["simulations_until_found"] = (
                        evaluation["individual"] + 1
                    ) * definition.replicates
                    row["validated"].append(checked)
                    params = ", ".join(f"{k}={v:.3g}" for k, v in evaluation["params"].items())
                    w1 = "-" if checked["fresh_w1"] is None else f"{checked['fresh_w1']:.2f}"
                    verdict = "validated" if checked["validated"] else "not reproduced"
                    print(
                        f"  {role}: individual {evaluation['individual']} ({params}), search N_t "
                        f"{evaluation['n_remaining']}; fresh {describe(checked['fresh_n_remaining'])}, "
                        f"W1 {w1} (truth {truth_w1:.2f}); {verdict}",
                        flush=True,
                    )
                found = [c["simulations_until_found"] for c in row["validated"] if c["validated"]]
                row["first_validated_match"] = min(found) if found else None
                row["validation_wall_s"] = time.monotonic() - clock
                report["methods"][algorithm] = row
                print(
                    f"  first validated match after {row['first_validated_match']} simulations; "
                    f"validation {row['validation_wall_s']:.0f} s wall",
                    flush=True,
                )
                if args.out:
                    Path(args.out).write_text(json.dumps(report, indent=1, default=str))
    finally:
        executor.close()

    print(f"\nbudget {budget} simulations per method; target N_t = {target:g} +- {tolerance:g}")
    print(f"searches {report['search_wall_s']:.0f} s wall together (interleaved)")
    print("| method | sims | to first match | to first validated match | fresh W1 (truth's) | sim wall, s |")
    for algorithm, row in report["methods"].items():
        w1 = [f"{c['fresh_w1']:.2f}" for c in row["validated"] if c["fresh_w1"] is not None]
        print(
            f"| {algorithm} | {row['simulations']} | {row['first_match']} | {row['first_validated_match']} | "
            f"{', '.join(w1) or '-'} ({truth_w1:.2f}) | {row['simulation_wall_s']:.0f} |"
        )
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1, default=str))


if __name__ == "__main__":
    main()
