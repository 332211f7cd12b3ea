"""A Redis restart under a busy worker: a real ``redis-server`` of the test's own is shut down
while a real ``demcal worker`` runs a trial, and started again (empty) a few seconds later. The
worker must ride the outage out: the trial's result arrives as a result (never an ``error`` made
of the outage), and the same worker takes the next trial."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import redis

from optimizer.protocols import TrialSpec
from tests.e2e.conftest import DEMCAL, free_port, tiny_scenario, wait_for
from worker.rq_executor import RqExecutor

pytestmark = [pytest.mark.redis, pytest.mark.slow]

PARAMS = {"E": 5e6, "nu": 0.3, "e": 0.5, "mu": 0.5}


class OwnRedis:
    """A throw-away redis-server (no persistence): a restart loses everything, like a crash."""

    def __init__(self, workdir: Path) -> None:
        self.port = free_port()
        self.workdir = workdir
        self.process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        self.process = subprocess.Popen(
            [shutil.which("redis-server") or "redis-server", "--port", str(self.port), "--save", "",
             "--appendonly", "no", "--dir", str(self.workdir)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        wait_for(self._up, 10, "redis-server to answer")

    def _up(self) -> bool:
        client = redis.Redis(port=self.port, socket_connect_timeout=0.5)
        try:
            return bool(client.ping())
        except redis.exceptions.ConnectionError:
            return False
        finally:
            client.close()

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            self.process.wait(10)


def spec(trial: str, vibration_time: float = 2.5) -> TrialSpec:
    scenario = tiny_scenario()
    scenario["stages"]["vibration_time"] = vibration_time
    return TrialSpec(trial, "st-restart", 0, 0, 0, 3, PARAMS, scenario)


def test_a_busy_worker_survives_a_redis_restart_and_its_result_is_not_an_error(tmp_path):
    server = OwnRedis(tmp_path)
    server.start()
    log = (tmp_path / "worker.log").open("w")
    worker = subprocess.Popen(
        [*DEMCAL, "worker", "--name", "w-restart", "--heartbeat", "1"],
        env={
            **{key: value for key, value in os.environ.items() if not key.startswith("DEMCAL_")},
            "DEMCAL_REDIS_URL": server.url, "DEMCAL_QUEUE_NAME": "restart",
            "DEMCAL_DATA_DIR": str(tmp_path / "data"),
        },
        stdout=log, stderr=subprocess.STDOUT,
    )
    executor = RqExecutor.from_url(server.url, "restart")
    try:
        # Long enough (60 s simulated, about 20 s of wall) that the outage falls inside the run:
        # at 10 s, session 11's engine speed-ups ended it (3.1 s) before Redis went away, and the
        # restart lost its delivered result. The check before the stop says so if it happens again.
        executor.submit([spec("st-restart-i00000-r00", vibration_time=60.0)])
        started = lambda: "st-restart-i00000-r00: started" in (tmp_path / "worker.log").read_text()  # noqa: E731
        wait_for(started, 300, "the worker to start the trial")
        time.sleep(1.0)
        assert "st-restart-i00000-r00: ok" not in (tmp_path / "worker.log").read_text(), (
            "the trial ended before the outage: lengthen its vibration_time"
        )

        server.stop()  # Redis gone mid-trial: the cancellation check and delivery must wait
        time.sleep(3.5)
        server.start()  # back, and empty
        executor.watch(["st-restart"])

        first = wait_for(lambda: executor.poll(timeout=1.0), 180, "the trial's result after the restart")
        assert worker.poll() is None, "the worker exited during the Redis restart"
        assert [outcome.result.status.value for outcome in first] == ["ok"], first[0].result.message

        executor.submit([spec("st-restart-i00001-r00")])
        second = wait_for(lambda: executor.poll(timeout=1.0), 180, "a second trial on the same worker")
        assert [outcome.trial_id for outcome in second] == ["st-restart-i00001-r00"]
    finally:
        executor.close()
        with contextlib.suppress(Exception):
            worker.terminate()
            worker.wait(30)
        if worker.poll() is None:
            worker.kill()
        log.close()
        server.stop()
        print((tmp_path / "worker.log").read_text()[-3000:])
