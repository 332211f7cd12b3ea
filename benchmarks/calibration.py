"""Synthetic-truth calibration benchmark: can a search find parameters we hid, how many
simulations does it need, and does its recommendation reproduce the experiment on fresh seeds?

1. A synthetic experiment: hidden parameters (the truth) simulated with 10 seeds. On the full
   feeder this is expensive, so it is read from the cache ``benchmarks/truth_pilot.py`` writes
   (``--truth-file``), which also holds the truth re-simulated on fresh seeds. Without a truth
   file, the quick feeder's truth (``--truth``) is simulated here.
2. Calibrate against it with each ``--algorithms`` entry in turn (surrogate, then nsga2 = the
   paper's GA, then random) at the same budget, batch sizes and study seed; the studies' own
   end-of-study validation is off (``validation.seeds = 0``), so the budget is all search.
3. Re-simulate each method's first matching set and its recommendation on the fresh seeds and
   judge them with the studies' own rule (``optimizer/validation.py``: a permutation test at
   level 0.1), with the Wasserstein-1 distance (W1) beside the truth's own W1
   on the same fresh seeds (the best any parameter set can be expected to do).

Prints, per method: simulations until the first match and until the first validated match
(``optimizer.report.first_match``: runs in creation order, extra replicates included), the
fresh-seed W1 and wall time. Resumable: the studies live in a SQLite file (``--db``, default
beside ``--out``) and every figure is written to ``--out`` (JSON) as it comes, so a run stopped
by ``--search-minutes`` or a kill leaves partial figures, and the same command continues it.

    python -m benchmarks.calibration                       # quick feeder (examples/study-quick.toml)
    NUMBA_NUM_THREADS=1 nice -n 10 python -m benchmarks.calibration --study examples/study.toml \\
        --truth-file benchmarks/full-feeder-truth.json --budget 60 --population 10 --offspring 5 \\
        --E-bounds 3e6,3e8 --fresh 5 --out /tmp/full-feeder-calibration.json --search-minutes 40

Run it as a module (``python -m``): ``benchmarks/queue.py`` would shadow the standard library's
``queue`` when the script's folder is first on the path.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from scipy.stats import wasserstein_distance

from api.db import create_db_engine, upgrade_database
from api.store import SqlStore
from optimizer.driver import Driver
from optimizer.objectives import evaluate
from optimizer.protocols import StudyStatus, TrialRecord, TrialSpec, TrialState
from optimizer.report import build_summary, first_match
from optimizer.study import load_study_file
from optimizer.validation import VALIDATED, check
from worker.local import LocalPoolExecutor

ROOT = Path(__file__).resolve().parent.parent
QUICK_TRUTH = {"E": 3.0e6, "nu": 0.3, "e": 0.5, "mu": 0.6}
EXPERIMENT_SEEDS = range(1000, 1010)
FRESH_SEEDS = range(5000, 5010)


def simulate(executor, scenario, params, seeds, label, timeout_s=None):
    """``scenario`` is a study's validated config; trials carry it as JSON."""
    data = scenario.model_dump(mode="json")
    specs = [TrialSpec(f"{label}-{seed}", label, 0, 0, 0, seed, params, data, timeout_s) for seed in seeds]
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


def validate(executor, definition, evaluation, seeds, label, timeout_s):
    """The evaluation's fresh-seed runs judged by the studies' own rule, as JSON."""
    specs = [
        TrialSpec(
            f"{label}-{seed}",
            label,
            evaluation.individual,
            10**6,
            r,
            seed,
            evaluation.params,
            definition.scenario.model_dump(mode="json"),
            timeout_s,
        )
        for r, seed in enumerate(seeds)
    ]
    results = simulate(executor, definition.scenario, evaluation.params, seeds, label, timeout_s)
    fresh = [TrialRecord(spec, TrialState.DONE, result) for spec, result in zip(specs, results, strict=True)]
    row = check(evaluation, fresh, definition)
    row["validated"] = row["verdict"] == VALIDATED
    return row


def first_matching(definition, records):
    """The earliest individual (creation order) whose f1 was within tolerance."""
    evaluations = evaluate(records, definition, definition.n_items())
    for evaluation in sorted(evaluations, key=lambda ev: ev.individual):
        if evaluation.matches(definition.match_tolerance()):
            return evaluation
    return None


def own_w1(report: dict) -> float | None:
    """The truth's own W1 (fresh seeds against the experiment), once every fresh seed ran."""
    if len(report["truth_fresh"]) < len(report["fresh_seeds"]) or not report["truth_fresh"]:
        return None
    report["truth_w1"] = round(float(wasserstein_distance(report["truth_fresh"], report["experiment"])), 3)
    return report["truth_w1"]


def save(path: Path | None, report: dict) -> None:
    if path is not None:
        path.write_text(json.dumps(report, indent=1, default=str))


