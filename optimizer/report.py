"""A study's results for people: ``trials.csv``, ``summary.json`` and ``pareto.png``.

The summary carries what an engineer reads first: the recommendation and its equivalent sets,
the Pareto front, the paper's Fig. 5 as numbers (median and spread of N_t and of f2 per
generation), and how many simulations it took until a parameter set first matched the experiment.

Computed from a study's record and trials only (what any Store returns); it must not run or
change anything. matplotlib is imported inside :func:`write_pareto_png` (Agg backend), so
importing this module stays cheap.
"""

from __future__ import annotations

import csv
import json
import statistics
from pathlib import Path
from typing import Any

from optimizer.objectives import Evaluation, evaluate
from optimizer.pareto import rank, summary
from optimizer.protocols import PARAMETER_NAMES, StudyRecord, TrialRecord
from optimizer.space import ParameterSpace
from optimizer.study import StudyDefinition

CSV_COLUMNS = (
    "trial_id",
    "individual",
    "generation",
    "replicate",
    "seed",
    *PARAMETER_NAMES,
    "state",
    "status",
    "n_remaining",
    "n_items",
    "wall_time_s",
    "cost",
    "steps",
    "dt",
    "f1",
    "f2",
    "pareto",
    "worker",
    "message",
)


def first_match(evaluations: list[Evaluation], tolerance: float, replicates: int) -> int | None:
    """Simulations run until an individual first matched, counting individuals in creation order."""
    for evaluation in sorted(evaluations, key=lambda ev: ev.individual):
        if evaluation.matches(tolerance):
            return (evaluation.individual + 1) * replicates
    return None


def _spread(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def build_summary(study: StudyRecord, records: list[TrialRecord]) -> dict[str, Any]:
    definition = StudyDefinition.model_validate(study.definition)
    experiment = definition.experiment
    space = ParameterSpace(definition.parameters)
    evaluations = evaluate(records, definition, definition.n_items())
    ranking = rank(evaluations, experiment.tolerance, space)
    generations = []
    for generation in sorted({evaluation.generation for evaluation in evaluations}):
        members = [ev for ev in evaluations if ev.generation == generation and ev.ok]
        generations.append(
            {
                "generation": generation,
                "individuals": sum(ev.generation == generation for ev in evaluations),
                "failed": sum(ev.generation == generation and not ev.ok for ev in evaluations),
                "n_remaining": _spread([n for ev in members for n in ev.n_remaining]),
                "f2": _spread([ev.f2 for ev in members]),
            }
        )
    return {
        "study_id": study.study_id,
        "name": definition.name,
        "status": study.status.value,
        "message": study.message,
        "target": experiment.target(),
        "tolerance": experiment.tolerance,
        "measured": experiment.measured,
        "objective_time": definition.objective_time,
        "algorithm": definition.ga.algorithm,
        "simulations": sum(record.result is not None for record in records),
        "simulations_planned": definition.total_simulations(),
        "simulations_until_first_match": first_match(
            evaluations, experiment.tolerance, definition.replicates
        ),
        "best_f1": ranking.best_f1,
        "recommendation": summary(ranking.recommendation) if ranking.recommendation else None,
        "equivalent": [summary(evaluation) for evaluation in ranking.equivalent],
        "pareto": [summary(evaluation) for evaluation in ranking.pareto],
        "generations": generations,
    }


def write_trials_csv(path: Path, definition: StudyDefinition, records: list[TrialRecord]) -> None:
    evaluations = evaluate(records, definition, definition.n_items())
    objectives = {tid: evaluation for evaluation in evaluations for tid in evaluation.trial_ids}
    space = ParameterSpace(definition.parameters)
    pareto = {
        tid
        for evaluation in rank(evaluations, definition.experiment.tolerance, space).pareto
        for tid in evaluation.trial_ids
    }
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for record in sorted(records, key=lambda r: (r.spec.individual, r.spec.replicate)):
            spec, result = record.spec, record.result
            evaluation = objectives.get(spec.trial_id)
            row = {
                "trial_id": spec.trial_id,
                "individual": spec.individual,
                "generation": spec.generation,
                "replicate": spec.replicate,
                "seed": spec.seed,
                **{name: spec.params.get(name) for name in PARAMETER_NAMES},
                "state": record.state.value,
                "f1": evaluation.f1 if evaluation else None,
                "f2": evaluation.f2 if evaluation else None,
                "pareto": spec.trial_id in pareto,
                "worker": record.worker,
            }
            if result is not None:
                row.update(
                    status=result.status.value,
                    n_remaining=result.n_remaining,
                    n_items=result.n_items,
                    wall_time_s=result.wall_time_s,
                    cost=result.cost,
                    steps=result.steps,
                    dt=result.dt,
                    message=result.message,
                )
            writer.writerow(row)


def write_pareto_png(
    path: Path, summary_json: dict[str, Any], evaluations: list[Evaluation], records: list[TrialRecord]
) -> None:
    """Left: every individual in (f2, f1) with the front and the recommendation; right: N_t per
    generation against the target (the paper's Fig. 5a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.5))
    if evaluations:
        points = left.scatter(
            [ev.f2 for ev in evaluations],
            [ev.f1 for ev in evaluations],
            c=[ev.generation for ev in evaluations],
            cmap="viridis",
            s=18,
        )
        fig.colorbar(points, ax=left, label="generation")
        if min(ev.f2 for ev in evaluations) > 0:
            left.set_xscale("log")
    front = summary_json["pareto"]
    if front:
        left.plot([ev["f2"] for ev in front], [ev["f1"] for ev in front], "k-", lw=1, label="Pareto front")
    left.axhline(summary_json["tolerance"], color="tab:red", ls="--", lw=1, label="tolerance")
    chosen = summary_json["recommendation"]
    if chosen:
        left.scatter([chosen["f2"]], [chosen["f1"]], marker="*", s=250, color="tab:red", label="recommended")
    left.set_xlabel("f2: " + ("cost" if summary_json["objective_time"] == "cost" else "wall time T, s"))
    left.set_ylabel("f1: |N_t - target|")
    left.legend(loc="upper right", fontsize=8)

    by_generation: dict[int, list[int]] = {}
    for record in records:
        if record.result is not None and record.result.n_remaining is not None:
            by_generation.setdefault(record.spec.generation, []).append(record.result.n_remaining)
    generations = sorted(by_generation)
    if generations:
        right.boxplot([by_generation[g] for g in generations], positions=generations)
    right.axhline(summary_json["target"], color="tab:red", ls="--", lw=1, label="target")
    right.set_xlabel("generation")
    right.set_ylabel("simulated N_t")
    right.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{summary_json['name']} ({summary_json['study_id']})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_results(directory: Path, study: StudyRecord, records: list[TrialRecord]) -> dict[str, Any]:
    """Write the three files into ``directory``; returns the summary."""
    directory.mkdir(parents=True, exist_ok=True)
    definition = StudyDefinition.model_validate(study.definition)
    summary_json = build_summary(study, records)
    (directory / "summary.json").write_text(json.dumps(summary_json, indent=2))
    write_trials_csv(directory / "trials.csv", definition, records)
    evaluations = evaluate(records, definition, definition.n_items())
    write_pareto_png(directory / "pareto.png", summary_json, evaluations, records)
    return summary_json
