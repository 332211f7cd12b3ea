"""SIGTERM to ``demcal serve`` on the embedded local pool: the server exits and takes its worker
processes with it, even while they compute (none keeps running after the server is gone)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from tests.e2e.conftest import DEMCAL, descendants, free_port, tiny_study, wait_for

pytestmark = pytest.mark.slow


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_sigterm_to_serve_stops_its_busy_local_workers(tmp_path):
    port = free_port()
    env = {
        **{key: value for key, value in os.environ.items() if not key.startswith("DEMCAL_")},
        "DEMCAL_DATABASE_URL": f"sqlite:///{tmp_path}/demcal.db",
        "DEMCAL_DATA_DIR": str(tmp_path / "data"),
        "DEMCAL_PORT": str(port),
        "DEMCAL_WORKERS": "2",
    }
    subprocess.run([*DEMCAL, "db", "upgrade"], env=env, cwd=tmp_path, check=True, capture_output=True)
    token = subprocess.run(
        [*DEMCAL, "apikey", "create", "--owner", "me", "--admin"], env=env, cwd=tmp_path, check=True,
        capture_output=True, text=True,
    ).stdout.strip().splitlines()[-1]
    log = (tmp_path / "serve.log").open("w")
    workers: list[int] = []
    serve = subprocess.Popen([*DEMCAL, "serve"], env=env, cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT)
    try:
        base = f"http://127.0.0.1:{port}"
        wait_for(lambda: _up(base), 60, "serve to answer")
        study = tiny_study("shutdown", population=4, generations=0)
        study["scenario"]["stages"]["vibration_time"] = 600.0  # busy for far longer than the test
        auth = {"Authorization": f"Bearer {token}"}
        # Generous: what this test checks is the shutdown; the creation builds the items' clumps
        # for the validity estimate, which once took over 60 s at a loaded CI's start.
        try:
            created = httpx.post(f"{base}/api/v1/studies", json=study, headers=auth, timeout=180)
        except httpx.TimeoutException:
            log.flush()
            pytest.fail("creating the study timed out; serve's log:\n" + _tail(tmp_path / "serve.log"))
        assert created.status_code == 201, created.text
        busy = lambda: len(descendants(serve.pid)) >= 2 and descendants(serve.pid)  # noqa: E731
        workers = wait_for(busy, 120, "the local workers")
        study_url = f"{base}/api/v1/studies/{created.json()['id']}"
        running = lambda: httpx.get(study_url, headers=auth, timeout=30).json()["progress"][  # noqa: E731
            "trials_by_state"
        ].get("running", 0) >= 2
        wait_for(running, 300, "both workers to compute a trial (after their warm-up)")
        time.sleep(2.0)

        serve.send_signal(signal.SIGTERM)
        assert serve.wait(60) == 0

        time.sleep(2.0)
        assert [pid for pid in workers if alive(pid)] == [], "local workers outlived serve"
    finally:
        if serve.poll() is None:
            serve.kill()
        for pid in workers:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        log.close()


def _tail(path: Path, lines: int = 40) -> str:
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])


def _up(base: str) -> bool:
    try:
        return httpx.get(f"{base}/healthz", timeout=2).status_code == 200
    except httpx.HTTPError:
        return False
