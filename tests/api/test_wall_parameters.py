"""Item-wall parameters in a study: searched within their bounds, carried by every trial, shown
in the API, both CSVs and the CLI's table; unknown names and unphysical bounds refused with what
fits (HTTP 422, exit 2)."""

from __future__ import annotations

import csv
import io

import pytest
from rich.console import Console

from api.commands.calibrate import _report
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_result
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition

LOW, HIGH = 0.2, 0.6
WALL = {"mu_wall": {"low": LOW, "high": HIGH}, "e_wall": {"fixed": 0.4}, "nu_wall": {"fixed": 0.45}}


def wall_friction_matters(spec):
    """The synthetic feeder, whose items also stick to the tray when mu_wall is high."""
    result = synthetic_result(spec)
    stuck = round(10 * (spec.params["mu_wall"] - LOW) / (HIGH - LOW))
    return result.model_copy(update={"n_remaining": min(result.n_items, result.n_remaining + stuck)})


@pytest.fixture
def wall_study(store):
    definition = StudyDefinition.model_validate(
        study_definition(parameters=WALL, ga={"population": 6, "offspring": 3, "generations": 2}, seed=5)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor(wall_friction_matters)).run_to_completion(study_id, poll_timeout=0)
    return study_id


def test_mu_wall_is_searched_within_its_bounds_and_shown_in_the_api_and_both_csvs(
    client, keys, store, wall_study, tmp_path
):
    base, auth = f"/api/v1/studies/{wall_study}", keys.auth()

    trials = client.get(f"{base}/trials", params={"limit": 100}, headers=auth).json()["items"]
    export = list(csv.DictReader(io.StringIO(client.get(f"{base}/export.csv", headers=auth).text)))
    exported = client.get(f"{base}/export.json", headers=auth).json()
    front = client.get(f"{base}/pareto", headers=auth).json()["points"]
    console = Console(record=True, width=200)
    _report(console, store, wall_study, tmp_path)
    [folder] = [p for p in tmp_path.iterdir() if p.is_dir()]
    report = list(csv.DictReader((folder / "trials.csv").open()))

    searched = [t["params"]["mu_wall"] for t in trials]
    assert len(trials) == 12 and all(LOW <= value <= HIGH for value in searched)
    assert len({round(value, 6) for value in searched}) >= 6  # searched, not one value
    assert all(list(t["params"]) == ["E", "nu", "e", "mu", "nu_wall", "e_wall", "mu_wall"] for t in trials)
    assert all(t["params"]["e_wall"] == 0.4 and t["params"]["nu_wall"] == 0.45 for t in trials)
    by_id = {t["id"]: t["params"]["mu_wall"] for t in trials}
    assert list(export[0]) == list(report[0])  # one table, two writers
    assert list(export[0])[5:12] == ["E", "nu", "e", "mu", "nu_wall", "e_wall", "mu_wall"]
    for rows in (export, report, exported["trials"]):
        assert {row["trial_id"]: float(row["mu_wall"]) for row in rows} == pytest.approx(by_id)
    assert front and all(LOW <= point["params"]["mu_wall"] <= HIGH for point in front)
    assert "mu_wall" in console.export_text()  # the CLI's Pareto table has its column


def test_a_study_without_wall_parameters_carries_the_four_and_stores_none(store):
    definition = StudyDefinition.model_validate(study_definition(seed=5))
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")

    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    assert set(store.load_study(study_id).definition["parameters"]) == {"E", "nu", "e", "mu"}
    assert all(list(r.spec.params) == ["E", "nu", "e", "mu"] for r in store.trials(study_id))


NAMES = "E, nu, e, mu (the items' material) and, optionally, E_wall, nu_wall, e_wall, mu_wall"


RANGE = "is outside the physical range"


@pytest.mark.parametrize(
    ("parameters", "expected"),
    [
        ({"mu_walls": {"low": 0.1}}, f"unknown parameter(s) mu_walls; the parameters are {NAMES}"),
        ({"mu_wall": {"low": -0.1, "high": 0.9}}, f"parameters.mu_wall.low = -0.1 {RANGE} [0, inf)"),
        ({"e_wall": {"fixed": 1.5}}, f"parameters.e_wall.fixed = 1.5 {RANGE} (0, 1]"),
        ({"E_wall": {"low": 0, "high": 1e9}}, f"parameters.E_wall.low = 0 {RANGE} (0, inf)"),
        ({"nu_wall": {"low": 0.2, "high": 0.5}}, f"parameters.nu_wall.high = 0.5 {RANGE} (-1, 0.5)"),
    ],
)
def test_unknown_or_unphysical_wall_parameters_are_422_saying_what_fits(client, keys, parameters, expected):
    definition = study_definition(parameters=parameters)

    response = client.post("/api/v1/studies", json=definition, headers=keys.auth())

    assert response.status_code == 422, response.text
    assert expected in response.json()["detail"]


def test_a_simulation_with_an_unknown_parameter_is_422_naming_the_ones_that_fit(client, keys):
    body = {"scenario": {}, "params": {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5, "mu_wal": 0.2}}

    response = client.post("/api/v1/simulations", json=body, headers=keys.auth())

    assert response.status_code == 422, response.text
    assert f"unknown parameter(s) mu_wal; the parameters are {NAMES}" in response.text


def test_a_study_file_with_an_unknown_wall_parameter_exits_2_naming_the_ones_that_fit(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from api.cli import app
    from api.settings import get_settings

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DEMCAL_DATABASE_URL", f"sqlite:///{tmp_path}/demcal.db")
    get_settings.cache_clear()
    (tmp_path / "study.toml").write_text(
        "[scenario]\n[experiment]\nmeasured = [1]\n[parameters]\nmu_floor = { low = 0.1, high = 0.9 }\n"
    )

    result = CliRunner().invoke(app, ["calibrate", "study.toml"])
    get_settings.cache_clear()

    assert result.exit_code == 2
    assert "unknown parameter(s) mu_floor" in result.output and "mu_wall" in result.output


def test_liggghts_refuses_a_study_with_wall_parameters_naming_the_engine_that_takes_them():
    wall = {"mu_wall": {"low": 0.1, "high": 0.9}}
    data = study_definition(scenario={"kind": "angle_of_repose"}, engine="liggghts", parameters=wall)

    with pytest.raises(ValueError, match="engine 'liggghts' cannot apply mu_wall.*'numba' takes them all"):
        StudyDefinition.model_validate(data)
