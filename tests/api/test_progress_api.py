"""Progress (hypervolume and best f1 per batch) and identifiability over HTTP: the same figures as
the study's summary.json, only for the study's owner."""

from __future__ import annotations

import time

from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_with_failures
from optimizer.progress import study_progress
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



def _progress_once_built(client, url: str, auth: dict, expected: list[dict]) -> list[dict]:
    """Poll until the view shows ``expected``: it is served one version stale while it builds."""
    deadline = time.monotonic() + 60
    while (points := client.get(url, headers=auth).json()["points"]) != expected:
        assert time.monotonic() < deadline, f"progress stayed at {points}, expected {expected}"
        time.sleep(0.02)
    return points


def test_progress_polled_during_a_run_reads_each_batch_once_and_agrees_with_one_pass(
    client, keys, store, monkeypatch
):
    from api.store import SqlStore

    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 4}, seed=7)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    driver = Driver(store, SyntheticExecutor(synthetic_with_failures))
    read = []
    batch_trials = SqlStore.batch_trials

    def counted(self, *args):
        records = batch_trials(self, *args)
        read.extend(record.spec.trial_id for record in records)
        return records

    monkeypatch.setattr(SqlStore, "batch_trials", counted)
    url = f"/api/v1/studies/{study_id}/progress"

    shown = []
    active = True
    while active:
        active = driver.step(study_id, timeout=0).active
        record = store.load_study(study_id)
        validation = (record.recommendation or {}).get("validation", [])
        expected = study_progress(store.trials(study_id), definition, record.generation, validation)
        shown.append(_progress_once_built(client, url, keys.auth(), expected.as_json()["points"]))

    assert len({len(points) for points in shown}) > 3  # it was polled after most batches
    completed = [t.spec.trial_id for t in store.trials(study_id) if t.spec.generation < record.generation]
    assert sorted(read) == sorted(completed)  # each completed batch read once, however many polls


def test_identifiability_resting_between_builds_says_when_to_ask_again(client, keys, store):
    # A stale answer while the view rests carries Retry-After (its 304 too): dashboards asking
    # for it every poll meanwhile made a third of their requests (benchmarks/README.md, session 6).
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 3}, seed=7)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    url = f"/api/v1/studies/{study_id}/identifiability"
    client.get(url, headers=keys.auth())  # built on the request: nothing to serve stale yet
    generation = store.load_study(study_id).generation

    def next_batch() -> None:
        nonlocal generation
        generation += 1
        store.save_generation(study_id, generation, b"state", [], None, objectives={})

    next_batch()
    deadline = time.monotonic() + 60
    while client.get(url, headers=keys.auth()).headers["X-Demcal-View"] != "current":  # built meanwhile
        assert time.monotonic() < deadline, "the next version was never built"
        time.sleep(0.05)
    next_batch()
    stale = client.get(url, headers=keys.auth())
    revalidated = client.get(url, headers={**keys.auth(), "If-None-Match": stale.headers["ETag"]})

    assert stale.status_code == 200 and stale.headers["X-Demcal-View"] == "stale"
    assert int(stale.headers["Retry-After"]) >= 1
    assert revalidated.status_code == 304
    assert 1 <= int(revalidated.headers["Retry-After"]) <= int(stale.headers["Retry-After"])  # counting down


def test_identifiability_while_it_builds_says_when_to_ask_again(client, keys, store, monkeypatch):
    # A stale answer while the next version builds carried no Retry-After: pages asked again every
    # poll, 84-915 times a benchmark run (benchmarks/README.md, API session 8, part 2).
    from api.services import progress

    def slow(build, store, study_id) -> bytes:
        time.sleep(1.5)  # a long study's build
        return build(store, study_id)

    monkeypatch.setattr(progress, "in_child", slow)
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 3}, seed=7)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    url = f"/api/v1/studies/{study_id}/identifiability"
    client.get(url, headers=keys.auth())  # built on the request: its build took 1.5 s
    generation = store.load_study(study_id).generation
    store.save_generation(study_id, generation + 1, b"state", [], None, objectives={})

    building = client.get(url, headers=keys.auth())

    assert building.headers["X-Demcal-View"] == "stale"
    assert int(building.headers["Retry-After"]) >= 2  # the 1.5 s a build took, rounded up
    deadline = time.monotonic() + 30
    while client.get(url, headers=keys.auth()).headers["X-Demcal-View"] != "current":  # ends in the test
        assert time.monotonic() < deadline, "the next version was never built"
        time.sleep(0.1)
