"""A study's results for people: ``trials.csv``, ``summary.json`` and ``pareto.png``.

The summary carries what an engineer reads first: the recommendation and its equivalent sets,
the Pareto front, the paper's Fig. 5 as numbers (``optimizer/generations.py``, the same summary
the API serves, plus the spread of f2 per generation), how many simulations it took until a
parameter set first matched the experiment, and the runs that measured nothing, counted by
status (``optimizer/outcomes.py``): they never appear as an N_t value, in the CSV, the summary or
the pictures, and every view counts them the same way.
It also carries the progress against simulations (hypervolume and best f1 per batch,
``optimizer/progress.py``) and which parameters the experiment pins down
(``optimizer/identifiability.py``).

Computed from a study's record and trials only (what any Store returns); it must not run or
change anything. matplotlib is imported inside :func:`write_pareto_png` (Agg backend), so
importing this module stays cheap.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dem.parameters import ALL_PARAMETER_NAMES, PARAMETER_NAMES
from optimizer.generations import Run, per_generation, spread
from optimizer.identifiability import study_identifiability
from optimizer.objectives import Evaluation, evaluate, f1_rule
from optimizer.outcomes import (
    count_failures,
    failure_status,
    individual_failures,
    measured_n,
    shown_objectives,
)
from optimizer.pareto import rank, summary
from optimizer.progress import study_progress
from optimizer.protocols import StudyRecord, TrialRecord
from optimizer.space import ParameterSpace
from optimizer.study import StudyDefinition


def response_column(response) -> str:
    """A response's CSV header: its name and unit, 'angle_deg [deg]' (a count has no unit)."""
    return response.name if response.unit == "1" else f"{response.name} [{response.unit}]"


def study_parameter_names(definition: dict[str, Any]) -> list[str]:
    """The parameters a stored study's trials carry, read from its definition as stored (no
    validation, so a definition this version no longer accepts still shows): the items' four, and
    the item-wall ones it names (``optimizer.study.Parameters.names``)."""
    named = definition.get("parameters") or {}
    return [name for name in ALL_PARAMETER_NAMES if name in PARAMETER_NAMES or named.get(name) is not None]


def trial_csv_columns(parameters: Sequence[str], responses: Sequence[str]) -> list[str]:
    """The one list of a trial's CSV columns, for calibrate's ``trials.csv`` and the API's
    ``export.csv`` alike: the study's parameters (``Parameters.names()``) and one column per
    response of its scenario (``response_column``) in their places."""
    return [
        "trial_id", "generation", "individual", "replicate", "seed", *parameters, "engine", "state",
        "status", *responses, "wall_time_s", "cost", "dt", "f1", "f2", "failure", "pareto", "worker",
        "attempts", "message",
    ]  # fmt: skip


def first_match(
    records: list[TrialRecord], definition: StudyDefinition, among: set[int] | None = None
) -> int | None:
    """Simulations run until a set (of ``among``, default any) first matched the experiment, or None.

    Runs are counted in the order the driver creates them: batch by batch, and within a batch by
    individual and replicate. A set counts as matching on the runs it had at that point, so the
    extra replicates of earlier batches are part of the count, and a set whose match needed its
    extra replicates matches only once they ran (not at its first batch, on runs it did not
    have yet). Validation runs never count: they come after the search.
    """
    validation = definition.validation_batch()
    runs = sorted(
        (r for r in records if r.result is not None and r.spec.generation < validation),
        key=lambda r: (r.spec.generation, r.spec.individual, r.spec.replicate),
    )
    tolerance, n_items = definition.match_tolerance(), definition.n_items()
    unfinished = {  # sets whose first runs are still out: not evaluated yet, as in evaluate()
        r.spec.individual for r in records if r.result is None and r.spec.replicate < definition.replicates
    }
    so_far: dict[int, list[TrialRecord]] = {}
    for count, record in enumerate(runs, start=1):
        so_far.setdefault(record.spec.individual, []).append(record)
        following = runs[count] if count < len(runs) else None
        if following is not None and (following.spec.generation, following.spec.individual) == (
            record.spec.generation,
            record.spec.individual,
        ):
            continue  # the set's runs of this batch are not all counted yet
        individual = record.spec.individual
        if individual in unfinished or (among is not None and individual not in among):
            continue
        evaluation = evaluate(so_far[record.spec.individual], definition, n_items)
        if evaluation and evaluation[0].matches(tolerance):
            return count
    return None


