"""Studies over HTTP: create within limits, read progress, status rules, delete."""

from __future__ import annotations

import pytest

from tests.api.conftest import study_definition


def test_create_study_returns_progress_of_its_budget(client, keys):
    response = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth())

    assert response.status_code == 201, response.text
    body = response.json()
    assert body["status"] == "created"
    assert body["owner"] == "alice"
    # 6 initial individuals + 4 offspring x 2 generations, one replicate each.
    assert body["progress"]["trials_total"] == 14
    assert body["progress"]["trials_done"] == 0
    assert body["definition"]["ga"]["population"] == 6


def test_created_study_is_listed_and_readable(client, keys):
    study_id = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]

    listed = client.get("/api/v1/studies", headers=keys.auth()).json()
    fetched = client.get(f"/api/v1/studies/{study_id}", headers=keys.auth())

    assert [item["id"] for item in listed["items"]] == [study_id]
    assert listed["total"] == 1
    assert fetched.status_code == 200
    assert fetched.json()["id"] == study_id


def test_list_filters_by_status_and_paginates(client, keys, store):
    ids = [
        client.post("/api/v1/studies", json=study_definition(name=f"s{i}"), headers=keys.auth()).json()["id"]
        for i in range(3)
    ]
    client.post(f"/api/v1/studies/{ids[0]}/pause", headers=keys.auth())

    paused = client.get("/api/v1/studies", params={"status": "paused"}, headers=keys.auth()).json()
    page = client.get("/api/v1/studies", params={"limit": 2, "offset": 2}, headers=keys.auth()).json()

    assert [item["id"] for item in paused["items"]] == [ids[0]]
    assert page["total"] == 3
    assert len(page["items"]) == 1


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"parameters": {"nu": {"low": 0.1, "high": 0.7}}}, "parameters.nu.high"),
        ({"parameters": {"mu": {"low": 0.8, "high": 0.2}}}, "must be smaller than high"),
        ({"ga": {"population": 101}}, "DEMCAL_MAX_POPULATION"),
        ({"ga": {"population": 50, "offspring": 50, "generations": 60}}, "DEMCAL_MAX_SIMULATIONS"),
        ({"experiment": {"measured": []}}, "experiment.measured"),
        ({"scenario": {"tray": {"inlet_width": -1}}}, "scenario"),
    ],
)
def test_invalid_definition_is_422_saying_what_to_fix(client, keys, change, expected):
    response = client.post("/api/v1/studies", json=study_definition(**change), headers=keys.auth())

    assert response.status_code == 422, response.text
    assert expected in response.json()["detail"]


def test_pause_resume_cancel_follow_the_status_rules(client, keys):
    study_id = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]

    paused = client.post(f"/api/v1/studies/{study_id}/pause", headers=keys.auth())
    resumed = client.post(f"/api/v1/studies/{study_id}/resume", headers=keys.auth())
    cancelled = client.post(f"/api/v1/studies/{study_id}/cancel", headers=keys.auth())
    resume_again = client.post(f"/api/v1/studies/{study_id}/resume", headers=keys.auth())

    assert paused.json()["status"] == "paused"
    assert resumed.json()["status"] == "running"
    assert cancelled.json()["status"] == "cancelled"
    assert resume_again.status_code == 409
    assert "it is cancelled" in resume_again.json()["detail"]


def test_resume_of_a_study_not_paused_is_409_naming_what_is_possible(client, keys):
    study_id = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]

    response = client.post(f"/api/v1/studies/{study_id}/resume", headers=keys.auth())

    assert response.status_code == 409
    assert "possible now: pause, cancel" in response.json()["detail"]


def test_delete_removes_the_study_and_refuses_a_running_one(client, keys, store):
    from optimizer.protocols import StudyStatus

    running = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]
    idle = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]
    store.set_status(running, StudyStatus.RUNNING)

    refused = client.delete(f"/api/v1/studies/{running}", headers=keys.auth())
    deleted = client.delete(f"/api/v1/studies/{idle}", headers=keys.auth())

    assert refused.status_code == 409
    assert deleted.status_code == 204
    assert client.get(f"/api/v1/studies/{idle}", headers=keys.auth()).status_code == 404


def test_unknown_study_is_404_with_a_hint(client, keys):
    response = client.get("/api/v1/studies/st-nope", headers=keys.auth())

    assert response.status_code == 404
    assert "GET /api/v1/studies" in response.json()["detail"]


def test_malformed_json_body_is_422(client, keys):
    response = client.post(
        "/api/v1/studies", content=b"{not json", headers=keys.auth() | {"Content-Type": "application/json"}
    )

    assert response.status_code == 422


def test_body_above_the_limit_is_413(client, keys):
    big = study_definition(description="x" * 70_000)

    response = client.post("/api/v1/studies", json=big, headers=keys.auth())

    assert response.status_code == 413
    assert "DEMCAL_MAX_REQUEST_BYTES" in response.json()["detail"]


def test_replicates_beyond_the_budget_are_a_422_that_says_what_fits(client, keys):
    definition = study_definition(replicates=3, budget=20)

    response = client.post("/api/v1/studies", json=definition, headers=keys.auth())

    assert response.status_code == 422
    assert "budget = 20 simulations cannot hold" in response.text
    assert "replicates <= 1" in response.text


def test_bounds_reaching_into_the_invalid_region_are_warned_about(client, keys):
    soft = study_definition(parameters={"E": {"low": 1e5, "high": 1e7}})
    stiff = study_definition(parameters={"E": {"low": 1e7, "high": 1e8}})

    warned = client.post("/api/v1/studies", json=soft, headers=keys.auth()).json()
    quiet = client.post("/api/v1/studies", json=stiff, headers=keys.auth()).json()

    assert len(warned["warnings"]) == 1 and "likely to be invalid" in warned["warnings"][0]
    assert quiet["warnings"] == []


def test_warnings_are_computed_when_a_study_is_created_not_on_every_read(client, keys, store, monkeypatch):
    import optimizer.study

    soft = study_definition(parameters={"E": {"low": 1e5, "high": 1e7}})
    created = client.post("/api/v1/studies", json=soft, headers=keys.auth()).json()
    legacy = store.create_study(created["definition"], owner="alice")  # as made before they were stored
    estimates = []

    def estimate(*args):
        estimates.append(args)
        return "recomputed"

    monkeypatch.setattr(optimizer.study, "_validity_warning", estimate)
    reads = [client.get(f"/api/v1/studies/{created['id']}", headers=keys.auth()).json() for _ in range(3)]
    old = [client.get(f"/api/v1/studies/{legacy}", headers=keys.auth()).json() for _ in range(3)]

    assert [read["warnings"] for read in reads] == [created["warnings"]] * 3
    assert "likely to be invalid" in created["warnings"][0]
    assert [read["warnings"] for read in old] == [["recomputed"]] * 3
    assert len(estimates) == 1  # the legacy study's, once, then stored
