"""Whole-system fixtures: real PostgreSQL, real Redis, and real ``demcal serve`` and
``demcal worker`` processes started the way an operator starts them.

Each test gets a fresh database (a copy of one migrated with ``demcal db upgrade``), the
dedicated Redis test database (flushed) and a queue of its own. Time constants are shortened
through the same settings and options an operator has (reconciliation every 2 s, study leases of
4 s, worker heartbeats every second), so that recoveries happen within seconds.
"""

from __future__ import annotations

import contextlib
import copy
import os
import signal
import socket
import subprocess
import sys
import time
import tomllib
import uuid
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
import redis
import sqlalchemy as sa

ROOT = Path(__file__).resolve().parents[2]
# The console script installed beside this interpreter: what an operator runs.
DEMCAL = [str(Path(sys.executable).with_name("demcal"))]
MEASURED = [2, 2, 3, 1, 2, 2, 3, 2, 2, 1]

# A feeder reduced to about two seconds of computation per trial: one camera on the quick
# example's tray, shaken gently (below lift-off) for 2.5 s. The step is forced to a value that
# divides the stage times exactly, which also keeps the run clear of the sub-step remainder at
# the end of a stage.
TINY_SCENARIO_CHANGES = {
    "items": {"counts": {"camera": 1}},
    "stages": {"insertion_time": 0.1, "vibration_start": 0.5, "vibration_time": 2.5},
    "vibration": {"frequency": 10.0, "amplitude": 1e-3},
    "run": {"dt": 2.5e-6, "stop_when_empty": False},
}


def tiny_scenario() -> dict:
    with (ROOT / "examples" / "feeder-quick.toml").open("rb") as handle:
        scenario = tomllib.load(handle)
    for section, values in TINY_SCENARIO_CHANGES.items():
        scenario[section] = {**scenario.get(section, {}), **copy.deepcopy(values)}
    return scenario


def tiny_study(name: str, *, population: int = 4, offspring: int = 2, generations: int = 1, **extra) -> dict:
    """A study of ``population + generations x offspring`` trials on the tiny feeder."""
    return {
        "name": name,
        "scenario": tiny_scenario(),
        "experiment": {"measured": MEASURED},
        "parameters": {"E": {"low": 1e6, "high": 1e7}},
        "ga": {"population": population, "offspring": offspring, "generations": generations},
        "validation": {"seeds": 0},  # the counts are the search's; the validation has its own tests
        "seed": 7,
        **extra,
    }


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (an RQ work horse runs in its own process group)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def wait_for(check: Callable[[], object], timeout: float, what: str, every: float = 0.25):
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(every)