def _measured(record: TrialRecord, response: str = "n_remaining") -> float | None:
    """A run's value of ``response``, only if it measured (ended ok)."""
    result = record.result
    if result is None:
        return None
    return measured_n(result.status.value, result.responses.get(response))


def failures_json(records: list[TrialRecord]) -> dict[str, Any]:
    """Runs that measured nothing: counts by status, the sentence views print, and per status the
    first run's message (what an engineer reads to decide what to change)."""
    finished = sorted(
        (record for record in records if record.result is not None),
        key=lambda record: (record.spec.individual, record.spec.replicate),
    )
    counts = count_failures(record.result.status.value for record in finished)
    first_message: dict[str, str] = {}
    for record in finished:
        first_message.setdefault(record.result.status.value, record.result.message)
    return {
        **counts.as_json(),
        "text": counts.text(),
        "first_message": {status: first_message[status] for status in counts.by_status},
    }


def build_summary(study: StudyRecord, records: list[TrialRecord]) -> dict[str, Any]:
    definition = StudyDefinition.model_validate(study.definition)
    experiment = definition.experiment
    space = ParameterSpace(definition.parameters)
    evaluations = evaluate(records, definition, definition.n_items())
    ranking = rank(evaluations, definition.match_tolerance(), space, min_replicates=definition.max_replicates)
    # Every batch with runs, so that the failed runs per batch add up to the study's count (extra
    # replicates and a validation are batches without new individuals).
    generations = [
        {
            **entry,
            "individuals": sum(ev.generation == entry["generation"] for ev in evaluations),
            "simulations": entry["done"],
            "f2": spread(ev.f2 for ev in evaluations if ev.generation == entry["generation"] and ev.ok),
        }
        for entry in per_generation(
            (Run.of(record) for record in records if record.result is not None),
            definition.measured_by_response(),
        )
    ]
    stored = study.recommendation or {}  # the driver's, once it stored one
    return {
        "study_id": study.study_id,
        "name": definition.name,
        "status": study.status.value,
        "message": study.message,
        "response": experiment.response,
        "responses_measured": _measured_text(definition),
        "target": experiment.target(),
        "tolerance": definition.match_tolerance(),
        "f1_rule": f1_rule(definition),
        "measured": experiment.measured,
        "objective_time": definition.objective_time,
        "algorithm": definition.ga.algorithm,
        "simulations": sum(record.result is not None for record in records),
        "simulations_planned": definition.total_simulations(),
        "simulations_until_first_match": first_match(records, definition),
        "best_f1": ranking.best_f1,
        "failures": failures_json(records),
        # The stored recommendation is the driver's: after the validation, the fastest validated set
        # (``chosen_by`` says how it was chosen).
        "recommendation": study.recommendation
        or (summary(ranking.recommendation) if ranking.recommendation else None),
        "validation_status": stored.get("validation_status"),
        "chosen_by": stored.get("chosen_by"),
        "validation": stored.get("validation", []),
        # The recommendation's own list once the driver stored one (even empty: the ranking's could
        # hold the validated pick): after the validation it holds the search's other matches *and*
        # its fastest match when a validated set was chosen over it.
        "equivalent": stored["equivalent"]
        if "equivalent" in stored
        else [summary(evaluation) for evaluation in ranking.equivalent],
        "pareto": [summary(evaluation) for evaluation in ranking.pareto],
        "generations": generations,
        "progress": study_progress(
            records, definition, study.generation, stored.get("validation", [])
        ).as_json(),
        "identifiability": study_identifiability(evaluations, definition, space),
    }


