"""One driver per study (``api/store/leases.py``): the lease ``demcal serve`` and
``demcal calibrate`` both take in the database, on SQLite and PostgreSQL."""

from __future__ import annotations

import time

import pytest
from typer.testing import CliRunner

from api.cli import app
from api.store.leases import DatabaseLeases
from optimizer.protocols import StudyStatus
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


def create(store) -> str:
    definition = StudyDefinition.model_validate(study_definition())
    return store.create_study(definition.model_dump(mode="json"), None)


def test_only_one_process_holds_a_studys_lease(store):
    study_id = create(store)
    serve, calibrate = DatabaseLeases(store, "serve-a"), DatabaseLeases(store, "calibrate-b")

    taken = [serve.acquire(study_id), calibrate.acquire(study_id), calibrate.renew(study_id)]

    assert taken == [True, False, False]
    assert calibrate.holder(study_id)[0] == "serve-a"


def test_an_expired_lease_goes_to_the_next_process_and_the_old_holder_knows(store):
    study_id = create(store)
    dead, alive = DatabaseLeases(store, "dead", ttl_s=0.2), DatabaseLeases(store, "alive")
    assert dead.acquire(study_id)

    time.sleep(0.4)

    assert alive.acquire(study_id)
    assert not dead.renew(study_id)


def test_release_frees_the_study_and_leases_leave_the_study_version_alone(store):
    study_id = create(store)
    leases, other = DatabaseLeases(store, "a"), DatabaseLeases(store, "b")
    version = store.study_version(study_id).trial_changes

    leases.acquire(study_id)
    leases.renew(study_id)
    leases.release(study_id)

    assert other.acquire(study_id)
    assert store.study_version(study_id).trial_changes == version


@pytest.fixture
def embedded(tmp_path, monkeypatch):
    from api.db import create_db_engine, upgrade_database
    from api.settings import get_settings
    from api.store import SqlStore

    url = f"sqlite:///{tmp_path}/demcal.db"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DEMCAL_DATABASE_URL", url)
    get_settings.cache_clear()
    upgrade_database(url)
    yield SqlStore(create_db_engine(url))
    get_settings.cache_clear()


def test_calibrate_refuses_to_resume_a_study_another_process_drives(embedded):
    study_id = create(embedded)
    embedded.set_status(study_id, StudyStatus.RUNNING)
    assert DatabaseLeases(embedded, "serve-on-host-a").acquire(study_id)

    result = CliRunner().invoke(app, ["calibrate", "--resume", study_id])

    assert result.exit_code == 2, result.output
    assert "serve-on-host-a" in result.output
    assert embedded.trials(study_id) == []  # nothing was run
