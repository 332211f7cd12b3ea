"""Migrations build the schema the models describe, on SQLite and PostgreSQL, both ways; the API
refuses a database that is not at the newest revision; ``demcal db upgrade`` applies them."""

from __future__ import annotations

import re
from pathlib import Path

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
    # The README quotes what it prints, and must keep up with new migrations.
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    quoted = re.search(r'demcal db current +# "([^"]+)"', readme).group(1)
    assert quoted == after.output.strip()
    engine = create_db_engine(url)
    check_schema_current(engine)
    engine.dispose()


def test_0005_carries_n_t_over_into_named_responses(empty_url):
    # A database made by the previous schema (0004), with a finished and a pending trial and a
    # finished single simulation, as a session before named responses would have left it.
    upgrade_database(empty_url, "0004")
    engine = create_db_engine(empty_url)
    now = "2026-11-20 10:00:00"
    trial = (
        "INSERT INTO trials (id, study_id, individual, generation, replicate, seed, params, scenario, "
        "state, status, n_remaining, message, attempts, pareto, created_at, updated_at) VALUES "
        "(:id, 's1', :i, 0, 0, 1, '{}', '{}', :state, :status, :n, '', 0, false, :now, :now)"
    )
    try:
        with engine.begin() as connection:
            _insert_finished_study(connection, now)
            connection.execute(
                sa.text(trial), {"id": "t1", "i": 0, "state": "done", "status": "ok", "n": 4, "now": now}
            )
            connection.execute(
                sa.text(trial),
                {"id": "t2", "i": 1, "state": "pending", "status": None, "n": None, "now": now},
            )
            connection.execute(
                sa.text(
                    "INSERT INTO simulations (id, scenario, params, seed, state, status, n_remaining, "
                    "attempts, created_at, updated_at) "
                    "VALUES ('m1', '{}', '{}', 0, 'done', 'ok', 7, 0, :now, :now)"
                ),
                {"now": now},
            )
        upgrade_database(empty_url)
        with engine.connect() as connection:
            trials = {
                row.id: row
                for row in connection.execute(
                    sa.text("SELECT id, responses, engine, n_remaining FROM trials")
                )
            }
            simulation = connection.execute(sa.text("SELECT responses, engine FROM simulations")).one()
        assert _json(trials["t1"].responses) == {"n_remaining": 4} and trials["t1"].n_remaining == 4
        assert _json(trials["t2"].responses) is None
        assert {row.engine for row in trials.values()} == {"numba"}
        assert _json(simulation.responses) == {"n_remaining": 7} and simulation.engine == "numba"
        # And back: the previous schema again, its N_t untouched.
        downgrade_database(empty_url, "0004")
        with engine.connect() as connection:
            columns = {c["name"] for c in sa.inspect(connection).get_columns("trials")}
            assert "responses" not in columns and "engine" not in columns
            assert connection.execute(sa.text("SELECT n_remaining FROM trials WHERE id = 't1'")).scalar() == 4
    finally:
        engine.dispose()


def test_0009_settles_the_pending_validation_of_studies_that_ended(empty_url):
    # Two studies as the previous revision left them: one cancelled before its validation (its
    # recommendation still "pending"), one searching (its check to come).
    upgrade_database(empty_url, "0008")
    engine = create_db_engine(empty_url)
    study = (
        "INSERT INTO studies (id, name, status, definition, generation, recommendation, message, extra, "
        "created_at, updated_at) VALUES (:id, 'old', :status, '{}', 1, :rec, '', '{}', :now, :now)"
    )
    pending = '{"individual": 3, "validation_status": "pending"}'
    now = "2026-11-23 10:00:00"
    try:
        with engine.begin() as connection:
            for sid, status in (("cancelled", "cancelled"), ("running", "running")):
                connection.execute(
                    sa.text(study), {"id": sid, "status": status, "rec": pending, "now": now}
                )
        upgrade_database(empty_url)
        stored = _studies_column(engine, "recommendation")
        assert stored["cancelled"] == {"individual": 3, "validation_status": "not validated"}
        assert stored["running"] == {"individual": 3, "validation_status": "pending"}
    finally:
        engine.dispose()