class Cluster:
    """The processes of one deployment, their logs, and an HTTP client with an API key."""

    def __init__(self, workdir: Path, database_url: str, redis_url: str) -> None:
        self.workdir = workdir
        self.redis_url = redis_url
        self.redis = redis.Redis.from_url(redis_url)
        self.port = free_port()
        self.queue = f"e2e-{uuid.uuid4().hex[:8]}"
        self.env = {
            **{key: value for key, value in os.environ.items() if not key.startswith("DEMCAL_")},
            "DEMCAL_DATABASE_URL": database_url,
            "DEMCAL_REDIS_URL": redis_url,
            "DEMCAL_QUEUE_NAME": self.queue,
            "DEMCAL_PORT": str(self.port),
            "DEMCAL_DATA_DIR": str(workdir / "data"),
            "DEMCAL_RECONCILE_INTERVAL_S": "2",
            "DEMCAL_LEASE_TTL_S": "4",
            "DEMCAL_LOG_LEVEL": "INFO",
        }
        self.processes: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.token = self.run("apikey", "create", "--owner", "e2e", "--admin").stdout.strip().splitlines()[-1]
        self.http = self._client(self.port)
        self._clients: dict[int, httpx.Client] = {self.port: self.http}

    def _client(self, port: int) -> httpx.Client:
        return httpx.Client(
            base_url=f"http://127.0.0.1:{port}/api/v1",
            headers={"Authorization": f"Bearer {self.token}"},
            timeout=30,
        )

    def api(self, port: int | None = None) -> httpx.Client:
        """The API of the replica listening on ``port`` (the first one by default)."""
        port = port or self.port
        if port not in self._clients:
            self._clients[port] = self._client(port)
        return self._clients[port]

    def run(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [*DEMCAL, *args], cwd=self.workdir, env=self.env, capture_output=True, text=True, check=True
        )

    def start(
        self, name: str, *args: str, cwd: Path | None = None, env: dict | None = None
    ) -> subprocess.Popen:
        log = self.workdir / f"{name}.log"
        handle = log.open("a")
        process = subprocess.Popen(
            [*DEMCAL, *args], cwd=cwd or self.workdir, env={**self.env, **(env or {})}, stdout=handle,
            stderr=subprocess.STDOUT,
        )
        handle.close()
        self.processes[name], self.logs[name] = process, log
        return process

    def start_serve(self, name: str = "serve", port: int | None = None) -> subprocess.Popen:
        """``demcal serve`` on the cluster's port, or (another replica) on ``port``."""
        process = self.start(name, "serve", env={"DEMCAL_PORT": str(port)} if port else None)
        wait_for(lambda: self._healthy(port or self.port), 60, f"{name} to answer /healthz")
        return process

    def start_worker(
        self, name: str, data_dir: Path | None = None, max_jobs: int | None = None
    ) -> subprocess.Popen:
        """``demcal worker``; ``data_dir`` gives it a data directory of its own (another machine's),
        ``max_jobs`` makes it exit after that many trials."""
        env = {"DEMCAL_DATA_DIR": str(data_dir)} if data_dir else None
        extra = ("--max-jobs", str(max_jobs)) if max_jobs else ()
        return self.start(name, "worker", "--name", name, "--heartbeat", "1", *extra, env=env)

    def _healthy(self, port: int) -> bool:
        try:
            return httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    def kill(self, name: str) -> None:
        """SIGKILL a process and everything it started: a machine lost, not a polite stop."""
        process = self.processes[name]
        for pid in [process.pid, *descendants(process.pid)]:
            with contextlib.suppress(ProcessLookupError):  # already gone
                os.kill(pid, signal.SIGKILL)
        process.wait(10)

    def stop(self, name: str, timeout: float = 60) -> int:
        process = self.processes[name]
        process.send_signal(signal.SIGTERM)
        return process.wait(timeout)

    def close(self) -> None:
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for name in list(self.processes):
            if self.processes[name].poll() is None:
                try:
                    self.processes[name].wait(15)
                except subprocess.TimeoutExpired:
                    self.kill(name)
        for client in self._clients.values():
            client.close()
        self.redis.close()

    def log_tail(self, lines: int = 40) -> str:
        parts = []
        for name, path in self.logs.items():
            text = path.read_text(errors="replace").splitlines()[-lines:]
            parts.append(f"----- {name} -----\n" + "\n".join(text))
        return "\n".join(parts)

    # -- the API as a client sees it ----------------------------------------------------------

    def create_study(self, definition: dict, via: int | None = None) -> str:
        response = self.api(via).post("/studies", json=definition)
        assert response.status_code == 201, response.text
        return response.json()["id"]

    def study(self, study_id: str) -> dict:
        response = self.http.get(f"/studies/{study_id}")
        response.raise_for_status()
        return response.json()

    def trials(self, study_id: str, via: int | None = None) -> list[dict]:
        response = self.api(via).get(f"/studies/{study_id}/trials", params={"limit": 5000})
        response.raise_for_status()
        return response.json()["items"]

    def wait_until_done(self, study_id: str, timeout: float = 300) -> dict:
        def finished():
            study = self.study(study_id)
            return study if study["status"] in ("done", "failed", "cancelled") else None

        try:
            return wait_for(finished, timeout, f"study {study_id} to finish", every=0.5)
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n{self.log_tail()}") from None

    def worker_busy(self, name: str) -> str | None:
        """The trial the named worker is running now, if any (from RQ's worker record)."""
        job = self.redis.hget(f"rq:worker:{name}", "current_job")
        return job.decode() if job else None


@pytest.fixture(scope="session")
def migrated_template(postgres_url):
    """A database migrated by `demcal db upgrade`, used as the template of each test's database."""
    url = sa.make_url(postgres_url)
    template = f"{url.database}_e2e"
    admin = sa.create_engine(url, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(sa.text(f'CREATE DATABASE "{template}"'))
    template_url = url.set(database=template).render_as_string(hide_password=False)
    env = {**os.environ, "DEMCAL_DATABASE_URL": template_url}
    subprocess.run([*DEMCAL, "db", "upgrade"], env=env, check=True, capture_output=True)
    yield admin, url, template
    with admin.connect() as connection:
        connection.execute(sa.text(f'DROP DATABASE IF EXISTS "{template}" WITH (FORCE)'))
    admin.dispose()


@pytest.fixture
def database_url(migrated_template):
    admin, url, template = migrated_template
    name = f"{template}_{uuid.uuid4().hex[:8]}"
    with admin.connect() as connection:
        connection.execute(sa.text(f'CREATE DATABASE "{name}" TEMPLATE "{template}"'))
    yield url.set(database=name).render_as_string(hide_password=False)
    with admin.connect() as connection:
        connection.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))


@pytest.fixture
def cluster(tmp_path, database_url, redis_url):
    deployment = Cluster(tmp_path, database_url, redis_url)
    yield deployment
    deployment.close()
