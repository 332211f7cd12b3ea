"""Fixtures for API and store tests, each run on SQLite and on PostgreSQL (a real server).

The schema always comes from the migrations, as in production. SQLite: one database is
migrated per session and copied for each test (a clean file per test). PostgreSQL: the session's
database is migrated once and every table is emptied before each test.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from api.app import create_app
from api.auth import create_key
from api.db import create_db_engine, current_revision, head_revision, upgrade_database
from api.models import Base
from api.settings import load_settings
from api.store import SqlStore

MEASURED = [3, 4, 4, 2, 5, 3, 4, 6, 3, 4]


@pytest.fixture(scope="session")
def sqlite_template(tmp_path_factory):
    path = tmp_path_factory.mktemp("template") / "template.db"
    upgrade_database(f"sqlite:///{path}")
    return path


def _empty_postgres(url: str) -> None:
    engine = create_db_engine(url)
    try:
        if current_revision(engine) != head_revision():
            upgrade_database(url)
        tables = ", ".join(table.name for table in Base.metadata.sorted_tables)
        with engine.begin() as connection:
            connection.execute(sa.text(f"TRUNCATE {tables} RESTART IDENTITY CASCADE"))
    finally:
        engine.dispose()


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def database_url(request, tmp_path, sqlite_template):
    """A migrated, empty database: a SQLite file, or the session's PostgreSQL database."""
    if request.param == "sqlite":
        path = tmp_path / "demcal.db"
        shutil.copy(sqlite_template, path)
        return f"sqlite:///{path}"
    url = request.getfixturevalue("postgres_url")
    _empty_postgres(url)
    return url


@pytest.fixture
def engine(database_url):
    engine = create_db_engine(database_url)
    yield engine
    engine.dispose()


@pytest.fixture
def store(engine):
    return SqlStore(engine)


@dataclass
class Keys:
    alice: str
    bob: str
    admin: str
    alice_id: int

    def auth(self, who: str = "alice") -> dict[str, str]:
        return {"Authorization": f"Bearer {getattr(self, who)}"}


@pytest.fixture
def keys(store) -> Keys:
    with store.session() as session:
        alice_row, alice = create_key(session, "alice")
        _, bob = create_key(session, "bob")
        _, admin = create_key(session, "root", admin=True)
        alice_id = alice_row.id
    return Keys(alice=alice, bob=bob, admin=admin, alice_id=alice_id)


@pytest.fixture
def settings(database_url, tmp_path):
    return load_settings(
        database_url=database_url, data_dir=tmp_path / "data", max_population=100, max_simulations=2000,
        max_request_bytes=64_000, max_upload_bytes=200_000,
        view_processes=0,  # views built in place; test_view_processes.py builds them in processes
    )


@pytest.fixture
def client(settings, engine):
    with TestClient(create_app(settings, engine=engine)) as client:
        yield client


def study_definition(**overrides) -> dict:
    """A small valid study as a client would POST it."""
    definition = {
        "name": "quick",
        "scenario": {},
        "experiment": {"measured": MEASURED},
        "ga": {"population": 6, "offspring": 4, "generations": 2},
        "validation": {"seeds": 0},  # the counts below stay the search's; validation has its tests
    }
    definition.update(overrides)
    return definition
