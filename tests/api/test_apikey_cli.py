"""``demcal apikey create | list | revoke`` as an operator runs them (the installed console
script, on PostgreSQL), and what a revocation does to a running API."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from api.db import create_db_engine
from api.settings import load_settings
from tests.api.conftest import _empty_postgres

pytestmark = pytest.mark.postgres

DEMCAL = str(Path(sys.executable).with_name("demcal"))


def demcal(database_url: str, *args: str) -> subprocess.CompletedProcess:
    env = {key: value for key, value in os.environ.items() if not key.startswith("DEMCAL_")}
    return subprocess.run(
        [DEMCAL, "apikey", *args], env={**env, "DEMCAL_DATABASE_URL": database_url},
        capture_output=True, text=True, timeout=120,
    )


def listed(database_url: str, *args: str) -> dict[int, list[str]]:
    """``apikey list`` as {id: tab-separated fields}."""
    result = demcal(database_url, "list", *args)
    assert result.returncode == 0, result.stderr
    rows = [line.split("\t") for line in result.stdout.strip().splitlines()]
    return {int(row[0]): row for row in rows}


@pytest.fixture
def database_url(postgres_url):
    _empty_postgres(postgres_url)
    return postgres_url


def test_keys_are_listed_without_their_tokens_and_revoked_keys_get_401(database_url, tmp_path):
    created = {owner: demcal(database_url, "create", "--owner", owner, "--name", f"{owner}-laptop")
               for owner in ("alice", "bob")}
    tokens = {owner: result.stdout.strip() for owner, result in created.items()}
    everyone = listed(database_url)
    [alice_id] = [key_id for key_id, row in everyone.items() if row[1] == "alice"]
    only_bob = listed(database_url, "--owner", "bob")

    # A running API with its key cache off: the revocation must show on the next request.
    now = load_settings(database_url=database_url, data_dir=tmp_path / "data", api_key_cache_s=0.0)
    engine = create_db_engine(database_url)
    with TestClient(create_app(now, engine=engine)) as client:
        def status(owner: str) -> int:
            headers = {"Authorization": f"Bearer {tokens[owner]}"}
            return client.get("/api/v1/studies", headers=headers).status_code

        before = status("alice"), status("bob")
        revoked = demcal(database_url, "revoke", str(alice_id))
        after = status("alice"), status("bob")
    engine.dispose()
    again = listed(database_url)
    unknown = demcal(database_url, "revoke", "9999")

    assert all(result.returncode == 0 for result in created.values())
    assert sorted(row[1] for row in everyone.values()) == ["alice", "bob"]
    assert [row[1] for row in only_bob.values()] == ["bob"]
    for row in everyone.values():
        assert tokens[row[1]] not in "\t".join(row)  # never the token itself
        assert tokens[row[1]].startswith(row[2].removesuffix("..."))  # its prefix, to recognise it
        assert row[5] == "revoked: -"
    assert revoked.returncode == 0, revoked.stderr
    assert before == (200, 200)
    assert after == (401, 200)
    assert again[alice_id][5].startswith("revoked: 20")
    assert unknown.returncode == 2
    assert "9999" in unknown.stderr
