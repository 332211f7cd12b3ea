"""The results folder: trials.csv, summary.json and pareto.png from a finished study."""

from __future__ import annotations

import csv
import json
import statistics
from collections import Counter

from dem.result import SimulationStatus
from optimizer.driver import Driver
from optimizer.memory import MemoryStore, SyntheticExecutor, synthetic_result, synthetic_with_failures
from optimizer.protocols import TrialRecord, TrialSpec, TrialState
from optimizer.report import first_match, write_results
from tests.optimizer.conftest import PAPER_MEASURED, make_definition

TARGET = 4  # the paper's median 3.5, rounded half up


def matching_where_mu_above(threshold: float):
    """The synthetic feeder with N_t exactly on target where mu > threshold and 8 items off
    elsewhere, so which trials match is known from their parameters alone, whatever the seed.
    The runs off target are faster than any on it, so a recommendation that ignored the match
    would pick one of them."""

    def respond(spec):
        result = synthetic_result(spec)
        if spec.params["mu"] > threshold:
            n_remaining, times = TARGET, {}
        else:
            n_remaining, times = TARGET + 8, {"wall_time_s": 0.0, "cost": 0.0}
        update = {"n_remaining": n_remaining, "responses": {"n_remaining": n_remaining}, **times}
        return result.model_copy(update=update)

    return respond


def run_and_write(tmp_path, definition, respond):
    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(respond)).run_to_completion(study_id, poll_timeout=0)
    summary = write_results(tmp_path, store.load_study(study_id), store.trials(study_id))
    return summary, list(csv.DictReader((tmp_path / "trials.csv").open()))


def test_results_folder_holds_every_trial_and_the_recommendation(tmp_path, small_definition):
    summary, rows = run_and_write(tmp_path, small_definition, matching_where_mu_above(0.5))

    assert len(rows) == summary["simulations"] == 20
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / "pareto.png").read_bytes()[:4] == b"\x89PNG"
    assert summary["target"] == TARGET
    assert [g["individuals"] for g in summary["generations"]] == [8, 4, 4, 4]
    pareto_ids = {tid for member in summary["pareto"] for tid in member["trial_ids"]}
    assert {row["trial_id"] for row in rows if row["pareto"] == "True"} == pareto_ids
    # The recommendation is the fastest matching trial, and the first match is counted in
    # creation order, both read back from trials.csv.
    matching = [row for row in rows if float(row["mu"]) > 0.5]
    assert matching and len(matching) < len(rows)
    assert all(float(row["f1"]) == 0 for row in matching)
    fastest = min(matching, key=lambda row: float(row["f2"]))
    assert min(rows, key=lambda row: float(row["f2"])) not in matching  # only the match rule excludes it
    assert summary["recommendation"]["trial_ids"] == [fastest["trial_id"]]
    assert summary["recommendation"]["f1"] == 0
    first = min(int(row["individual"]) for row in matching)
    assert summary["simulations_until_first_match"] == first + 1


def test_the_equivalent_sets_are_the_recommendations_own_once_the_validation_chose_it(
    tmp_path, small_definition
):
    """The paper's study (calibration 20) recommended validated #172 over the search's fastest match
    #20: summary.json and the CLI listed only #86 as equivalent, the recommendation #20 and #86."""
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(matching_where_mu_above(0.5))).run_to_completion(study_id, poll_timeout=0)
    study = store.load_study(study_id)
    searched = write_results(tmp_path / "search", study, store.trials(study_id))
    fastest = searched["recommendation"]
    validated = next(m for m in searched["pareto"] if m["individual"] != fastest["individual"])
    study.recommendation = {**validated, "equivalent": [fastest, *searched["equivalent"]]}

    summary = write_results(tmp_path / "validated", study, store.trials(study_id))

    assert summary["equivalent"] == study.recommendation["equivalent"]
    assert fastest["individual"] in {member["individual"] for member in summary["equivalent"]}


def test_a_study_without_a_match_has_no_recommendation(tmp_path, small_definition):
    summary, rows = run_and_write(tmp_path, small_definition, matching_where_mu_above(2.0))

    assert len(rows) == 20
    assert summary["recommendation"] is None
    assert summary["simulations_until_first_match"] is None
    assert summary["best_f1"] == 8


