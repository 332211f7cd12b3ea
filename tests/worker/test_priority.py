"""Workers compute DEM below the API's CPU priority (``worker/priority.py``): the local pool's
processes and ``demcal worker`` raise their nice value by ``DEMCAL_WORKER_NICE``, so that an
open dashboard stays responsive while they run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.worker.test_local import collect, spec
from worker.local import LocalPoolExecutor
from worker.priority import DEFAULT_NICE

pytestmark = pytest.mark.slow


def _nice(pid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, pid)


def test_local_pool_processes_run_below_the_service_priority():
    executor = LocalPoolExecutor(1, nice=7)
    try:
        executor.submit([spec("a")])
        outcomes = collect(executor, 1)
        (slot,) = executor._slots

        worker_nice = _nice(slot.process.pid)
    finally:
        executor.close()

    assert [outcome.trial_id for outcome in outcomes] == ["a"]
    assert worker_nice == min(_nice(0) + 7, 19)


def test_demcal_worker_lowers_its_priority_by_the_setting(redis_url):
    env = dict(os.environ, DEMCAL_REDIS_URL=redis_url, DEMCAL_LOG_LEVEL="WARNING")
    worker = subprocess.Popen(
        [str(Path(sys.executable).with_name("demcal")), "worker", "--name", "nice-check"], env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30
        while _nice(worker.pid) == _nice(0) and worker.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)

        worker_nice = _nice(worker.pid)
    finally:
        worker.send_signal(signal.SIGTERM)
        try:
            worker.wait(timeout=60)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait()

    assert worker_nice == min(_nice(0) + DEFAULT_NICE, 19)
