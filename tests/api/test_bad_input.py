"""Input that once answered 500 or was accepted and failed later: every case is a 4xx at once,
on SQLite and PostgreSQL (which refuses NUL characters and Infinity in JSON)."""

from __future__ import annotations

import json

import pytest

from tests.api.conftest import study_definition


@pytest.mark.parametrize("resource", ["studies", "shapes", "simulations"])
def test_an_id_with_a_nul_character_is_404_not_500(client, keys, resource):
    response = client.get(f"/api/v1/{resource}/%00", headers=keys.auth())

    assert response.status_code == 404, response.text
    assert "NUL" in response.json()["detail"]


HTTP_METHODS = {"GET", "POST", "PUT", "PATCH", "DELETE"}


def test_a_method_not_allowed_is_405_with_every_allowed_method_in_allow(client, keys):
    # One path can have several routes (GET and DELETE /studies/{id}): Allow must name them all.
    paths = client.get("/openapi.json").json()["paths"]

    for path, operations in paths.items():
        documented = {method.upper() for method in operations} & HTTP_METHODS
        url = path.replace("{", "x-").replace("}", "")
        for method in sorted(HTTP_METHODS - documented):
            response = client.request(method, url, headers=keys.auth())

            assert response.status_code == 405, (method, path, response.text)
            allowed = {word.strip() for word in response.headers["allow"].split(",")}
            assert allowed == documented, (method, path, allowed)
            assert method in response.json()["detail"]


def post_raw(client, keys, path: str, document: dict, raw: dict[str, str]):
    """POST ``document`` as JSON with some values replaced by raw JSON tokens (``Infinity``)."""
    text = json.dumps(document)
    for placeholder, token in raw.items():
        text = text.replace(json.dumps(placeholder), token)
    return client.post(path, content=text, headers={**keys.auth(), "Content-Type": "application/json"})


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"experiment": {"measured": [3], "tolerance": "@inf"}}, "experiment.tolerance"),
        ({"trial_timeout_s": "@inf"}, "trial_timeout_s"),
        ({"scenario": {"params": {"E": "@inf"}}}, "scenario.params.E"),
        ({"scenario": {"stages": {"vibration_time": "@inf"}}}, "scenario.stages.vibration_time"),
        ({"scenario": {"tray": {"mesh_scale": "@nan"}}}, "scenario.tray.mesh_scale"),
    ],
)
def test_infinity_or_nan_anywhere_in_a_study_is_422_naming_the_field(client, keys, overrides, field):
    response = post_raw(
        client, keys, "/api/v1/studies", study_definition(**overrides), {"@inf": "Infinity", "@nan": "NaN"}
    )

    assert response.status_code == 422, response.text
    assert field.split(".")[-1] in response.json()["detail"]


def test_a_measurement_no_scenario_can_produce_is_refused_at_creation(client, keys):
    response = client.post(
        "/api/v1/studies", json=study_definition(experiment={"measured": [1e308]}), headers=keys.auth()
    )

    assert response.status_code == 422, response.text
    assert "experiment.measured" in response.json()["detail"]


def test_infinity_in_a_simulations_scenario_is_422(client, keys):
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.4}
    request = {"scenario": {"stages": {"vibration_time": "@inf"}}, "params": params}

    response = post_raw(client, keys, "/api/v1/simulations", request, {"@inf": "Infinity"})

    assert response.status_code == 422, response.text
    assert "vibration_time" in response.json()["detail"]


SIMULATION_PARAMS = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.4}


@pytest.mark.parametrize(
    "scenario",
    [
        {"tray": {"mesh_file": "/etc/shadow"}},
        {"tray": {"mesh_file": "../../etc/passwd"}},
        {"items": {"folder": "/etc", "counts": {"passwd": 30}}},
    ],
)
def test_a_scenario_naming_a_server_path_is_422_before_anything_is_opened(client, keys, scenario):
    study = client.post("/api/v1/studies", json=study_definition(scenario=scenario), headers=keys.auth())
    single = client.post(
        "/api/v1/simulations", json={"scenario": scenario, "params": SIMULATION_PARAMS}, headers=keys.auth()
    )

    for response in (study, single):
        assert response.status_code == 422, response.text
        assert "mesh directory" in response.json()["detail"]


