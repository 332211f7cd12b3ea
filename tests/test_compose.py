"""docker-compose.yml and the Dockerfile, checked without a Docker engine: the services the
deployment needs are there, each runs a ``demcal`` command that exists, each sets only
environment variables that ``Settings`` reads, and the service contract of the README holds
(scalable workers, a private Redis that never evicts, migrations before the API).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import typer.main
import yaml

from api.cli import app
from api.settings import ENV_PREFIX, Settings

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


@pytest.fixture(scope="module")
def services(compose) -> dict:
    return compose["services"]


def command_words(service: dict) -> list[str]:
    command = service["command"]
    return shlex.split(command) if isinstance(command, str) else list(command)


def is_group(command) -> bool:
    # typer >= 0.20 ships its own copy of click, so isinstance(click.Group) is not reliable.
    return hasattr(command, "list_commands")


def resolve(words: list[str]):
    """The command object that ``demcal words...`` would run, or None if there is none."""
    command = typer.main.get_command(app)
    for word in words:
        if word.startswith("-") or not is_group(command):
            break
        sub = command.get_command(command.context_class(command), word)
        if sub is None:
            return None
        command = sub
    return command


def test_compose_has_the_six_services(services):
    assert set(services) == {"api", "worker", "worker-liggghts", "redis", "postgres", "migrate"}


@pytest.mark.parametrize("name", ["api", "worker", "worker-liggghts", "migrate"])
def test_each_demcal_service_runs_a_command_that_exists(services, name):
    words = command_words(services[name])

    command = resolve(words[1:])

    assert words[0] == "demcal"
    assert command is not None and not is_group(command), f"demcal {' '.join(words[1:])} is not a command"
    for option in (word.split("=")[0] for word in words[2:] if word.startswith("--")):
        assert option in {opt for param in command.params for opt in param.opts}, option


@pytest.mark.parametrize("name", ["api", "worker", "worker-liggghts", "migrate"])
def test_each_demcal_variable_is_a_setting(services, name):
    variables = services[name].get("environment", {})

    unknown = [
        var
        for var in variables
        if not var.startswith(ENV_PREFIX) or var.removeprefix(ENV_PREFIX).lower() not in Settings.model_fields
    ]

    assert unknown == []


def test_the_service_settings_are_accepted_by_settings(services):
    for name in ("api", "worker", "migrate"):
        env = {
            key.removeprefix(ENV_PREFIX).lower(): str(value)
            for key, value in services[name].get("environment", {}).items()
        }

        Settings(_env_file=None, **env)


def test_the_api_command_is_serve_on_port_8000_and_waits_for_the_migration(services):
    api = services["api"]

    assert command_words(api) == ["demcal", "serve"]
    assert "8000:8000" in api["ports"]
    assert api["environment"]["DEMCAL_HOST"] == "0.0.0.0"
    assert api["depends_on"]["migrate"]["condition"] == "service_completed_successfully"
    assert api["depends_on"]["postgres"]["condition"] == "service_healthy"
    assert api["depends_on"]["redis"]["condition"] == "service_healthy"
    assert "healthz" in " ".join(api["healthcheck"]["test"])


def test_the_migration_is_a_one_shot_db_upgrade(services):
    migrate = services["migrate"]

    assert command_words(migrate) == ["demcal", "db", "upgrade"]
    assert migrate["restart"] == "no"
    assert migrate["depends_on"]["postgres"]["condition"] == "service_healthy"


@pytest.mark.parametrize("name", ["worker", "worker-liggghts"])
def test_workers_are_scalable_need_only_redis_and_get_time_to_finish_a_trial(services, name):
    worker = services[name]

    assert command_words(worker)[:2] == ["demcal", "worker"]
    assert "container_name" not in worker
    assert "ports" not in worker
    assert set(worker["environment"]) >= {"DEMCAL_REDIS_URL"}
    assert "DEMCAL_DATABASE_URL" not in worker["environment"]
    assert worker["depends_on"]["redis"]["condition"] == "service_healthy"
    assert worker.get("stop_signal", "SIGTERM") == "SIGTERM"
    grace = worker["stop_grace_period"]
    assert grace.endswith("m") and int(grace[:-1]) >= 5
    assert "healthcheck" in worker


def test_redis_is_private_never_evicts_and_persists(services, compose):
    redis = services["redis"]
    command = " ".join(command_words(redis))

    assert "ports" not in redis
    assert "--maxmemory-policy noeviction" in command
    assert "--appendonly yes" in command
    assert any(volume.split(":")[0] in compose["volumes"] for volume in redis["volumes"])
    assert "healthcheck" in redis


def test_postgres_keeps_its_data_and_reports_readiness(services, compose):
    postgres = services["postgres"]

    assert any(volume.split(":")[0] in compose["volumes"] for volume in postgres["volumes"])
    assert "pg_isready" in " ".join(postgres["healthcheck"]["test"])


def test_api_worker_and_migrate_share_one_image_built_from_the_dockerfile(services):
    images = {services[name]["image"] for name in ("api", "worker", "migrate")}

    assert len(images) == 1
    assert all(services[name]["build"] == "." for name in ("api", "worker", "migrate"))


def test_the_dockerfile_installs_demcal_on_python_311_slim_as_a_non_root_user():
    lines = [line.strip() for line in (ROOT / "Dockerfile").read_text().splitlines()]
    instructions = [line for line in lines if line and not line.startswith("#")]

    assert instructions[0].startswith("FROM python:3.11-slim")
    assert any(re.search(r"pip install (--\S+ )*\.(\s|$)", line) for line in instructions)
    users = [line.split()[1] for line in instructions if line.startswith("USER ")]
    assert users and users[-1] not in ("root", "0")
    copied = {line.split()[1] for line in instructions if line.startswith("COPY ")}
    assert {"api", "worker", "dem", "optimizer", "migrations"} <= copied


def test_the_liggghts_workers_image_adds_debians_liggghts_to_the_same_image(services):
    worker = services["worker-liggghts"]
    assert worker["build"] == {"context": ".", "target": "liggghts"}
    assert worker["image"] != services["worker"]["image"]
    text = (ROOT / "Dockerfile").read_text()
    stage = text.split("FROM demcal AS liggghts", 1)[1].split("\nFROM ", 1)[0]
    assert "apt-get install -y --no-install-recommends liggghts" in stage
    assert [line for line in stage.splitlines() if line.startswith("USER ")][-1] == "USER demcal"
    # The default target stays the plain image: the last stage is demcal itself.
    assert [line for line in text.splitlines() if line.startswith("FROM ")][-1] == "FROM demcal"