def test_failed_runs_are_counted_by_status_and_never_shown_as_n_t(tmp_path, small_definition):
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    records = store.trials(study_id)
    failed = {r.spec.trial_id: r.result.status.value for r in records if not r.result.ok}

    summary = write_results(tmp_path, store.load_study(study_id), records)

    rows = {row["trial_id"]: row for row in csv.DictReader((tmp_path / "trials.csv").open())}
    expected = Counter(failed.values())
    assert set(expected) == {"unstable", "timeout"}  # the study exercises two statuses
    assert summary["failures"]["by_status"] == dict(expected)
    assert summary["failures"]["total"] == len(failed)
    assert summary["failures"]["text"].startswith(f"failed: {len(failed)} (")
    assert sum(g["failed"] for g in summary["generations"]) == len(failed)
    for tid, status in failed.items():
        assert rows[tid]["status"] == status
        assert rows[tid]["n_remaining [items]"] == "" and rows[tid]["f1"] == "" and rows[tid]["f2"] == ""
        assert rows[tid]["failure"] == status
    for entry in summary["generations"]:  # Fig. 5's numbers come from the ok runs alone
        generation = [r for r in records if r.spec.generation == entry["generation"]]
        ok = [r.result.n_remaining for r in generation if r.result.ok]
        shown = {key: entry["n_remaining"][key] for key in ("median", "min", "max")}
        assert shown == {"median": statistics.median(ok), "min": min(ok), "max": max(ok)}
    assert all(not member["failure"] for member in summary["pareto"])


def _record(individual: int, batch: int, replicate: int, n_remaining: int) -> TrialRecord:
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.1 * (individual + 1)}
    spec = TrialSpec(
        f"s-i{individual:05d}-r{replicate:02d}",
        "s",
        individual,
        batch,
        replicate,
        1000 + replicate,
        params,
        {},
    )
    result = synthetic_result(spec).model_copy(
        update={"n_remaining": n_remaining, "responses": {"n_remaining": n_remaining}}
    )
    return TrialRecord(spec, TrialState.DONE, result)


def test_first_match_counts_the_extra_replicates_run_before_it():
    """Batch 0: sets 0-7, two runs each, none matching; set 0 ([4, 12], median 8) is near enough
    to earn a third run. Batch 1: set 0's third run (now [4, 12, 4], median 4: a match) and sets
    8-11. Runs until the first match: 16 of batch 0, then set 0's extra run = 17; a count by
    individual x replicates would say 2 (set 0 before its extra run existed)."""
    definition = make_definition(
        replicates=2, max_replicates=3, experiment={"measured": PAPER_MEASURED, "distance": "aggregate"}
    )
    records = [_record(0, 0, 0, TARGET), _record(0, 0, 1, TARGET + 8)]
    records += [_record(i, 0, r, TARGET + 8) for i in range(1, 8) for r in range(2)]
    records += [_record(0, 1, 2, TARGET)]
    records += [_record(i, 1, r, TARGET + 8) for i in range(8, 12) for r in range(2)]

    assert first_match(records, definition) == 17
    assert first_match(records[:16], definition) is None


def test_first_match_counts_every_earlier_extra_replicate():
    """Set 9 matches in batch 1, after 16 runs of batch 0, set 0's extra run and set 8's two."""
    definition = make_definition(
        replicates=2, max_replicates=3, experiment={"measured": PAPER_MEASURED, "distance": "aggregate"}
    )
    records = [_record(i, 0, r, TARGET + 8) for i in range(8) for r in range(2)]
    records += [_record(0, 1, 2, TARGET + 8)]
    records += [_record(i, 1, r, TARGET if i == 9 else TARGET + 8) for i in range(8, 12) for r in range(2)]

    assert first_match(records, definition) == 16 + 1 + 2 + 2


def test_the_pareto_axis_spans_the_measured_sets_and_cheaper_failures_sit_at_its_edge(
    tmp_path, small_definition, monkeypatch
):
    """The paper study's invalid insertions cost 1e-4 of a full run; on an axis down to them the
    measured sets were squeezed into a sliver of pareto.png."""
    import matplotlib.figure

    def respond(spec):
        result = synthetic_result(spec)
        if spec.params["E"] < 1e6:  # stopped during the insertion: 1e-4 of a full run
            return result.model_copy(update={
                "status": SimulationStatus.INVALID, "message": "overlap",
                "wall_time_s": result.wall_time_s * 1e-4, "cost": result.cost * 1e-4,
            })  # fmt: skip
        return result

    figures = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: figures.append(fig))
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(respond)).run_to_completion(study_id, poll_timeout=0)
    records = store.trials(study_id)
    write_results(tmp_path, store.load_study(study_id), records)

    [figure] = figures
    strip, front = figure.axes[0], figure.axes[2]
    x = "wall_time_s" if small_definition.objective_time == "wall" else "cost"
    ok = [getattr(r.result, x) for r in records if r.result.ok]
    failed = [getattr(r.result, x) for r in records if not r.result.ok]
    low, high = front.get_xlim()
    assert failed and max(failed) < min(ok)
    assert min(ok) / 2 < low < min(ok) and max(ok) < high < 2 * max(ok)
    drawn = [x for collection in strip.collections for x, _ in collection.get_offsets()]
    assert drawn and min(drawn) == low
    assert any("at the left edge" in text.get_text() for text in strip.texts)