@pytest.mark.parametrize(
    "scenario, where",
    [
        (
            {"kind": "angle_of_repose", "particles": {"items": {"folder": "/etc", "counts": {"passwd": 1}}}},
            "scenario.particles.items.folder",
        ),
        (
            {"kind": "combined", "parts": {"a": {"kind": "feeder", "tray": {"mesh_file": "/etc/shadow"}}}},
            "scenario.parts.a.tray.mesh_file",
        ),
    ],
)
def test_a_path_nested_in_a_scenario_is_confined_as_a_top_level_one(client, keys, scenario, where):
    # Before, only the top-level tray and items were confined: these were accepted (202).
    response = client.post(
        "/api/v1/simulations", json={"scenario": scenario, "params": SIMULATION_PARAMS}, headers=keys.auth()
    )

    assert response.status_code == 422, response.text
    assert response.json()["detail"].startswith(where) and "mesh directory" in response.json()["detail"]


def test_a_worker_resolves_nested_relative_paths_inside_its_own_mesh_directory(tmp_path):
    from dem.scenarios.paths import ScenarioPathError, mesh_root, resolve_paths

    scenario = {"kind": "combined", "parts": {"a": {"kind": "angle_of_repose", "particles": {"items": {
        "folder": "scans"}}}}}  # fmt: skip
    resolved = resolve_paths(scenario, tmp_path)

    assert resolved["parts"]["a"]["particles"]["items"]["folder"] == str(mesh_root(tmp_path) / "scans")
    assert scenario["parts"]["a"]["particles"]["items"]["folder"] == "scans"  # a copy
    scenario["parts"]["a"]["particles"]["items"]["folder"] = "../../etc"
    with pytest.raises(ScenarioPathError, match="parts.a.particles.items.folder"):
        resolve_paths(scenario, tmp_path)


def test_a_mesh_inside_the_mesh_directory_is_stored_relative_to_it(client, keys, settings):
    # Each worker resolves it against its own mesh directory: no path of the server's travels.
    inside = str((settings.data_dir / "meshes" / "trays" / "t1.stl").resolve())
    for given in ("trays/t1.stl", "trays/../trays/./t1.stl", inside):
        scenario = {"tray": {"mesh_file": given}}

        response = client.post(
            "/api/v1/studies", json=study_definition(scenario=scenario), headers=keys.auth()
        )

        assert response.status_code == 201, response.text
        assert response.json()["definition"]["scenario"]["tray"]["mesh_file"] == "trays/t1.stl"


def test_simulate_with_an_unphysical_set_exits_2_with_one_line():
    from pathlib import Path

    from typer.testing import CliRunner

    from api.cli import app

    config = Path(__file__).resolve().parents[2] / "examples" / "feeder-quick.toml"
    result = CliRunner().invoke(app, ["simulate", str(config), "--set", "E=-5"])

    assert result.exit_code == 2
    assert result.output.strip().count("\n") == 0
    assert "E = -5.0 is outside its physical range (0, inf)" in result.output


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        (
            {"experiment": {"measured": [3], "tolerence": 1}},
            "experiment.tolerence: unknown key; did you mean 'tolerance'?",
        ),
        (
            {"scenario": {"tray": {"inlet_widht": 0.2}}},
            "scenario.tray.inlet_widht: unknown key; did you mean 'inlet_width'?",
        ),
    ],
)
def test_an_unknown_key_names_the_nearest_valid_one_and_the_path_once(client, keys, overrides, expected):
    response = client.post("/api/v1/studies", json=study_definition(**overrides), headers=keys.auth())

    assert response.status_code == 422, response.text
    assert response.json()["detail"] == expected


@pytest.mark.parametrize(
    ("scenario", "expected"),
    [
        ({"kind": "angle_of_repose", "cylinder": {"height": -1}}, "scenario.cylinder.height: Input"),
        ({"kind": "angle_of_repose", "tray": {"mesh_scale": 1.0}}, "scenario.tray: unknown key"),
        ({"kind": "angle_of_repose", "particles": {"diameter": 5e-324}}, "particles.diameter = 4.94066e-324"),
        ({"kind": "feeder", "cylinder": {"height": 0.1}}, "scenario.cylinder: unknown key"),
        ({"stages": {"vibration_time": "long"}}, "scenario.stages.vibration_time: Input should be a valid"),
        ({"kind": "drum"}, "scenario.kind: unknown scenario kind 'drum'; known kinds: angle_of_repose"),
    ],
)
def test_a_bad_scenario_is_422_naming_the_field_of_its_kind(client, keys, scenario, expected):
    study = client.post("/api/v1/studies", json=study_definition(scenario=scenario), headers=keys.auth())
    simulation = client.post(
        "/api/v1/simulations", json={"scenario": scenario, "params": SIMULATION_PARAMS}, headers=keys.auth()
    )

    assert study.status_code == simulation.status_code == 422, (study.text, simulation.text)
    assert expected in study.json()["detail"]
    assert expected in simulation.json()["detail"]
