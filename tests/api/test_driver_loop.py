"""The driver loop of ``demcal serve`` (``api/driver_loop.py``) on the real store: one study's
failure fails that study only, and cancel, pause and delete withdraw the work from the executor
(the RQ queue on the real Redis, the local process pool)."""

from __future__ import annotations

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
