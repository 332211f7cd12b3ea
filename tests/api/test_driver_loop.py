"""The driver loop of ``demcal serve`` (``api/driver_loop.py``) on the real store: one study's
failure fails that study only, and cancel, pause and delete withdraw the work from the executor
(the RQ queue on the real Redis, the local process pool)."""

from __future__ import annotations

import threading
import time

import pytest

from api.driver_loop import DriverLoop
from api.store.leases import DatabaseLeases
from optimizer.memory import SyntheticExecutor
from optimizer.protocols import StudyStatus, TrialState
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition
from tests.worker.test_jobs import LONG_SCENARIO


def create(store, **overrides) -> str:
    definition = StudyDefinition.model_validate(study_definition(**overrides))
    return store.create_study(definition.model_dump(mode="json"), owner="alice")


def loop_on(store, executor) -> DriverLoop:
    return DriverLoop(store, executor, DatabaseLeases(store, "test"), poll_s=0.05, scan_every_s=0.0)


def tick_until(loop: DriverLoop, done, limit_s: float = 30.0) -> None:
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        loop.tick()
        if done():
            return
    raise AssertionError(f"condition not reached within {limit_s:g} s")


def test_a_study_the_driver_cannot_step_fails_alone_and_the_others_advance(store):
    broken, healthy = create(store, name="broken"), create(store, name="healthy")
    # A GA state that cannot be read back: whatever escapes the driver for one study.
    store.save_generation(broken, 1, b"not a pickled search", [], None)
    loop = loop_on(store, SyntheticExecutor())

    tick_until(loop, lambda: store.load_study(healthy).generation >= 1)

    failed = store.load_study(broken)
    assert failed.status is StudyStatus.FAILED
    assert "the driver failed on this study" in failed.message
    assert broken not in loop.held


def test_a_study_cancelled_then_deleted_within_a_scan_leaves_nothing_queued(store):
    doomed, other = create(store, name="doomed"), create(store, name="other")
    executor = SyntheticExecutor(per_poll=0)  # nothing finishes: every trial stays queued
    loop = loop_on(store, executor)
    loop.tick()
    assert any(trial.startswith(doomed) for trial in executor.in_flight())

    assert store.transition(doomed, [StudyStatus.RUNNING], StudyStatus.CANCELLED)
    store.delete_study(doomed)
    loop.tick()
    loop.tick()

    assert not any(trial.startswith(doomed) for trial in executor.in_flight())
    assert doomed not in loop.held
    assert other in loop.held
    assert any(trial.startswith(other) for trial in executor.in_flight())


@pytest.mark.redis
def test_cancel_removes_a_studys_jobs_from_the_redis_queue(store, redis_url):
    from worker.rq_executor import RqExecutor

    executor = RqExecutor.from_url(redis_url, "demcal-cancel-test")
    try:
        study_id = create(store)
        loop = loop_on(store, executor)
        loop.tick()  # no worker runs: the whole first batch waits in the queue
        assert executor.queue_depth() == 6

        assert store.transition(study_id, [StudyStatus.RUNNING], StudyStatus.CANCELLED)
        loop.tick()

        assert executor.queue_depth() == 0
        assert not executor.in_flight()
    finally:
        executor.close()


@pytest.mark.redis
def test_a_trial_for_an_engine_no_worker_has_stays_queued_saying_so_until_a_worker_takes_it(
    store, redis_url, client, keys
):
    from worker.rq_executor import RqExecutor

    executor = RqExecutor.from_url(redis_url, "demcal-engine-test")
    try:
        study_id = create(
            store, engine="liggghts", scenario={"kind": "angle_of_repose"},
            experiment={"response": "angle_deg", "measured": [30.0]},
        )
        loop_on(store, executor).tick()  # no worker takes demcal-engine-test.liggghts

        trials = client.get(f"/api/v1/studies/{study_id}/trials", headers=keys.auth()).json()["items"]
        assert len(trials) == 6
        for trial in trials:
            assert (trial["state"], trial["engine"]) == ("queued", "liggghts")
            assert trial["message"].startswith("waiting for a worker with engine 'liggghts': no worker takes "
                                               "queue 'demcal-engine-test.liggghts'")
        store.mark_running(trials[0]["id"], "worker-with-liggghts")
        base = f"/api/v1/studies/{study_id}/trials"
        running = client.get(f"{base}/{trials[0]['id']}", headers=keys.auth()).json()
        assert (running["state"], running["message"]) == ("running", "")
    finally:
        executor.close()


@pytest.mark.slow
def test_cancel_frees_the_local_pool_at_once_for_the_next_study(store):
    from worker.local import LocalPoolExecutor

    executor = LocalPoolExecutor(workers=1)
    try:
        small = {
            "scenario": LONG_SCENARIO, "experiment": {"measured": [1]},
            "ga": {"population": 2, "generations": 0},
        }
        first = create(store, name="first", **small)
        loop = loop_on(store, executor)
        tick_until(loop, lambda: any(t.startswith(first) for t in executor.running()))

        assert store.transition(first, [StudyStatus.RUNNING], StudyStatus.CANCELLED)
        second = create(store, name="second", **small)
        tick_until(loop, lambda: any(t.startswith(second) for t in executor.running()), limit_s=20.0)

        assert not any(t.startswith(first) for t in executor.in_flight())
        assert not store.trials(first, [TrialState.QUEUED, TrialState.RUNNING])
    finally:
        executor.close()


