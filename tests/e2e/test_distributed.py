"""Distributed execution end to end: ``demcal serve`` drives a study whose trials run on
``demcal worker`` processes, and the study completes, exactly once per trial, through a killed
worker, a restarted server, a flushed Redis and a worker that cannot run its simulation.
"""

from __future__ import annotations

import signal
import time
from dataclasses import asdict

import pytest
import sqlalchemy as sa
import trimesh

from api.db import create_db_engine
from api.models import StudyRow
from api.store import SqlStore
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.tray import TrayConfig, parametric_tray_mesh
from optimizer.protocols import TrialOutcome
from tests.e2e.conftest import free_port, tiny_scenario, tiny_study, wait_for
from worker.jobs import run_trial
from worker.rq_job import results_key

pytestmark = [pytest.mark.postgres, pytest.mark.redis, pytest.mark.slow]

TRIALS = 4 + 2  # tiny_study: population 4, then one generation of 2 offspring


def stored_trials(cluster, study_id: str):
    engine = create_db_engine(cluster.env["DEMCAL_DATABASE_URL"])
    try:
        return SqlStore(engine).trials(study_id)
    finally:
        engine.dispose()


def lease_holders(cluster, study_ids) -> dict[str, str | None]:
    """Each study's lease holder as the database records it (``studies.driver``)."""
    engine = create_db_engine(cluster.env["DEMCAL_DATABASE_URL"])
    try:
        with engine.connect() as connection:
            rows = connection.execute(
                sa.select(StudyRow.id, StudyRow.driver).where(StudyRow.id.in_(list(study_ids)))
            ).all()
    finally:
        engine.dispose()
    assert len(rows) == len(study_ids)
    return dict(rows)


# What a result depends on: the parameters and the seed, never the machine or the run's history.
DETERMINISTIC = {
    "status", "n_items", "n_remaining", "discharge_times", "emptied_at", "sim_time", "steps", "cost",
}


def assert_every_trial_has_exactly_one_result(cluster, study_id: str, planned: int = TRIALS) -> list[dict]:
    """Exactly once: every planned trial has one recorded result, no result is left waiting in
    Redis to be counted again, and the store refuses a second result for any trial."""
    trials = cluster.trials(study_id)
    assert len(trials) == planned
    assert all(trial["state"] == "done" and trial["status"] for trial in trials), trials
    assert cluster.redis.llen(results_key(cluster.queue, study_id)) == 0
    engine = create_db_engine(cluster.env["DEMCAL_DATABASE_URL"])
    try:
        store = SqlStore(engine)
        records = store.trials(study_id)
        assert sorted(record.spec.trial_id for record in records) == sorted(trial["id"] for trial in trials)
        assert all(record.result is not None for record in records)
        for record in records:
            intruder = SimulationResult(status=SimulationStatus.OK, n_items=1, n_remaining=99)
            second = TrialOutcome(record.spec.trial_id, intruder, worker="intruder")
            assert store.record_result(second) is False
        assert {r.spec.trial_id: r.result for r in store.trials(study_id)} == {
            r.spec.trial_id: r.result for r in records
        }
    finally:
        engine.dispose()
    return trials


