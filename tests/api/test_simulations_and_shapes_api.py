"""Single simulations are queued and read back; shapes are uploaded, validated, listed, deleted."""

from __future__ import annotations

import io

import pytest
import trimesh

from dem.result import SimulationResult, SimulationStatus

PARAMS = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.4}
STUDY = {
    "name": "uploaded", "experiment": {"measured": [2, 2, 3]}, "parameters": {"E": {"low": 1e6, "high": 1e7}},
    "ga": {"population": 4, "offspring": 2, "generations": 1},
}


def _box_stl() -> bytes:
    buffer = io.BytesIO()
    trimesh.creation.box(extents=(0.14, 0.07, 0.01)).export(buffer, file_type="stl")
    return buffer.getvalue()


def test_simulation_is_queued_as_pending_and_shows_its_result(client, keys, store):
    created = client.post("/api/v1/simulations", json={"scenario": {}, "params": PARAMS, "seed": 3},
                          headers=keys.auth())
    sim_id = created.json()["id"]
    store.mark_simulation_queued(sim_id)
    store.record_simulation_result(
        sim_id, SimulationResult(status=SimulationStatus.OK, n_items=30, n_remaining=4, wall_time_s=2.0), "w1"
    )

    read = client.get(f"/api/v1/simulations/{sim_id}", headers=keys.auth()).json()

    assert created.status_code == 202
    assert created.json()["state"] == "pending"
    assert (read["state"], read["n_remaining"], read["worker"]) == ("done", 4, "w1")


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ({"E": 1e7, "nu": 0.6, "e": 0.5, "mu": 0.4}, "nu = 0.6 is outside"),
        ({"E": 1e7, "nu": 0.3, "e": 0.5}, "give E, nu, e and mu (missing: mu)"),
        ({"E": -1.0, "nu": 0.3, "e": 0.5, "mu": 0.4}, "E = -1.0"),
    ],
)
def test_simulation_with_unphysical_parameters_is_422(client, keys, params, expected):
    body = {"scenario": {}, "params": params}

    response = client.post("/api/v1/simulations", json=body, headers=keys.auth())

    assert response.status_code == 422
    assert expected in response.json()["detail"]


def test_simulation_with_a_bad_scenario_is_422_naming_the_key(client, keys):
    body = {"scenario": {"vibration": {"bogus": 1}}, "params": PARAMS}

    response = client.post("/api/v1/simulations", json=body, headers=keys.auth())

    assert response.status_code == 422
    assert "scenario.vibration.bogus" in response.json()["detail"]


def test_other_owner_cannot_read_a_simulation(client, keys):
    body = {"scenario": {}, "params": PARAMS}
    sim_id = client.post("/api/v1/simulations", json=body, headers=keys.auth()).json()["id"]

    assert client.get(f"/api/v1/simulations/{sim_id}", headers=keys.auth("bob")).status_code == 404


@pytest.mark.slow
def test_uploaded_mesh_is_validated_clumped_listed_and_deleted(client, keys):
    upload = client.post(
        "/api/v1/shapes", files={"file": ("phone.stl", _box_stl(), "model/stl")},
        data={"mass": "0.15", "n_spheres": "4"}, headers=keys.auth(),
    )
    shape = upload.json()

    listed = client.get("/api/v1/shapes", headers=keys.auth()).json()
    hidden = client.get(f"/api/v1/shapes/{shape['id']}", headers=keys.auth("bob"))
    deleted = client.delete(f"/api/v1/shapes/{shape['id']}", headers=keys.auth())

    assert upload.status_code == 201, upload.text
    assert shape["report"]["n_faces"] == 12
    assert shape["clump"]["n_spheres"] <= 4
    assert shape["clump"]["mass"] == pytest.approx(0.15)
    assert [item["id"] for item in listed["items"]] == [shape["id"]]
    assert hidden.status_code == 404
    assert deleted.status_code == 204


@pytest.mark.parametrize(
    ("filename", "content", "expected"),
    [
        ("phone.zip", b"PK\x03\x04rest", "ending in .stl"),
        ("phone.stl", b"PK\x03\x04rest", "zip archive"),
        ("phone.obj", b"this is not a mesh", "phone.obj"),
        ("../../etc/passwd", b"root:x:0:0", "ending in .stl"),
    ],
)
def test_bad_uploads_are_422_saying_what_to_fix(client, keys, filename, content, expected):
    response = client.post(
        "/api/v1/shapes", files={"file": (filename, content, "application/octet-stream")},
        data={"mass": "0.1"}, headers=keys.auth(),
    )

    assert response.status_code == 422, response.text
    assert expected in response.json()["detail"]


def test_upload_above_the_byte_limit_is_413(client, keys):
    response = client.post(
        "/api/v1/shapes", files={"file": ("big.stl", b"\0" * 300_000, "model/stl")}, data={"mass": "1"},
        headers=keys.auth(),
    )

    assert response.status_code == 413


def _upload_box(client, keys, who="alice", mass="0.15") -> str:
    response = client.post(
        "/api/v1/shapes", files={"file": ("phone.stl", _box_stl(), "model/stl")},
        data={"mass": mass, "n_spheres": "4"}, headers=keys.auth(who),
    )
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_a_scenario_feeds_uploaded_shapes_by_id_with_their_own_mass(client, keys, settings):
    shape_id = _upload_box(client, keys, mass="0.15")
    items = {"uploaded": True, "counts": {shape_id: 2}, "masses": {shape_id: 99.0}}

    created = client.post(
        "/api/v1/simulations", json={"scenario": {"items": items}, "params": PARAMS}, headers=keys.auth()
    )

    assert created.status_code == 202, created.text
    stored = created.json()["scenario"]["items"]
    assert (stored["uploaded"], stored["counts"], stored["masses"]) == (True, {shape_id: 2}, {shape_id: 0.15})
    assert "folder" not in stored or stored["folder"] is None  # no server path in the scenario
    kept = trimesh.load(settings.data_dir / "shapes" / f"{shape_id}.ply", force="mesh")
    assert sorted(kept.extents) == pytest.approx(sorted((0.14, 0.07, 0.01)))


def test_a_shape_of_another_owner_or_none_is_422_naming_the_id(client, keys, settings):
    bobs = _upload_box(client, keys, who="bob")

    for shape_id in (bobs, "sh-000000000000"):
        items = {"uploaded": True, "counts": {shape_id: 2}}
        study = client.post(
            "/api/v1/studies", json={**STUDY, "scenario": {"items": items}}, headers=keys.auth()
        )
        single = client.post(
            "/api/v1/simulations", json={"scenario": {"items": items}, "params": PARAMS}, headers=keys.auth()
        )

        for response in (study, single):
            assert response.status_code == 422, response.text
            assert f"no uploaded shape {shape_id!r} of yours" in response.json()["detail"]


def test_deleting_a_shape_removes_the_mesh_kept_for_workers(client, keys, settings):
    shape_id = _upload_box(client, keys)
    kept = settings.data_dir / "shapes" / f"{shape_id}.ply"
    assert kept.is_file()

    response = client.delete(f"/api/v1/shapes/{shape_id}", headers=keys.auth())

    assert response.status_code == 204
    assert not kept.exists()