def _measured_text(definition: StudyDefinition) -> str:
    """What a successful run measured, as views name it: 'N_t', 'angle of repose', 'every response'."""
    if len(definition.experiments) > 1:
        return "every response"
    declared = definition.declared_responses().get(definition.experiment.response)
    return (declared.label or declared.name) if declared else definition.experiment.response


def write_trials_csv(path: Path, definition: StudyDefinition, records: list[TrialRecord]) -> None:
    evaluations = evaluate(records, definition, definition.n_items())
    objectives = shown_objectives(evaluations)
    failures = individual_failures(
        (r.spec.individual, r.spec.replicate, r.result.status.value) for r in records if r.result
    )
    space = ParameterSpace(definition.parameters)
    pareto = {
        tid
        for evaluation in rank(evaluations, definition.match_tolerance(), space).pareto
        for tid in evaluation.trial_ids
    }
    declared = list(definition.declared_responses().values())
    columns = trial_csv_columns(definition.parameters.names(), [response_column(r) for r in declared])
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        for record in sorted(records, key=lambda r: (r.spec.individual, r.spec.replicate)):
            spec, result = record.spec, record.result
            f1, f2 = objectives.get(spec.trial_id, (None, None))
            # Only runs that measured: a failed run's responses are not measurements.
            measured = result.responses if result is not None and result.status.value == "ok" else {}
            row = {
                "trial_id": spec.trial_id,
                "generation": spec.generation,
                "individual": spec.individual,
                "replicate": spec.replicate,
                "seed": spec.seed,
                **{name: spec.params.get(name) for name in definition.parameters.names()},
                "engine": spec.engine,
                "state": record.state.value,
                **{response_column(r): measured.get(r.name) for r in declared},
                "f1": f1,
                "f2": f2,
                "failure": failures.get(spec.individual, ""),
                "pareto": spec.trial_id in pareto,
                "worker": record.worker,
                "attempts": record.attempts,
            }
            if result is not None:
                row.update(
                    status=result.status.value,
                    wall_time_s=result.wall_time_s,
                    cost=result.cost,
                    dt=result.dt,
                    message=result.message,
                )
            writer.writerow(row)


# Marker and colour per failed status (Okabe-Ito colours); a status not listed gets the fallback.
FAILURE_STYLE = {
    "invalid": ("^", "#cc79a7"),
    "unstable": ("X", "#d55e00"),
    "timeout": ("s", "#e69f00"),
    "error": ("D", "#000000"),
    "cancelled": ("o", "#999999"),
}
FAILURE_FALLBACK = ("P", "#56b4e9")


def _failure_style(status: str) -> tuple[str, str]:
    return FAILURE_STYLE.get(status, FAILURE_FALLBACK)