def assert_result_equals_a_clean_run(cluster, study_id: str, trial_id: str) -> None:
    """The recorded result of a trial that was interrupted and run again is the one an
    uninterrupted run of the same spec gives (here, in this process)."""
    [record] = [record for record in stored_trials(cluster, study_id) if record.spec.trial_id == trial_id]
    clean = SimulationResult.model_validate(run_trial(asdict(record.spec)))
    assert clean.status is SimulationStatus.OK, clean.message
    assert record.result.model_dump(include=DETERMINISTIC) == clean.model_dump(include=DETERMINISTIC)


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
    # The API counts the run on w1 that never delivered: the trial took two attempts.
    assert trials[killed_trial]["attempts"] == 2
    assert {trial["attempts"] for trial_id, trial in trials.items() if trial_id != killed_trial} == {1}
    assert_result_equals_a_clean_run(cluster, study_id, killed_trial)


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
    # The study's tray is a mesh in the mesh directory: each worker reads it from its own data dir,
    # where w-with-mesh has it and w-without-mesh does not (a machine nobody copied the file to).
    # The server's data dir has none either: it only checks the path, a worker opens the file.
    with_mesh, without_mesh = tmp_path / "with-mesh", tmp_path / "without-mesh"
    (with_mesh / "meshes" / "trays").mkdir(parents=True)
    without_mesh.mkdir()
    vertices, faces = parametric_tray_mesh(TrayConfig())
    trimesh.Trimesh(vertices, faces, process=False).export(with_mesh / "meshes" / "trays" / "tray.stl")
    definition = tiny_study("missing-mesh")
    definition["scenario"]["tray"] = {**definition["scenario"].get("tray", {}), "mesh_file": "trays/tray.stl"}
    cluster.start_serve()
    # Its failures take no time: it runs one trial and exits, or it would fail every trial (all
    # the study's batches) before w-with-mesh has warmed up.
    without = cluster.start_worker("w-without-mesh", data_dir=without_mesh, max_jobs=1)
    study_id = cluster.create_study(definition)
    assert without.wait(timeout=120) == 0
    cluster.start_worker("w-with-mesh", data_dir=with_mesh)
    study = cluster.wait_until_done(study_id)

    assert study["status"] == "done", study["message"]
    trials = assert_every_trial_has_exactly_one_result(cluster, study_id)
    failed = [trial for trial in trials if trial["worker"] == "w-without-mesh"]
    assert failed and all(trial["status"] == "error" for trial in failed)
    missing = without_mesh.resolve() / "meshes" / "trays" / "tray.stl"
    assert all(f"tray.mesh_file {missing} does not exist" in trial["message"] for trial in failed)
    assert {trial["status"] for trial in trials if trial["worker"] != "w-without-mesh"} == {"ok"}


def test_a_shape_uploaded_through_the_api_is_fed_to_a_simulation_on_a_worker(cluster):
    import io

    mesh = io.BytesIO()
    trimesh.creation.box(extents=(0.14, 0.07, 0.01)).export(mesh, file_type="stl")
    cluster.start_serve()
    cluster.start_worker("w1")
    upload = cluster.http.post(
        "/shapes", files={"file": ("phone.stl", mesh.getvalue(), "model/stl")}, data={"mass": "0.15"}
    )
    assert upload.status_code == 201, upload.text
    scenario = tiny_scenario()
    scenario["items"] = {"uploaded": True, "counts": {upload.json()["id"]: 2}, "resolution": 4}

    params = {"E": 2e6, "nu": 0.3, "e": 0.5, "mu": 0.4}
    created = cluster.http.post("/simulations", json={"scenario": scenario, "params": params})
    assert created.status_code == 202, created.text
    done = wait_for(
        lambda: (body := cluster.http.get(f"/simulations/{created.json()['id']}").json())["state"] == "done"
        and body,
        120,
        "the simulation on the uploaded shape",
    )

    assert done["worker"] == "w1"
    assert done["result"]["status"] == "ok", done["result"]["message"]
    assert done["result"]["n_items"] == 2


def test_a_worker_stopped_with_sigterm_finishes_its_trial_first(cluster):
    cluster.start_serve()
    worker = cluster.start_worker("w1")
    study_id = cluster.create_study(tiny_study("sigterm"))
    running = wait_for(lambda: cluster.worker_busy("w1"), 60, "w1 to start a trial")

    worker.send_signal(signal.SIGTERM)
    exit_code = worker.wait(120)
    # The worker has pushed its result; serve records it on its next step (every second).
    def recorded():
        trial = {t["id"]: t for t in cluster.trials(study_id)}[running]
        return trial if trial["state"] == "done" else None

    finished = wait_for(recorded, 30, f"serve to record {running}")

    assert exit_code == 0
    assert finished["worker"] == "w1"
    assert finished["status"] == "ok"
    assert cluster.worker_busy("w1") is None