def test_0010_copies_each_results_full_load_factor_into_its_trial(empty_url):
    # Three trials as the previous revision left them: a run that stopped early (its result holds
    # a factor), one stored before the factor existed (its result reads 1), one not run yet.
    upgrade_database(empty_url, "0009")
    engine = create_db_engine(empty_url)
    now = "2026-11-24 10:00:00"
    trial = (
        "INSERT INTO trials (id, study_id, individual, generation, replicate, seed, params, scenario, "
        "state, status, wall_time_s, cost, result, message, attempts, pareto, created_at, updated_at) "
        "VALUES (:id, 's1', :i, 0, 0, 1, '{}', '{}', :state, :status, 2.0, 10.0, :result, '', 0, false, "
        ":now, :now)"
    )
    try:
        with engine.begin() as connection:
            _insert_finished_study(connection, now)
            for i, (tid, state, result) in enumerate((
                ("early", "done", '{"status": "ok", "cost": 10.0, "full_load_factor": 2.5}'),
                ("older", "done", '{"status": "ok", "cost": 10.0}'),
                ("pending", "pending", None),
            )):
                status = "ok" if result else None
                connection.execute(
                    sa.text(trial),
                    {"id": tid, "i": i, "state": state, "status": status, "result": result, "now": now},
                )
        upgrade_database(empty_url)
        with engine.connect() as connection:
            factors = dict(connection.execute(sa.text("SELECT id, full_load_factor FROM trials")).all())
        assert factors == {"early": 2.5, "older": 1.0, "pending": 1.0}
        downgrade_database(empty_url, "0009")
        with engine.connect() as connection:
            assert "full_load_factor" not in {c["name"] for c in sa.inspect(connection).get_columns("trials")}
    finally:
        engine.dispose()


def test_0011_gives_a_study_stored_before_common_seeds_the_study_wide_seeds_it_ran_on(empty_url):
    upgrade_database(empty_url, "0010")
    engine = create_db_engine(empty_url)
    study = (
        "INSERT INTO studies (id, name, status, definition, generation, message, extra, created_at, "
        "updated_at) VALUES (:id, 'old', 'paused', :definition, 1, '', '{}', :now, :now)"
    )
    now = "2026-11-25 00:00:00"
    try:
        with engine.begin() as connection:
            for sid, definition in (("old", '{"seed": 7}'), ("new", '{"seed": 7, "common_seeds": "trial"}')):
                connection.execute(sa.text(study), {"id": sid, "definition": definition, "now": now})
        upgrade_database(empty_url)
        stored = _studies_column(engine, "definition")
        assert stored["old"] == {"seed": 7, "common_seeds": "study"}
        assert stored["new"] == {"seed": 7, "common_seeds": "trial"}
        downgrade_database(empty_url, "0010")
        assert list(_studies_column(engine, "definition").values()) == [{"seed": 7}, {"seed": 7}]
    finally:
        engine.dispose()


def _insert_finished_study(connection, now: str) -> None:
    """Study 's1', done, with the columns every revision since 0004 has: the trials' parent row."""
    connection.execute(
        sa.text(
            "INSERT INTO studies (id, name, status, definition, generation, message, extra, "
            "created_at, updated_at) VALUES ('s1', 'old', 'done', '{}', 1, '', '{}', :now, :now)"
        ),
        {"now": now},
    )


def _studies_column(engine: sa.Engine, column: str) -> dict:
    """Study id -> one JSON column of the studies table, read back by raw SQL."""
    with engine.connect() as connection:
        rows = connection.execute(sa.text(f"SELECT id, {column} FROM studies"))
        return {row[0]: _json(row[1]) for row in rows}


def _json(value):
    """A JSON column as read back by raw SQL: a dict on PostgreSQL, text on SQLite."""
    import json

    return json.loads(value) if isinstance(value, str) else value
