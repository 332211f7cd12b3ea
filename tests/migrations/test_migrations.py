"""Migrations build the schema the models describe, on SQLite and PostgreSQL, both ways; the API
refuses a database that is not at the newest revision; ``demcal db upgrade`` applies them."""

from __future__ import annotations

import pytest
import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from typer.testing import CliRunner

from api.db import (
    SchemaOutOfDateError,
    check_schema_current,
    create_db_engine,
    current_revision,
    downgrade_database,
    head_revision,
    upgrade_database,
)
from api.models import Base


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def empty_url(request, tmp_path):
    """A database with no demcal schema."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'empty.db'}"
        return
    url = request.getfixturevalue("postgres_url")
    downgrade_database(url, "base")
    yield url
    # Leave the session's database migrated for the API tests that share it.
    upgrade_database(url)


def _schema_differences(engine: sa.Engine) -> list:
    with engine.connect() as connection:
        context = MigrationContext.configure(connection, opts={"compare_type": True})
        return compare_metadata(context, Base.metadata)


def test_upgrade_from_empty_builds_the_models_schema(empty_url):
    upgrade_database(empty_url)

    engine = create_db_engine(empty_url)
    try:
        assert current_revision(engine) == head_revision()
        assert _schema_differences(engine) == []
    finally:
        engine.dispose()


def test_downgrade_then_upgrade_round_trips(empty_url):
    upgrade_database(empty_url)
    downgrade_database(empty_url, "base")
    engine = create_db_engine(empty_url)
    try:
        emptied = set(sa.inspect(engine).get_table_names()) - {"alembic_version"}

        upgrade_database(empty_url)

        assert emptied == set()
        assert _schema_differences(engine) == []
    finally:
        engine.dispose()


def test_out_of_date_schema_is_refused_with_the_command_to_run(empty_url):
    from api.app import create_app
    from api.settings import load_settings

    settings = load_settings(database_url=empty_url)

    with pytest.raises(SchemaOutOfDateError, match="demcal db upgrade"):
        create_app(settings)


def test_db_upgrade_command_migrates_the_configured_database(tmp_path, monkeypatch):
    from api.cli import app
    from api.settings import get_settings

    url = f"sqlite:///{tmp_path / 'cli.db'}"
    monkeypatch.setenv("DEMCAL_DATABASE_URL", url)
    get_settings.cache_clear()
    runner = CliRunner()
    try:
        before = runner.invoke(app, ["db", "current"])
        upgraded = runner.invoke(app, ["db", "upgrade"])
        after = runner.invoke(app, ["db", "current"])
    finally:
        get_settings.cache_clear()

    assert before.exit_code == 1 and "demcal db upgrade" in before.output
    assert upgraded.exit_code == 0, upgraded.output
    assert after.exit_code == 0 and "up to date" in after.output
    engine = create_db_engine(url)
    check_schema_current(engine)
    engine.dispose()
