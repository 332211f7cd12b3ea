"""Fixtures for real services and programs: a fresh PostgreSQL database per test session, a
dedicated, flushed Redis database, and Debian's LIGGGHTS (Chromium: ``tests/dashboard``).

With ``CI=true`` a missing one fails the test (``.ci/run`` provides them all); elsewhere it skips
with a reason that says how to provide it (``DEMCAL_TEST_DATABASE_URL`` /
``DEMCAL_TEST_REDIS_URL``, or the Debian package), so the README's test command passes on a
fresh machine.
"""

from __future__ import annotations

import os
import uuid

import pytest

DEFAULT_TEST_DATABASE_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
DEFAULT_TEST_REDIS_URL = "redis://127.0.0.1:6379/13"
# The fields of a SimulationResult that depend only on the parameters and the seed (not on the
# machine, the worker or the run's history): two runs of one spec agree on all of them.
DETERMINISTIC_RESULT_FIELDS = frozenset(
    {"status", "n_items", "n_remaining", "discharge_times", "emptied_at", "sim_time", "steps", "cost"}
)


def _in_ci() -> bool:
    return os.environ.get("CI", "").lower() in ("1", "true", "yes")


def missing(what: str, reason: str) -> None:
    """A test's prerequisite is missing: fail with CI=true, else skip with the reason."""
    if _in_ci():
        pytest.fail(f"CI=true requires {what}: {reason}")
    pytest.skip(reason)


def _unavailable(service: str, variable: str, exc: Exception) -> None:
    missing(
        service,
        f"{service} is not reachable ({exc.__class__.__name__}: {exc}); start it or point {variable} at one",
    )


@pytest.fixture(scope="session")
def liggghts() -> None:
    """The LIGGGHTS engine can run here: its own check (``dem/engines/liggghts.py``: the binary on
    the PATH or ``DEMCAL_LIGGGHTS``), so the tests skip exactly where the engine would refuse."""
    from dem.engines.base import get_engine

    reason = get_engine("liggghts").unavailable()
    if reason:
        missing("LIGGGHTS", f"{reason} (see .ci/run)")


@pytest.fixture(scope="session")
def postgres_url():
    """URL of a database created for this test session and dropped afterwards."""
    import sqlalchemy as sa

    base_url = sa.make_url(os.environ.get("DEMCAL_TEST_DATABASE_URL", DEFAULT_TEST_DATABASE_URL))
    if base_url.drivername == "postgresql":
        base_url = base_url.set(drivername="postgresql+psycopg")
    admin = sa.create_engine(base_url, isolation_level="AUTOCOMMIT", connect_args={"connect_timeout": 5})
    name = f"demcal_test_{uuid.uuid4().hex[:12]}"
    try:
        with admin.connect() as conn:
            conn.execute(sa.text(f'CREATE DATABASE "{name}"'))
    except Exception as exc:  # noqa: BLE001 - any connection failure means "no server"
        admin.dispose()
        _unavailable("PostgreSQL", "DEMCAL_TEST_DATABASE_URL", exc)
    try:
        yield base_url.set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as conn:
            conn.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


@pytest.fixture(scope="session")
def redis_server_url():
    """URL of the dedicated Redis database for tests (session scope, reachable)."""
    import redis

    url = os.environ.get("DEMCAL_TEST_REDIS_URL", DEFAULT_TEST_REDIS_URL)
    try:
        client = redis.Redis.from_url(url, socket_connect_timeout=5)
        client.ping()
        client.close()
    except Exception as exc:  # noqa: BLE001
        _unavailable("Redis", "DEMCAL_TEST_REDIS_URL", exc)
    return url


@pytest.fixture
def redis_url(redis_server_url):
    """The dedicated Redis database, flushed before and after the test."""
    import redis

    client = redis.Redis.from_url(redis_server_url)
    client.flushdb()
    yield redis_server_url
    client.flushdb()
    client.close()
