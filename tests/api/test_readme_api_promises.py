"""Promises the README makes about the REST API, each on the real store (SQLite and PostgreSQL):
objective values that are not finite are ``null`` in every JSON view, unknown query parameters
are a 422 that names them, and ``DEMCAL_MAX_MESH_FACES`` bounds an uploaded mesh."""

from __future__ import annotations

import io
import json
import math

import pytest
import trimesh
from fastapi.testclient import TestClient

from api.app import create_app
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


def _finished_study(store) -> str:
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 4, "offspring": 2, "generations": 1}, seed=3)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    return study_id


def _strict_json(text: str):
    """JSON as the standard defines it: NaN and Infinity are not JSON, so they must not appear."""

    def refuse(token):
        raise AssertionError(f"{token} in a JSON response")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_objectives_are_null_in_every_json_view(client, keys, store):
    study_id = _finished_study(store)
    study = store.load_study(study_id)
    first, second, third = (row.id for row in store.trial_columns(study_id)[:3])
    objectives = {first: (math.inf, 2.5), second: (0.5, -math.inf), third: (math.nan, 1.0)}
    store.save_generation(study_id, study.generation, study.ga_state, [first, second, third],
                          study.recommendation, objectives=objectives)
    base = f"/api/v1/studies/{study_id}"

    page = _strict_json(client.get(f"{base}/trials", params={"limit": 100}, headers=keys.auth()).text)
    detail = _strict_json(client.get(f"{base}/trials/{first}", headers=keys.auth()).text)
    export = _strict_json(client.get(f"{base}/export.json", headers=keys.auth()).text)
    pareto = _strict_json(client.get(f"{base}/pareto", headers=keys.auth()).text)

    trials = {item["id"]: item for item in page["items"]}
    assert (trials[first]["f1"], trials[first]["f2"]) == (None, 2.5)
    assert (trials[second]["f1"], trials[second]["f2"]) == (0.5, None)
    assert (trials[third]["f1"], trials[third]["f2"]) == (None, 1.0)
    assert (detail["f1"], detail["f2"]) == (None, 2.5)
    exported = {item["trial_id"]: item for item in export["trials"]}
    assert (exported[first]["f1"], exported[second]["f2"]) == (None, None)
    members = {point["id"]: point for point in pareto["points"]}
    assert first not in members  # the front lists only points with a finite f1 to rank them by
    assert members[second]["f2"] is None
    # The database keeps them exactly: the values come back as floats, not as nulls.
    rows = {row.id: row for row in store.trial_columns(study_id)}
    assert (rows[first].f1_kind, rows[second].f2_kind, rows[third].f1_kind) == ("inf", "-inf", "nan")


@pytest.mark.parametrize(
    "path",
    [
        "/api/v1/studies",
        "/api/v1/studies/{study}",
        "/api/v1/studies/{study}/trials",
        "/api/v1/studies/{study}/pareto",
        "/api/v1/simulations",
        "/api/v1/shapes",
    ],
)
def test_unknown_query_parameters_are_422_naming_them(client, keys, store, path):
    study_id = store.create_study(study_definition(), owner="alice")
    url = path.format(study=study_id)

    misspelt = client.get(url, params={"statuss": "done"}, headers=keys.auth())
    plain = client.get(url, headers=keys.auth())

    assert plain.status_code == 200, plain.text
    assert misspelt.status_code == 422, misspelt.text
    assert "statuss" in misspelt.json()["detail"]


def test_an_uploaded_mesh_above_max_mesh_faces_is_refused_saying_which_limit(settings, engine, keys):
    limited = settings.model_copy(update={"max_mesh_faces": 100})
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=20.0)  # 320 faces, mm
    small = trimesh.creation.icosphere(subdivisions=1, radius=20.0)  # 80 faces
    uploads = {}
    with TestClient(create_app(limited, engine=engine)) as client:
        for name, mesh in (("big", sphere), ("small", small)):
            data = io.BytesIO()
            mesh.export(data, file_type="stl")
            uploads[name] = client.post(
                "/api/v1/shapes", files={"file": (f"{name}.stl", data.getvalue(), "model/stl")},
                data={"mass": "0.1", "scale": "0.001", "n_spheres": "2"}, headers=keys.auth(),
            )

    assert len(sphere.faces) > 100 >= len(small.faces)
    assert uploads["big"].status_code == 422, uploads["big"].text
    assert "320 faces" in uploads["big"].json()["detail"]
    assert "100" in uploads["big"].json()["detail"]
    assert uploads["small"].status_code == 201, uploads["small"].text
