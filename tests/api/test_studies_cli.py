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
    assert json.loads(shown.stdout)["status"] == "created"


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


def test_archive_then_restore_moves_a_study_to_another_database(cli, tmp_path, monkeypatch):
    from api.db import upgrade_database
    from api.settings import get_settings

    runner, store, study_id = cli
    store.set_status(study_id, store.load_study(study_id).status.RUNNING)
    archived = runner.invoke(app, ["studies", "archive", study_id, "-o", str(tmp_path / "a.json")])
    (tmp_path / "other").mkdir()
    monkeypatch.setenv("DEMCAL_DATABASE_URL", f"sqlite:///{tmp_path}/other/demcal.db")
    get_settings.cache_clear()
    upgrade_database(f"sqlite:///{tmp_path}/other/demcal.db")

    restored = runner.invoke(app, ["studies", "restore", str(tmp_path / "a.json")])
    again = runner.invoke(app, ["studies", "restore", str(tmp_path / "a.json")])
    (tmp_path / "x.json").write_text("[1, 2")
    not_json = runner.invoke(app, ["studies", "restore", str(tmp_path / "x.json")])
    missing = runner.invoke(app, ["studies", "restore", str(tmp_path / "nope.json")])
    shown = runner.invoke(app, ["studies", "show", study_id])

    assert archived.exit_code == 0 and "0 trials written" in archived.output, archived.output
    assert restored.exit_code == 0, restored.output
    assert f"demcal calibrate --resume {study_id}" in restored.output
    assert json.loads(shown.stdout)["status"] == "paused" and json.loads(shown.stdout)["name"] == "laptop"
    assert again.exit_code == 2 and "already in this database" in again.output
    assert not_json.exit_code == 2 and "not JSON" in not_json.output
    assert missing.exit_code == 2 and "nope.json" in missing.output


def test_restoring_a_finished_study_points_at_its_results_not_at_resume(cli, tmp_path, monkeypatch):
    from api.db import upgrade_database
    from api.settings import get_settings

    runner, store, study_id = cli
    store.set_status(study_id, store.load_study(study_id).status.DONE)
    runner.invoke(app, ["studies", "archive", study_id, "-o", str(tmp_path / "a.json")])
    (tmp_path / "other").mkdir()
    monkeypatch.setenv("DEMCAL_DATABASE_URL", f"sqlite:///{tmp_path}/other/demcal.db")
    get_settings.cache_clear()
    upgrade_database(f"sqlite:///{tmp_path}/other/demcal.db")

    restored = runner.invoke(app, ["studies", "restore", str(tmp_path / "a.json")])

    assert restored.exit_code == 0, restored.output
    assert "restored, done" in restored.output and f"demcal studies show {study_id}" in restored.output
    assert "--resume" not in restored.output
