"""One study with failed runs, read through every view: the CLI's final report, summary.json and
trials.csv of the results folder, and the API (the study list and the study's progress, the
per-generation summary, trial pages, the Pareto front, the CSV export). They must agree on the
failure counts by status, and none may show a failed run as an N_t value or a failed individual
as a ranked point."""

from __future__ import annotations

import csv
import io
import json
from collections import Counter

from rich.console import Console

from api.commands.calibrate import _report
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_with_failures
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


def test_every_view_counts_failed_runs_alike_and_shows_no_n_t_for_them(client, keys, store, tmp_path):
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 3}, seed=7)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    truth = Counter(r.result.status.value for r in store.trials(study_id) if not r.result.ok)
    failed_ids = {r.spec.trial_id for r in store.trials(study_id) if not r.result.ok}
    console = Console(record=True, width=200)

    _report(console, store, study_id, tmp_path / "results")

    cli = console.export_text()
    # The results folder also holds the SQLite file (and its -wal/-shm): take the study's folder.
    [folder] = [p for p in (tmp_path / "results").iterdir() if p.is_dir()]
    summary = json.loads((folder / "summary.json").read_text())
    report_csv = list(csv.DictReader((folder / "trials.csv").open()))
    base, auth = f"/api/v1/studies/{study_id}", keys.auth()
    progress = client.get(base, headers=auth).json()["progress"]
    listed = client.get("/api/v1/studies", headers=auth).json()["items"][0]["failures"]
    generations = client.get(f"{base}/generations", headers=auth).json()
    trials = client.get(f"{base}/trials", params={"limit": 1000}, headers=auth).json()["items"]
    front = client.get(f"{base}/pareto", headers=auth).json()["points"]
    api_csv = list(csv.DictReader(io.StringIO(client.get(f"{base}/export.csv", headers=auth).text)))

    assert set(truth) == {"unstable", "timeout"} and sum(truth.values()) >= 3
    text = f"failed: {sum(truth.values())} (unstable {truth['unstable']}, timeout {truth['timeout']})"
    assert summary["failures"]["by_status"] == progress["failures"]["by_status"] == dict(truth)
    assert summary["failures"]["text"] == progress["failures"]["text"] == listed["text"] == text
    assert text in cli
    for status, count in truth.items():
        assert f"│ {status} " in cli and f" {count} │" in cli  # the CLI's failures table row
    per_generation = Counter()
    for entry in generations:
        per_generation.update(entry["failed_by_status"])
    assert per_generation == truth
    assert [g["failed"] for g in summary["generations"]] == [g["failed"] for g in generations]
    for key in ("n_remaining", "responses", "wall_time_s", "cost"):  # one summary, two views
        assert [g[key] for g in summary["generations"]] == [g[key] for g in generations]
    # One table: the report's CSV and the API's have the same columns.
    assert list(report_csv[0]) == list(api_csv[0])
    for rows in (report_csv, api_csv):
        column = "n_remaining [items]"
        shown = Counter(row["status"] for row in rows if row["status"] != "ok")
        assert shown == truth
        hidden = [row for row in rows if row["trial_id"] in failed_ids]
        assert all(row[column] == "" and row["f1"] == "" for row in hidden)
    assert all(t["n_remaining"] is None and t["f1"] is None for t in trials if t["id"] in failed_ids)
    assert all(t["n_remaining"] is not None for t in trials if t["id"] not in failed_ids)
    assert not {point["id"] for point in front} & failed_ids