def test_a_second_sigterm_stops_the_worker_at_once_and_the_trial_runs_elsewhere(cluster):
    # Trials of 30 simulated seconds (about 9 s of wall): longer than the two signals take (about
    # 2 s) even on a fast machine, so the second one reaches a trial still running (10 s took 3.1 s
    # of wall after session 11's engine speed-ups, too close).
    definition = tiny_study("second-sigterm", population=2, offspring=1, generations=1)
    definition["scenario"]["stages"]["vibration_time"] = 30.0
    cluster.start_serve()
    worker = cluster.start_worker("w1")
    study_id = cluster.create_study(definition)
    running = wait_for(lambda: cluster.worker_busy("w1"), 60, "w1 to start a trial")

    worker.send_signal(signal.SIGTERM)
    # The worker notes the first signal in its RQ record; RQ takes a second signal within a
    # second of the first for a duplicate (a pool and a terminal both signalling), so wait that out.
    wait_for(lambda: cluster.redis.hget("rq:worker:w1", "shutdown_requested_date"), 30, "the first SIGTERM")
    time.sleep(1.5)
    assert worker.poll() is None, "the first SIGTERM must let the trial finish"
    worker.send_signal(signal.SIGTERM)
    started = time.monotonic()
    exit_code = worker.wait(30)
    stopped_after = time.monotonic() - started
    cluster.start_worker("w2")
    study = cluster.wait_until_done(study_id, timeout=600)  # three 30 s trials on a loaded machine
    trial = {t["id"]: t for t in cluster.trials(study_id)}[running]

    assert stopped_after < 5.0
    assert exit_code == 1
    assert study["status"] == "done", study["message"]
    # Whether w1 delivered is read once the study is done, not the instant w1 exits (serve records
    # a pushed result within a second): had w1 finished the trial, its result would be the one
    # recorded (the store refuses a second), so the trial ran again and only w2's run counts.
    assert trial["worker"] == "w2"
    # At least w1's interrupted run and w2's. One more when serve's reconciliation also found the
    # trial lost in the moment between w1's exit and RQ's retry, and sent it again itself (seen
    # once at load, 3 == 2): each sending is an attempt, whichever process made it.
    assert trial["attempts"] >= 2


def test_two_serve_replicas_at_once_share_the_studies(cluster):
    second_port = free_port()
    first = cluster.start_serve("serve-1")
    second = cluster.start_serve("serve-2", port=second_port)
    cluster.start_worker("w1")
    cluster.start_worker("w2")
    # Three trials a study: what is shared is the studies, not their size.
    studies = [cluster.create_study(tiny_study(f"replica-{k}", population=2, offspring=1), via=via)
               for k, via in enumerate([cluster.port, second_port])]

    done = [cluster.wait_until_done(study_id, timeout=240) for study_id in studies]
    # A finished study's lease (in the database) is let go by whichever replica held it, at
    # its next tick: released, not merely left to expire.
    wait_for(lambda: set(lease_holders(cluster, studies).values()) == {None}, 30, "the leases to be released")
    logs = {name: cluster.logs[name].read_text(errors="replace") for name in ("serve-1", "serve-2")}

    assert first.poll() is None and second.poll() is None
    assert [study["status"] for study in done] == ["done"] * 2, [study["message"] for study in done]
    for study_id in studies:
        assert_every_trial_has_exactly_one_result(cluster, study_id, planned=2 + 1)
        # Either replica shows every study, with the same trials.
        assert cluster.trials(study_id, via=second_port) == cluster.trials(study_id)
        # One replica drove it, from start to end: no replica took it while another held it.
        drivers = [name for name, text in logs.items() for line in text.splitlines()
                   if f"study {study_id}: now driven by" in line]
        assert len(drivers) == 1, (study_id, drivers)
