"""``GET /healthz`` answers 503 with what is wrong when a component it depends on is gone: a
real Redis server stopped under a running app, a real PostgreSQL database dropped under it."""

from __future__ import annotations

import socket
import subprocess
import time
import uuid

import pytest
import redis
import sqlalchemy as sa
from fastapi.testclient import TestClient

from api.app import create_app
from api.db import create_db_engine, upgrade_database
from api.settings import load_settings


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def own_redis(tmp_path):
    """A redis-server of this test's own, so that stopping it disturbs nobody else."""
    port = _free_port()
    process = subprocess.Popen(
        ["redis-server", "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
         "--dir", str(tmp_path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    url = f"redis://127.0.0.1:{port}/0"
    deadline = time.monotonic() + 10
    while True:
        try:
            redis.Redis.from_url(url).ping()
            break
        except redis.ConnectionError:
            if time.monotonic() > deadline:
                process.kill()
                pytest.fail(f"redis-server on port {port} did not start")
            time.sleep(0.05)
    yield process, url
    if process.poll() is None:
        process.kill()
    process.wait(10)


def test_healthz_is_503_naming_redis_when_the_redis_server_stops(tmp_path, own_redis):
    process, redis_url = own_redis
    url = f"sqlite:///{tmp_path / 'demcal.db'}"
    upgrade_database(url)
    settings = load_settings(database_url=url, redis_url=redis_url, data_dir=tmp_path / "data")
    engine = create_db_engine(url)
    try:
        with TestClient(create_app(settings, engine=engine)) as client:
            up = client.get("/healthz")
            process.terminate()
            process.wait(10)
            down = client.get("/healthz")
    finally:
        engine.dispose()

    assert up.status_code == 200, up.text
    assert (up.json()["status"], up.json()["redis"]) == ("ok", "ok")
    assert down.status_code == 503, down.text
    assert down.json()["status"] == "degraded"
    assert down.json()["redis"].startswith("error")
    assert down.json()["database"] == "ok"


@pytest.mark.postgres
def test_healthz_is_503_naming_the_database_when_it_is_dropped(tmp_path, postgres_url):
    base = sa.make_url(postgres_url)
    url = base.set(database=f"{base.database}_health_{uuid.uuid4().hex[:6]}")
    admin = sa.create_engine(base, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(sa.text(f'CREATE DATABASE "{url.database}"'))
    rendered = url.render_as_string(hide_password=False)
    try:
        upgrade_database(rendered)
        settings = load_settings(database_url=rendered, data_dir=tmp_path / "data")
        engine = create_db_engine(rendered)
        with TestClient(create_app(settings, engine=engine)) as client:
            up = client.get("/healthz")
            with admin.connect() as connection:
                connection.execute(sa.text(f'DROP DATABASE "{url.database}" WITH (FORCE)'))
            down = client.get("/healthz")
        engine.dispose()
    finally:
        with admin.connect() as connection:
            connection.execute(sa.text(f'DROP DATABASE IF EXISTS "{url.database}" WITH (FORCE)'))
        admin.dispose()

    assert up.status_code == 200, up.text
    assert down.status_code == 503, down.text
    assert down.json()["status"] == "degraded"
    assert down.json()["database"].startswith("error")
    assert down.json()["redis"] == "not configured"
