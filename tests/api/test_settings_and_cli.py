"""Settings fail early with the variable's name; the CLI explains itself."""

import os
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from api import __version__
from api.cli import app
from api.settings import SettingsError, load_settings


def test_defaults_are_the_embedded_mode(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    settings = load_settings()
    assert settings.database_url.startswith("sqlite")
    assert settings.redis_url is None


def test_bad_database_url_names_the_variable(monkeypatch):
    monkeypatch.setenv("DEMCAL_DATABASE_URL", "mysql://nope")
    with pytest.raises(SettingsError, match="DEMCAL_DATABASE_URL"):
        load_settings()


def test_bad_log_level_names_the_variable(monkeypatch):
    monkeypatch.setenv("DEMCAL_LOG_LEVEL", "LOUD")
    with pytest.raises(SettingsError, match="DEMCAL_LOG_LEVEL"):
        load_settings()


def test_production_refuses_sqlite(monkeypatch):
    monkeypatch.setenv("DEMCAL_ENVIRONMENT", "production")
    with pytest.raises(SettingsError, match="DEMCAL_DATABASE_URL"):
        load_settings()


def test_plain_postgresql_url_uses_psycopg3():
    settings = load_settings(database_url="postgresql://u@h/db")
    assert settings.database_url == "postgresql+psycopg://u@h/db"


def test_version_and_help():
    runner = CliRunner()
    assert __version__ in runner.invoke(app, ["--version"]).output
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "config" in result.output


def test_console_script_reports_bad_setting_and_exits_2(monkeypatch):
    monkeypatch.setenv("DEMCAL_REDIS_URL", "http://example")
    proc = subprocess.run(
        [sys.executable, "-c", "from api.cli import main; main()", "config"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert "DEMCAL_REDIS_URL" in proc.stderr


def test_out_of_date_database_is_a_one_line_error_not_a_traceback(tmp_path):
    import sqlalchemy as sa

    database = tmp_path / "old.db"
    engine = sa.create_engine(f"sqlite:///{database}")
    with engine.begin() as conn:
        conn.execute(sa.text("CREATE TABLE alembic_version (version_num VARCHAR(32) PRIMARY KEY)"))
        conn.execute(sa.text("INSERT INTO alembic_version VALUES ('0001')"))
    engine.dispose()

    proc = subprocess.run(
        [sys.executable, "-c", "from api.cli import main; main()", "apikey", "list"],
        capture_output=True,
        text=True,
        env={**os.environ, "DEMCAL_DATABASE_URL": f"sqlite:///{database}"},
    )

    assert proc.returncode == 2
    assert "demcal db upgrade" in proc.stderr
    assert "Traceback" not in proc.stderr