def medians_per_generation(generations: list[dict]) -> str:
    """The median N_t of each batch's measured runs, the paper's Fig. 5 as one line:
    ``g0 0 (10 ok), g1 1 (5 ok), ...`` (``-`` for a batch without a measured run)."""
    parts = []
    for entry in generations:
        median = "-" if entry["n_remaining"] is None else f"{entry['n_remaining']['median']:g}"
        parts.append(f"g{entry['generation']} {median} ({entry['simulations'] - entry['failed']} ok)")
    return ", ".join(parts)


def search_row(store, study_id: str, finished: bool) -> dict:
    records = store.trials(study_id)
    summary = build_summary(store.load_study(study_id), records)
    done = [r for r in records if r.result is not None]
    return {
        "study_id": study_id,
        "simulations": summary["simulations"],
        "failed": summary["failures"]["total"],
        "failures": summary["failures"]["text"],
        "finished": finished,
        "first_match": summary["simulations_until_first_match"],
        "best_f1": summary["best_f1"],
        "simulation_wall_s": sum(r.result.wall_time_s for r in done),
        "identifiability": summary.get("identifiability"),
        "generations": summary["generations"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="examples/study-quick.toml")
    parser.add_argument("--truth-file", default=None, help="Cached truth (benchmarks/truth_pilot.py).")
    parser.add_argument("--truth", default="", help=f"Quick mode: parameters to change in {QUICK_TRUTH}")
    parser.add_argument("--algorithms", default="surrogate,nsga2,random")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--population", type=int, default=8)
    parser.add_argument("--offspring", type=int, default=4)
    parser.add_argument(
        "--budget",
        type=int,
        default=20,
        help="Individuals per method (rounded down); x replicates = simulations.",
    )
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--fresh", type=int, default=10, help="Fresh seeds per validated set.")
    parser.add_argument("--E-bounds", default="", help="'low,high' in Pa (default: the study's).")
    parser.add_argument("--timeout", type=float, default=None, help="Per simulation, wall s.")
    parser.add_argument("--out", default=None, help="Write every figure as JSON here (and resume from it).")
    parser.add_argument("--db", default=None, help="The studies' SQLite file (default: --out with .db).")
    parser.add_argument(
        "--search-minutes", type=float, default=0.0, help="Stop searching after this long (0: the budget)."
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
    out = Path(args.out) if args.out else None
    report: dict = json.loads(out.read_text()) if out is not None and out.exists() else {}
    report.update(command=vars(args), budget=budget)
    report.setdefault("methods", {})
    db = Path(args.db) if args.db else (out.with_suffix(".db") if out else Path("/tmp/demcal-calibration.db"))
    executor = LocalPoolExecutor(args.workers)
    try:
        started = time.monotonic()
        if args.truth_file:
            truth, experiment, fresh_seeds, truth_fresh = truth_from_file(ROOT / args.truth_file, args.fresh)
            fresh_seeds = list(FRESH_SEEDS[: args.fresh])
            truth_fresh = report.get("truth_fresh") or truth_fresh  # missing ones: run after the searches
        elif "experiment" in report:
            truth, experiment = report["truth"], report["experiment"]
            fresh_seeds, truth_fresh = report["fresh_seeds"], report["truth_fresh"]
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
        report.update(truth=truth, experiment=experiment, fresh_seeds=fresh_seeds, truth_fresh=truth_fresh)
        truth_w1 = own_w1(report)
        save(out, report)
        print(f"truth {truth}\n  experiment N_t (seeds 1000-1009): {describe(experiment)}", flush=True)
        if truth_w1 is not None:
            print(
                f"  truth on fresh seeds {fresh_seeds}: {describe(truth_fresh)}; W1 {truth_w1:.2f}",
                flush=True,
            )
        print(f"  ({time.monotonic() - started:.0f} s)", flush=True)

        url = f"sqlite:///{db}"
        upgrade_database(url)
        store = SqlStore(create_db_engine(url))
        driver = Driver(store, executor)
        stop_at = time.monotonic() + 60.0 * args.search_minutes if args.search_minutes else float("inf")
        for algorithm in args.algorithms.split(","):
            row = report["methods"].setdefault(algorithm, {})
            definition = base.model_copy(
                update={
                    "name": f"bench-{algorithm}",
                    "seed": args.seed,
                    "trial_timeout_s": args.timeout,
                    "experiments": [base.experiment.model_copy(update={"measured": experiment})],
                    "validation": base.validation.model_copy(update={"seeds": 0}),
                    "budget": None,
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
            definition = type(definition).model_validate(definition.model_dump(mode="json"))
            if "study_id" not in row:
                row["study_id"] = store.create_study(definition.model_dump(mode="json"), None)
            study_id, clock = row["study_id"], time.monotonic()
            active = store.load_study(study_id).status is StudyStatus.RUNNING or not row.get("finished")
            while active and time.monotonic() < stop_at:
                progress = driver.step(study_id, timeout=0.5)
                if progress.recorded:
                    row.update(search_row(store, study_id, finished=False))
                    row["search_wall_s"] = row.get("search_wall_s", 0.0) + time.monotonic() - clock
                    clock = time.monotonic()
                    save(out, report)
                    print(
                        f"  [{row['search_wall_s']:5.0f} s] {algorithm}: {progress.trials_done} of "
                        f"{progress.trials_planned} done, first match after {row['first_match']}, "
                        f"best f1 {progress.best_f1}",
                        flush=True,
                    )
                active = progress.active
            row.update(search_row(store, study_id, finished=not active))
            save(out, report)
            print(
                f"\n[{algorithm}] {row['simulations']} simulations ({row['failures']}, "
                f"{row['simulation_wall_s']:.0f} s of simulation wall); first match after "
                f"{row['first_match']}; best f1 {row['best_f1']}"
                f"{'' if row['finished'] else ' (search unfinished: time over)'}",
                flush=True,
            )
            print(f"  median N_t per generation: {medians_per_generation(row['generations'])}", flush=True)
            if active:  # time is over: the next run of the same command continues this study
                executor.cancel(sorted(executor.in_flight()))

            records = store.trials(study_id)
            evaluations = evaluate(records, definition, definition.n_items())
            recommendation = (store.load_study(study_id).recommendation or {}).get("individual")
            candidates = []
            first = first_matching(definition, records)
            if first is not None:
                candidates.append(("first match", first))
            chosen = next((ev for ev in evaluations if ev.individual == recommendation), None)
            if not active and chosen is not None and (first is None or chosen.individual != first.individual):
                candidates.append(("recommendation", chosen))
            checked_rows = row.setdefault("validated", [])
            for role, evaluation in candidates:
                if any(c["individual"] == evaluation.individual for c in checked_rows):
                    continue
                clock = time.monotonic()
                checked = validate(
                    executor,
                    definition,
                    evaluation,
                    fresh_seeds,
                    f"{algorithm}-{evaluation.individual}",
                    args.timeout,
                )
                checked.update(
                    role=role,
                    simulations_until_found=first_match(records, definition, among={evaluation.individual}),
                    validation_wall_s=time.monotonic() - clock,
                )
                checked_rows.append(checked)
                save(out, report)
                params = ", ".join(f"{k}={v:.3g}" for k, v in evaluation.params.items())
                w1 = "-" if checked["w1"] is None else f"{checked['w1']:.2f}"
                print(
                    f"  {role}: individual {evaluation.individual} ({params}), search N_t "
                    f"{evaluation.n_remaining}; fresh {describe(checked['n_remaining'])}, "
                    f"W1 {w1} (truth {truth_w1}); {checked['verdict']}",
                    flush=True,
                )
            found = [c["simulations_until_found"] for c in checked_rows if c["validated"]]
            row["first_validated_match"] = min(found) if found else None
            save(out, report)
            if active:
                break  # the recommendation is not final: validated when the search ends
        if args.truth_file and len(report["truth_fresh"]) < len(fresh_seeds):
            # The truth pilot may have run the missing fresh seeds while the searches ran.
            report["truth_fresh"] = truth_from_file(ROOT / args.truth_file, args.fresh)[3]
            truth_w1 = own_w1(report)
        if len(report["truth_fresh"]) < len(fresh_seeds):
            # The truth's own W1, the yardstick of the table (the truth on the same fresh seeds).
            runs = simulate(executor, base.scenario, truth, fresh_seeds, "truth-fresh", args.timeout)
            report["truth_fresh"] = [r.n_remaining for r in runs if r.ok]
            truth_w1 = own_w1(report)
            save(out, report)
            print(f"truth on fresh seeds {fresh_seeds}: {describe(report['truth_fresh'])}; W1 {truth_w1}")
    finally:
        executor.close()

    print(
        f"\nbudget {budget} individuals per method (x replicates, + extra replicates); "
        f"experiment {describe(experiment)}"
    )
    print("| method | sims | to first match | to first validated match | fresh W1 (truth's) | sim wall, s |")
    for algorithm, row in report["methods"].items():
        if "simulations" not in row:
            continue
        w1 = [f"{c['w1']:.2f}" for c in row.get("validated", []) if c["w1"] is not None]
        print(
            f"| {algorithm} | {row['simulations']}{'' if row['finished'] else ' (unfinished)'} | "
            f"{row['first_match']} | {row.get('first_validated_match')} | "
            f"{', '.join(w1) or '-'} ({truth_w1}) | {row['simulation_wall_s']:.0f} |"
        )
    save(out, report)


if __name__ == "__main__":
    main()
