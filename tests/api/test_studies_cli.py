"""``demcal studies``: list, show, pause, resume, cancel and export studies without a server."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from api.cli import app
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


@pytest.fixture
def cli(tmp_path, monkeypatch):
    """The CLI on a migrated SQLite file holding one study; yields (runner, store, study id)."""
    from api.db import create_db_engine, upgrade_database
    from api.settings import get_settings
    from api.store import SqlStore

    url = f"sqlite:///{tmp_path}/demcal.db"
    monkeypatch.setenv("DEMCAL_DATABASE_URL", url)
    get_settings.cache_clear()
    upgrade_database(url)
    store = SqlStore(create_db_engine(url))
    definition = StudyDefinition.model_validate(study_definition(name="laptop"))
    yield CliRunner(), store, store.create_study(definition.model_dump(mode="json"), None)
    get_settings.cache_clear()


def test_list_and_show_read_the_database(cli):
    runner, _, study_id = cli

    listed = runner.invoke(app, ["studies", "list"])
    shown = runner.invoke(app, ["studies", "show", study_id])

    assert listed.exit_code == 0, listed.output
    assert study_id in listed.output and "laptop" in listed.output and "0/14" in listed.output
    assert json.loads(shown.output)["status"] == "created"


def test_pause_resume_cancel_follow_the_apis_rules(cli):
    runner, store, study_id = cli

    outputs = [runner.invoke(app, ["studies", action, study_id]) for action in ("pause", "pause")]
    resumed = runner.invoke(app, ["studies", "resume", study_id])
    cancelled = runner.invoke(app, ["studies", "cancel", study_id])

    assert (outputs[0].exit_code, outputs[1].exit_code) == (0, 2)
    assert "possible now: resume, cancel" in outputs[1].output
    assert resumed.exit_code == 0 and cancelled.exit_code == 0
    assert store.load_study(study_id).status.value == "cancelled"


def test_export_writes_the_trials_csv_and_an_unknown_id_exits_2(cli, tmp_path):
    runner, _, study_id = cli

    exported = runner.invoke(app, ["studies", "export", study_id, "-o", str(tmp_path / "t.csv")])
    unknown = runner.invoke(app, ["studies", "show", "st-nope"])

    assert exported.exit_code == 0, exported.output
    assert (tmp_path / "t.csv").read_text().startswith("trial_id,generation,individual")
    assert unknown.exit_code == 2 and "demcal studies list" in unknown.output
