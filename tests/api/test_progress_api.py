"""Progress (hypervolume and best f1 per batch) and identifiability over HTTP: the same figures as
the study's summary.json, only for the study's owner."""

from __future__ import annotations

from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_with_failures
from optimizer.report import build_summary
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


def test_progress_and_identifiability_match_the_summary_and_are_private(client, keys, store):
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 3}, seed=7)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    summary = build_summary(store.load_study(study_id), store.trials(study_id))
    base = f"/api/v1/studies/{study_id}"

    progress = client.get(f"{base}/progress", headers=keys.auth()).json()
    identified = client.get(f"{base}/identifiability", headers=keys.auth()).json()
    hidden = client.get(f"{base}/progress", headers=keys.auth("bob"))

    assert progress["points"] == summary["progress"]["points"]
    assert progress["reference"] == summary["progress"]["reference"]
    assert [p["simulations"] for p in progress["points"]] == [8, 12, 16, 20]
    assert progress["points"][-1]["failed"] == summary["failures"]["total"]
    assert {k: v for k, v in identified.items() if k != "study_id"} == summary["identifiability"]
    assert [entry["name"] for entry in identified["parameters"]] == ["E", "nu", "e", "mu"]
    assert hidden.status_code == 404