@pytest.mark.slow
def test_a_trial_a_worker_started_shows_running_at_the_next_tick_not_the_next_scan(store):
    from worker.local import LocalPoolExecutor

    executor = LocalPoolExecutor(workers=1)
    try:
        small = {"measured": [1]}, {"population": 2, "generations": 0}
        study_id = create(store, scenario=LONG_SCENARIO, experiment=small[0], ga=small[1])
        # A scan (lease bookkeeping) only at the first tick: showing a trial running must not wait for one.
        loop = DriverLoop(store, executor, DatabaseLeases(store, "test"), poll_s=0.05, scan_every_s=3600.0)
        tick_until(loop, lambda: bool(executor.running()))
        started = dict(executor.running())

        loop.tick()

        running = {t.spec.trial_id: t for t in store.trials(study_id, [TrialState.RUNNING])}
        assert set(started) <= set(running)
        assert all(running[trial].worker == worker for trial, worker in started.items())
    finally:
        executor.close()


def test_a_running_trial_is_written_once_per_worker_not_at_every_tick(store, monkeypatch):
    from api.driver_loop import RunningMarks

    study_id = create(store)
    loop_on(store, SyntheticExecutor(per_poll=0)).tick()  # the first batch is queued, none runs
    trial = store.trials(study_id, [TrialState.QUEUED])[0].spec.trial_id
    written: list[tuple[str, str]] = []
    mark = store.mark_running
    monkeypatch.setattr(store, "mark_running", lambda t, w=None: (written.append((t, w)), mark(t, w)))

    class Workers:
        now: dict[str, str] = {trial: "w1"}

        def running(self) -> dict[str, str]:
            return dict(self.now)

    marks, workers = RunningMarks(), Workers()
    for _ in range(3):
        marks.update(store, workers)
    assert written == [(trial, "w1")]
    assert {t.spec.trial_id: t.worker for t in store.trials(study_id, [TrialState.RUNNING])} == {trial: "w1"}

    workers.now = {}  # lost with w1; sent again (queued), then taken by w2
    marks.update(store, workers)
    store.mark_queued([trial])
    workers.now = {trial: "w2"}
    marks.update(store, workers)
    marks.update(store, workers)
    assert written == [(trial, "w1"), (trial, "w2")]
    assert store.trials(study_id, [TrialState.RUNNING])[0].worker == "w2"


def test_a_poll_reads_only_the_trials_written_since_the_last_and_never_a_simulation_per_result(store, engine):
    import sqlalchemy as sa

    from api.models import TrialRow

    study_id = create(store, ga={"population": 8, "offspring": 4, "generations": 8})
    store.create_simulation({}, {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.4}, 5, "alice")
    loop = DriverLoop(
        store, SyntheticExecutor(per_poll=3), DatabaseLeases(store, "test"),
        poll_s=0.0, scan_every_s=3600.0, reconcile_every_s=3600.0,
    )
    statements: list[str] = []
    loaded: list[TrialRow] = []

    def newest() -> object:
        with store.session() as s:
            return s.scalar(sa.select(sa.func.max(TrialRow.updated_at)).where(TrialRow.study_id == study_id))

    def tick() -> tuple[list[str], list[tuple[object, int]]]:
        statements.clear(), loaded.clear()
        sa.event.listen(engine, "before_cursor_execute", on_statement)
        sa.event.listen(TrialRow, "load", on_load)
        try:
            loop.tick()
        finally:
            sa.event.remove(engine, "before_cursor_execute", on_statement)
            sa.event.remove(TrialRow, "load", on_load)
        return list(statements), [(row.updated_at, row.generation) for row in loaded]

    def on_statement(conn, cursor, statement, *args):
        statements.append(statement)

    def on_load(row, context):
        loaded.append(row)

    ticks = []
    while store.load_study(study_id).status is not StudyStatus.DONE:
        ticks.append((newest(), *tick()))

    total = len(store.trials(study_id))
    read_per_tick = [len(rows) for _, _, rows in ticks[1:]]  # the first poll reads the study whole
    assert total == 8 + 4 * 8 and len(ticks) > 16
    assert max(read_per_tick) < total / 2
    for (since, *_), (_, _, rows) in zip(ticks[1:], ticks[2:], strict=False):
        # What a poll may read: the rows written since the previous poll began.
        assert all(updated >= since for updated, _ in rows)
    simulation_reads = [
        sum(s.lstrip().upper().startswith("SELECT") and "FROM simulations" in s for s in sql)
        for _, sql, _ in ticks[1:]
    ]
    assert max(simulation_reads) <= 1  # the pending list; never one per polled result
    assert store.get_simulation(store.list_simulations(None, 1, 0).items[0].id).state == TrialState.DONE.value


def test_a_step_longer_than_the_lease_keeps_the_study_with_its_driver(store):
    """The lease is renewed on its own heartbeat: a step that takes several TTLs (a surrogate
    fit, a starved CPU) must not let another replica take a study that is being driven."""
    study = create(store, name="slow")
    ttl = 0.6
    loop = DriverLoop(store, SyntheticExecutor(per_poll=0), DatabaseLeases(store, "slow", ttl_s=ttl),
                      poll_s=0.05, scan_every_s=0.0)
    stepping, release = threading.Event(), threading.Event()
    step = loop.driver.step

    def slow_step(study_id, timeout):
        stepping.set()
        release.wait(10)
        return step(study_id, timeout=timeout)

    loop.driver.step = slow_step
    other = DatabaseLeases(store, "other", ttl_s=ttl)
    loop.start()
    try:
        assert stepping.wait(10)
        time.sleep(4 * ttl)  # several lease periods inside one step
        assert not other.acquire(study), "the lease lapsed while its holder was stepping the study"
        assert study in loop.held
    finally:
        release.set()
        loop.stop(timeout=10)
