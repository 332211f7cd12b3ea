"""API keys guard every endpoint but health: no key, wrong key, revoked key, another owner."""

from __future__ import annotations

import pytest

from api.auth import hash_token, revoke_key
from api.models import ApiKeyRow
from tests.api.conftest import study_definition

PROTECTED = [
    ("get", "/api/v1/studies"),
    ("post", "/api/v1/studies"),
    ("get", "/api/v1/studies/st-x/pareto"),
    ("get", "/api/v1/studies/st-x/trials"),
    ("get", "/api/v1/shapes"),
    ("get", "/api/v1/simulations"),
    ("get", "/metrics"),
]


@pytest.mark.parametrize(("method", "path"), PROTECTED)
def test_no_key_is_401_saying_how_to_get_one(client, method, path):
    response = getattr(client, method)(path)

    assert response.status_code == 401
    assert "demcal apikey create" in response.json()["detail"]
    assert response.headers["www-authenticate"] == "Bearer"


def test_wrong_key_is_401(client, keys):
    response = client.get("/api/v1/studies", headers={"Authorization": "Bearer dcl_not-a-key"})

    assert response.status_code == 401
    assert "unknown API key" in response.json()["detail"]


def test_revoked_key_is_401(client, keys, store):
    with store.session() as session:
        revoke_key(session, keys.alice_id)

    response = client.get("/api/v1/studies", headers=keys.auth("alice"))

    assert response.status_code == 401
    assert "revoked" in response.json()["detail"]


def test_another_owners_study_is_404_not_403(client, keys):
    study_id = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]

    read = client.get(f"/api/v1/studies/{study_id}", headers=keys.auth("bob"))
    cancel = client.post(f"/api/v1/studies/{study_id}/cancel", headers=keys.auth("bob"))
    trials = client.get(f"/api/v1/studies/{study_id}/trials", headers=keys.auth("bob"))
    listed = client.get("/api/v1/studies", headers=keys.auth("bob")).json()

    assert (read.status_code, cancel.status_code, trials.status_code) == (404, 404, 404)
    assert listed["total"] == 0


def test_admin_key_sees_every_owners_study(client, keys):
    study_id = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]

    read = client.get(f"/api/v1/studies/{study_id}", headers=keys.auth("admin"))
    listed = client.get("/api/v1/studies", headers=keys.auth("admin")).json()

    assert read.status_code == 200
    assert [item["id"] for item in listed["items"]] == [study_id]


def test_health_needs_no_key(client):
    response = client.get("/healthz")

    assert response.status_code == 200
    assert response.json()["database"] == "ok"


def test_only_the_hash_of_a_key_is_stored(store, keys):
    with store.session() as session:
        rows = session.query(ApiKeyRow).all()

    assert {row.token_sha256 for row in rows} == {hash_token(k) for k in (keys.alice, keys.bob, keys.admin)}
    assert all(keys.alice not in (row.prefix, row.token_sha256) for row in rows)
