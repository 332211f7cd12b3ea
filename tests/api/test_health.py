"""``/healthz`` with the RQ queue: work waiting and no worker to do it is not "ok"."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from api.settings import load_settings
from optimizer.protocols import TrialSpec
from worker.rq_executor import RqExecutor

pytestmark = pytest.mark.redis


@pytest.fixture
def queued_client(database_url, engine, redis_url, tmp_path):
    settings = load_settings(
        database_url=database_url, data_dir=tmp_path / "data", redis_url=redis_url, queue_name="health"
    )
    with TestClient(create_app(settings, engine=engine)) as client:
        yield client, RqExecutor.from_url(redis_url, "health")


def test_health_is_503_with_the_reason_when_jobs_wait_and_no_worker_runs(queued_client):
    client, executor = queued_client
    assert client.get("/healthz").status_code == 200  # an idle queue without workers is fine

    executor.submit([TrialSpec("st-h-i00000-r00", "st-h", 0, 0, 0, 1, {"E": 1e7}, {})])
    response = client.get("/healthz")

    assert response.status_code == 503, response.text
    body = response.json()
    assert (body["status"], body["workers"], body["queued"]) == ("degraded", 0, 1)
    assert "no worker" in body["problem"]
    executor.close()
