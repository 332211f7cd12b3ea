"""Distributed execution end to end: ``demcal serve`` drives a study whose trials run on
``demcal worker`` processes, and the study completes, exactly once per trial, through a killed
worker, a restarted server, a flushed Redis and a worker that cannot run its simulation.
"""

from __future__ import annotations

import signal

import pytest
import trimesh

from api.db import create_db_engine
from api.store import SqlStore
from dem.scenarios.tray import TrayConfig, parametric_tray_mesh
from tests.e2e.conftest import tiny_scenario, tiny_study, wait_for

pytestmark = [pytest.mark.postgres, pytest.mark.redis, pytest.mark.slow]

TRIALS = 4 + 2  # tiny_study: population 4, then one generation of 2 offspring


def stored_trials(cluster, study_id: str):
    engine = create_db_engine(cluster.env["DEMCAL_DATABASE_URL"])
    try:
        return SqlStore(engine).trials(study_id)
    finally:
        engine.dispose()


def assert_every_trial_has_exactly_one_result(cluster, study_id: str) -> list[dict]:
    trials = cluster.trials(study_id)
    ids = [trial["id"] for trial in trials]
    assert len(ids) == len(set(ids)) == TRIALS
    assert all(trial["state"] == "done" and trial["status"] for trial in trials), trials
    return trials


def test_serve_and_two_workers_complete_a_study_and_the_api_shows_what_is_stored(cluster):
    cluster.start_serve()
    cluster.start_worker("w1")
    cluster.start_worker("w2")
    study_id = cluster.create_study(tiny_study("two-workers"))
    simulation = cluster.http.post(
        "/simulations",
        json={"scenario": tiny_scenario(), "params": {"E": 2e6, "nu": 0.3, "e": 0.5, "mu": 0.4}},
    )

    study = cluster.wait_until_done(study_id)
    single = wait_for(
        lambda: (
            (body := cluster.http.get(f"/simulations/{simulation.json()['id']}").json())["state"] == "done"
            and body
        ),
        60,
        "the single simulation's result",
    )

    assert study["status"] == "done", study["message"]
    shown = {trial["id"]: trial for trial in assert_every_trial_has_exactly_one_result(cluster, study_id)}
    stored = {record.spec.trial_id: record for record in stored_trials(cluster, study_id)}
    assert shown.keys() == stored.keys()
    for trial_id, record in stored.items():
        assert shown[trial_id]["status"] == record.result.status.value
        assert shown[trial_id]["n_remaining"] == record.result.n_remaining
        assert shown[trial_id]["params"] == pytest.approx(record.spec.params)
        assert shown[trial_id]["worker"] in ("w1", "w2")
    assert study["progress"]["trials_done"] == TRIALS
    assert simulation.status_code == 202, simulation.text
    assert single["worker"] in ("w1", "w2")
    assert single["result"]["status"] == "ok"


def test_serve_without_redis_runs_the_study_on_its_local_pool(cluster):
    del cluster.env["DEMCAL_REDIS_URL"]
    cluster.env["DEMCAL_WORKERS"] = "2"
    cluster.start_serve()
    study_id = cluster.create_study(tiny_study("local-pool"))

    study = cluster.wait_until_done(study_id)

    assert study["status"] == "done", study["message"]
    assert_every_trial_has_exactly_one_result(cluster, study_id)


def test_a_worker_killed_mid_trial_loses_no_trial_and_counts_none_twice(cluster):
    cluster.start_serve()
    cluster.start_worker("w1")
    study_id = cluster.create_study(tiny_study("killed-worker"))
    killed_trial = wait_for(lambda: cluster.worker_busy("w1"), 60, "w1 to start a trial")
    cluster.start_worker("w2")

    cluster.kill("w1")
    study = cluster.wait_until_done(study_id)

    assert study["status"] == "done", study["message"]
    trials = {trial["id"]: trial for trial in assert_every_trial_has_exactly_one_result(cluster, study_id)}
    assert trials[killed_trial]["worker"] == "w2"


def test_a_restarted_serve_resumes_the_study_mid_generation(cluster):
    cluster.start_serve("serve-1")
    cluster.start_worker("w1")
    study_id = cluster.create_study(tiny_study("restarted-serve"))
    wait_for(lambda: cluster.worker_busy("w1"), 60, "the first trial to start")

    cluster.kill("serve-1")  # no chance to release its lease: the next serve waits it out
    cluster.start_serve("serve-2")
    cluster.start_worker("w2")
    study = cluster.wait_until_done(study_id)

    assert study["status"] == "done", study["message"]
    assert_every_trial_has_exactly_one_result(cluster, study_id)


def test_a_flushed_redis_mid_generation_loses_no_trial(cluster):
    cluster.start_serve()
    cluster.start_worker("w1")
    cluster.start_worker("w2")
    study_id = cluster.create_study(tiny_study("flushed-redis"))
    wait_for(lambda: cluster.worker_busy("w1") or cluster.worker_busy("w2"), 60, "a trial to start")

    cluster.redis.flushdb()  # stands for FLUSHALL: the test Redis database is all this deployment has
    study = cluster.wait_until_done(study_id)

    assert study["status"] == "done", study["message"]
    assert_every_trial_has_exactly_one_result(cluster, study_id)


def test_a_worker_whose_simulation_fails_reports_an_error_trial_and_the_study_goes_on(cluster, tmp_path):
    # The study's tray is a user mesh given by a relative path: present where w-with-mesh runs,
    # missing where w-without-mesh runs (a machine nobody copied the file to).
    with_mesh, without_mesh = tmp_path / "with-mesh", tmp_path / "without-mesh"
    with_mesh.mkdir()
    without_mesh.mkdir()
    vertices, faces = parametric_tray_mesh(TrayConfig())
    trimesh.Trimesh(vertices, faces, process=False).export(with_mesh / "tray.stl")
    definition = tiny_study("missing-mesh")
    definition["scenario"]["tray"] = {**definition["scenario"].get("tray", {}), "mesh_file": "tray.stl"}
    cluster.start_serve()
    cluster.start_worker("w-without-mesh", cwd=without_mesh)
    study_id = cluster.create_study(definition)
    wait_for(
        lambda: any(trial["status"] == "error" for trial in cluster.trials(study_id)),
        60,
        "the worker without the mesh to report an error",
    )

    cluster.start_worker("w-with-mesh", cwd=with_mesh)
    study = cluster.wait_until_done(study_id)

    assert study["status"] == "done", study["message"]
    trials = assert_every_trial_has_exactly_one_result(cluster, study_id)
    failed = [trial for trial in trials if trial["worker"] == "w-without-mesh"]
    assert failed and all(trial["status"] == "error" for trial in failed)
    assert all("tray.mesh_file tray.stl does not exist" in trial["message"] for trial in failed)


def test_a_worker_stopped_with_sigterm_finishes_its_trial_first(cluster):
    cluster.start_serve()
    worker = cluster.start_worker("w1")
    study_id = cluster.create_study(tiny_study("sigterm"))
    running = wait_for(lambda: cluster.worker_busy("w1"), 60, "w1 to start a trial")

    worker.send_signal(signal.SIGTERM)
    exit_code = worker.wait(120)

    assert exit_code == 0
    finished = {trial["id"]: trial for trial in cluster.trials(study_id)}
    assert finished[running]["worker"] == "w1"
    assert finished[running]["state"] in ("done",)