def write_pareto_png(
    path: Path,
    summary_json: dict[str, Any],
    evaluations: list[Evaluation],
    records: list[TrialRecord],
    last_generation: int | None = None,
) -> None:
    """Left: every measured individual in (f2, f1) with the front and the recommendation; right:
    measured N_t per generation against the target (the paper's Fig. 5a). Above each, in a strip
    of its own, what measured nothing: failed individuals at their real f2, marked by status, and
    failed runs per generation stacked by status."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(
        2, 2, figsize=(11, 5.6), sharex="col", gridspec_kw={"height_ratios": [1, 4], "hspace": 0.08}
    )
    (left_failed, right_failed), (left, right) = axes
    wall = summary_json["objective_time"] == "wall"
    measured = [ev for ev in evaluations if ev.ok]
    failed = [ev for ev in evaluations if not ev.ok]
    if measured:
        points = left.scatter(
            [ev.f2 for ev in measured],
            [ev.f1 for ev in measured],
            c=[ev.generation for ev in measured],
            cmap="viridis",
            s=18,
        )
        bar = fig.colorbar(points, ax=[left_failed, left], label="generation")
        bar.locator = MaxNLocator(integer=True)  # generations are whole numbers
        bar.update_ticks()
    def real_f2(ev: Evaluation) -> float:
        return ev.wall_time_s if wall else ev.cost

    # The axis spans the measured sets: a run that failed early (an invalid insertion) costs
    # 1e-4 of a full run, and on an axis reaching down to it the measured points were squeezed
    # into a sliver. Failed runs below the span are drawn at its left edge and counted.
    spanned = [real_f2(ev) for ev in (measured or evaluations)]
    # Log only where f2 spans a decade or more: on a narrower span matplotlib labels minor ticks,
    # which overlap into an unreadable axis.
    log_axis = bool(spanned) and min(spanned) > 0 and max(spanned) >= 10 * min(spanned)
    left_edge = None
    if log_axis:
        left.set_xscale("log")
        left_edge, right_edge = min(spanned) / 1.5, max(spanned) * 1.5
        left.set_xlim(left_edge, right_edge)
    front = [member for member in summary_json["pareto"] if not member.get("failure")]
    if front:
        # The attained front is a staircase (nothing is known between members), as on the dashboard.
        front = sorted(front, key=lambda ev: ev["f2"])
        left.plot([ev["f2"] for ev in front], [ev["f1"] for ev in front], "k-", lw=1, drawstyle="steps-post",
                  label="Pareto front")
    left.axhline(summary_json["tolerance"], color="tab:red", ls="--", lw=1, label="tolerance")
    chosen = summary_json["recommendation"]
    if chosen:
        left.scatter([chosen["f2"]], [chosen["f1"]], marker="*", s=250, color="tab:red", label="recommended")
    left.set_xlabel("f2: " + ("wall time T, s" if wall else "cost"))
    response = summary_json.get("response") or "n_remaining"
    left.set_ylabel(f"f1 = {summary_json['f1_rule']}", fontsize=8)
    left.legend(loc="best", fontsize=8)

    statuses = list(summary_json["failures"]["by_status"])
    by_status: dict[str, list[Evaluation]] = {}
    for ev in failed:
        by_status.setdefault(failure_status(ev) or "", []).append(ev)
    below = 0
    for row, status in enumerate(statuses):
        members = by_status.get(status, [])
        marker, colour = _failure_style(status)
        xs = [real_f2(ev) for ev in members]
        if left_edge is not None:
            below += sum(x < left_edge for x in xs)
            xs = [max(x, left_edge) for x in xs]
        left_failed.scatter(xs, [row] * len(members), marker=marker, color=colour, s=22, clip_on=False)
    measured_names = summary_json.get("responses_measured") or "N_t"
    _failure_strip(left_failed, statuses, f"failed individuals: {len(failed)} (not ranked)", measured_names)
    if below:
        left_failed.text(0.99, 0.06, f"{below} stopped cheaper than any measured set: at the left edge",
                         transform=left_failed.transAxes, ha="right", va="bottom", fontsize=7)

    by_generation: dict[int, list[int]] = {}
    failed_by_generation: dict[int, dict[str, int]] = {}
    w1_by_generation: dict[int, float] = {}
    band_by_generation: dict[int, dict[str, Any]] = {}
    for entry in summary_json["generations"]:
        failed_by_generation[entry["generation"]] = entry["failed_by_status"]
        w1 = (entry.get("w1_to_experiment") or {}).get(response)
        if w1 is not None:
            w1_by_generation[entry["generation"]] = w1
        band = (entry.get("as_experiment") or {}).get(response)
        if band is not None:
            band_by_generation[entry["generation"]] = band
    for record in records:
        if last_generation is not None and record.spec.generation > last_generation:
            continue  # extra replicates and validation: not a generation of the search
        n = _measured(record, response)
        if n is not None:
            by_generation.setdefault(record.spec.generation, []).append(n)
    generations = sorted(by_generation)
    if generations:
        # Behind each box, the 5-95 % range of the median of a generation drawn from the experiment
        # itself: with noisy single runs that is how far a converged generation's median strays.
        banded = [g for g in generations if g in band_by_generation]
        for g in banded:
            band = band_by_generation[g]
            label = "the experiment's median, 5-95 %" if g == banded[0] else None
            right.fill_between([g - 0.4, g + 0.4], band["median_5"], band["median_95"], color="tab:red",
                               alpha=0.12, lw=0, label=label)
        right.boxplot([by_generation[g] for g in generations], positions=generations)
        # Each generation's W1 to the experiment along the top: a median of noisy single runs
        # can sit on the target by chance; the distance says how like the experiment they are.
        # Bold: the generation is alike (its W1 inside the experiment's own band, optimizer/generations.py).
        along_top = right.get_xaxis_transform()
        right.text(generations[0] - 0.5, 1.01, "W1", transform=along_top, ha="right", va="bottom", fontsize=6)
        for g in generations:
            if g in w1_by_generation:
                band = band_by_generation.get(g)
                alike = band is not None and band["alike"]
                right.text(g, 1.01, f"{w1_by_generation[g]:.1f}", transform=along_top, ha="center",
                           va="bottom", fontsize=6, fontweight="bold" if alike else "normal")
    right.axhline(summary_json["target"], color="tab:red", ls="--", lw=1, label="target")
    right.set_xlabel("generation")
    right.set_ylabel(f"measured {response} (ok runs)")
    right.legend(loc="upper right", fontsize=8)
    bottom = dict.fromkeys(failed_by_generation, 0)
    for status in statuses:
        heights = [failed_by_generation[g].get(status, 0) for g in failed_by_generation]
        right_failed.bar(
            list(failed_by_generation),
            heights,
            bottom=[bottom[g] for g in failed_by_generation],
            color=_failure_style(status)[1],
            width=0.6,
            label=status,
        )
        for generation, height in zip(failed_by_generation, heights, strict=True):
            bottom[generation] += height
    right_failed.set_ylabel("failed\nruns", fontsize=8)
    right_failed.set_title(summary_json["failures"]["text"], fontsize=9, loc="left")
    if statuses:
        right_failed.legend(fontsize=7, loc="upper right", ncols=len(statuses))
    right_failed.set_ylim(0, max(1, *bottom.values()) * 1.25 if bottom else 1)
    right_failed.tick_params(labelsize=7)
    right_failed.yaxis.set_major_locator(MaxNLocator(integer=True, nbins=3))
    fig.suptitle(f"{summary_json['name']} ({summary_json['study_id']})")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _failure_strip(ax, statuses: list[str], title: str, measured: str) -> None:
    """One row per failed status, labelled, with the count in the title; 'none' when empty."""
    ax.set_yticks(range(len(statuses)), statuses, fontsize=7)
    ax.set_ylim(-0.7, max(len(statuses), 1) - 0.3)
    ax.set_title(title, fontsize=9, loc="left")
    if not statuses:
        ax.set_yticks([])
        ax.text(0.5, 0.4, f"every run measured {measured}", transform=ax.transAxes, ha="center", fontsize=8)


def write_results(directory: Path, study: StudyRecord, records: list[TrialRecord]) -> dict[str, Any]:
    """Write the three files into ``directory``; returns the summary."""
    directory.mkdir(parents=True, exist_ok=True)
    definition = StudyDefinition.model_validate(study.definition)
    summary_json = build_summary(study, records)
    (directory / "summary.json").write_text(json.dumps(summary_json, indent=2))
    write_trials_csv(directory / "trials.csv", definition, records)
    evaluations = evaluate(records, definition, definition.n_items())
    write_pareto_png(directory / "pareto.png", summary_json, evaluations, records, definition.ga.generations)
    return summary_json
