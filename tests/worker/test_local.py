"""The local process pool on real trials: results once, cancel, dead workers, clean close."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time

import pytest

from dem.result import SimulationStatus
from optimizer.protocols import TrialSpec
from tests.worker.test_jobs import LONG_SCENARIO, PARAMS, TINY_SCENARIO
from worker.local import LocalPoolExecutor

pytestmark = pytest.mark.slow


def spec(trial: str, scenario=TINY_SCENARIO, timeout_s=None) -> TrialSpec:
    return TrialSpec(trial, "t", 0, 0, 0, 11, PARAMS, scenario, timeout_s)


def collect(executor, count, limit_s=120.0):
    outcomes, end = [], time.monotonic() + limit_s
    while len(outcomes) < count and time.monotonic() < end:
        outcomes += executor.poll(timeout=1.0)
    return outcomes


def wait_running(executor, trial, limit_s=60.0):
    end = time.monotonic() + limit_s
    while trial not in executor.running() and time.monotonic() < end:
        executor.poll(timeout=0.2)
    return executor.running()[trial]


@pytest.fixture(scope="module")
def pool():
    """One pool for the module: starting worker processes is the slow part; every test leaves it
    with nothing in flight, which is itself checked."""
    executor = LocalPoolExecutor(2)
    yield executor
    executor.close()


def test_real_trials_are_reported_once_each(pool):
    pool.submit([spec("a"), spec("b"), spec("c")])
    pool.submit([spec("a")])  # already in flight: a no-op

    outcomes = collect(pool, 3)
    later = pool.poll(timeout=0.5)

    assert sorted(outcome.trial_id for outcome in outcomes) == ["a", "b", "c"]
    assert all(outcome.result.status is SimulationStatus.OK for outcome in outcomes)
    assert later == [] and pool.in_flight() == set()


def test_cancelled_running_trial_is_never_reported(pool):
    pool.submit([spec("long", LONG_SCENARIO)])
    wait_running(pool, "long")

    pool.cancel(["long"])
    outcomes = pool.poll(timeout=1.0)

    assert outcomes == [] and pool.in_flight() == set()


def test_killed_worker_reports_its_trial_as_error_and_the_pool_goes_on(pool):
    pool.submit([spec("victim", LONG_SCENARIO)])
    pid = int(wait_running(pool, "victim").removeprefix("local-"))

    os.kill(pid, signal.SIGKILL)
    [outcome] = collect(pool, 1)
    pool.submit([spec("after")])
    [after] = collect(pool, 1)

    assert outcome.trial_id == "victim"
    assert outcome.result.status is SimulationStatus.ERROR
    assert f"exit code {-signal.SIGKILL}" in outcome.result.message
    assert after.result.status is SimulationStatus.OK
    assert pool.in_flight() == set()


def test_deadline_is_honoured(pool):
    pool.submit([spec("slow", LONG_SCENARIO, timeout_s=2.0)])

    [outcome] = collect(pool, 1, limit_s=60.0)

    assert outcome.result.status is SimulationStatus.TIMEOUT
    assert pool.in_flight() == set()


def test_close_stops_every_process():
    others = set(multiprocessing.active_children())
    executor = LocalPoolExecutor(2)
    executor.submit([spec("long", LONG_SCENARIO), spec("short")])
    wait_running(executor, "long")
    started = set(multiprocessing.active_children()) - others

    executor.close()

    assert len(started) == 2
    assert not any(process.is_alive() for process in started)
