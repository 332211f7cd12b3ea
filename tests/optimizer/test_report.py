"""The results folder: trials.csv, summary.json and pareto.png from a finished study."""

from __future__ import annotations

import csv
import json

from optimizer.driver import Driver
from optimizer.memory import MemoryStore, SyntheticExecutor
from optimizer.report import write_results


def test_results_folder_holds_every_trial_and_the_recommendation(tmp_path, small_definition):
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    summary = write_results(tmp_path, store.load_study(study_id), store.trials(study_id))

    rows = list(csv.DictReader((tmp_path / "trials.csv").open()))
    assert len(rows) == summary["simulations"] == 20
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / "pareto.png").read_bytes()[:4] == b"\x89PNG"
    assert summary["target"] == 4.0
    assert [g["individuals"] for g in summary["generations"]] == [8, 4, 4, 4]
    pareto_ids = {tid for member in summary["pareto"] for tid in member["trial_ids"]}
    assert {row["trial_id"] for row in rows if row["pareto"] == "True"} == pareto_ids
    assert summary["recommendation"]["f1"] <= 0.5  # seed 7 finds a match in 20 simulations
    assert summary["simulations_until_first_match"] <= summary["recommendation"]["individual"] + 1
