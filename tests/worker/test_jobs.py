"""The job function: a real (tiny) feeder simulation in, its result as JSON out, never a raise."""

from __future__ import annotations

import time
from dataclasses import asdict

import pytest

from dem.result import SimulationResult, SimulationStatus
from optimizer.protocols import TrialSpec
from worker.jobs import longest_first, run_trial

# Two items, a fraction of a second: the smallest run that still deposits and vibrates.
# The step is forced: stable for E in 1e6-3e6 Pa, and it divides every stage time, which keeps
# the run clear of a sub-step remainder at a stage's end.
TINY_SCENARIO = {
    "items": {"counts": {"smartphone": 1, "camera": 1}, "resolution": 4},
    "stages": {"insertion_time": 0.1, "vibration_start": 0.3, "vibration_time": 0.2},
    "run": {"dt": 1e-5},
}
# Ten minutes simulated, and no early end when the tray empties: always longer than any deadline.
LONG_SCENARIO = {
    **TINY_SCENARIO,
    "stages": {**TINY_SCENARIO["stages"], "vibration_time": 600.0},
    "run": {"dt": 1e-5, "stop_when_empty": False},
}
PARAMS = {"E": 1e6, "nu": 0.3, "e": 0.5, "mu": 0.5}


def tiny_spec(trial="t-0", scenario=None, params=None, timeout_s=None, seed=3) -> dict:
    spec = TrialSpec(trial, "t", 0, 0, 0, seed, params or PARAMS, scenario or TINY_SCENARIO, timeout_s)
    return asdict(spec)


@pytest.mark.slow
def test_tiny_feeder_run_returns_a_valid_result_with_its_seed_and_params():
    result = SimulationResult.model_validate(run_trial(tiny_spec()))

    assert result.status is SimulationStatus.OK, result.message
    assert result.n_items == 2
    assert 0 <= result.n_remaining <= 2
    assert (result.seed, result.params) == (3, PARAMS)
    assert result.steps > 0 and result.cost > 0


def test_bad_scenario_becomes_an_error_result_naming_the_key():
    spec = tiny_spec(scenario={"vibration": {"amplitude": -1.0}})

    result = SimulationResult.model_validate(run_trial(spec))

    assert result.status is SimulationStatus.ERROR
    assert "amplitude" in result.message


def test_unusable_parameter_becomes_an_error_result():
    spec = tiny_spec(params={**PARAMS, "nu": 0.7})

    result = SimulationResult.model_validate(run_trial(spec))

    assert result.status is SimulationStatus.ERROR
    assert "nu" in result.message


def test_missing_scenario_becomes_an_error_result():
    spec = tiny_spec()
    del spec["scenario"]

    result = SimulationResult.model_validate(run_trial(spec))

    assert result.status is SimulationStatus.ERROR
    assert "scenario" in result.message


# How late after its deadline a run may stop: the deadline is checked between chunks of 0.01 s
# simulated (1,000 steps of two items, milliseconds); the rest absorbs a loaded shared machine.
DEADLINE_SLACK_S = 3.0


@pytest.mark.slow
def test_deadline_ends_the_run_as_timeout_soon_after_it_passes_and_not_before():
    run_trial(tiny_spec())  # compiles the kernels, so that the deadline falls inside the simulation
    started = time.monotonic()
    # A backstop well past the slack, so that an ignored deadline fails here instead of running
    # the ten simulated minutes.
    backstop = lambda: time.monotonic() > started + 5 * DEADLINE_SLACK_S  # noqa: E731

    result = SimulationResult.model_validate(
        run_trial(tiny_spec(scenario=LONG_SCENARIO, timeout_s=3.0), should_stop=backstop)
    )
    elapsed = time.monotonic() - started

    assert result.status is SimulationStatus.TIMEOUT, result.message
    assert 3.0 <= elapsed < 3.0 + DEADLINE_SLACK_S
    assert result.sim_time > 0


def test_trial_asking_for_snapshots_leaves_a_replayable_directory(tmp_path):
    from dem.scenarios.render import load_run

    spec = {**tiny_spec(trial="t-snap"), "keep_snapshots": True}

    result = SimulationResult.model_validate(run_trial(spec, snapshot_root=tmp_path))

    assert result.status is SimulationStatus.OK, result.message
    run = load_run(tmp_path / "t-snap")
    assert len(run.frames) >= 2
    assert len(run.names) == result.n_items


def test_trial_without_snapshots_writes_nothing(tmp_path):
    run_trial(tiny_spec(trial="t-none"), snapshot_root=tmp_path)

    assert list(tmp_path.iterdir()) == []


def test_a_relative_mesh_path_is_read_from_this_workers_mesh_directory(tmp_path):
    import trimesh

    from dem.scenarios.tray import TrayConfig, parametric_tray_mesh

    mine, theirs = tmp_path / "mine", tmp_path / "theirs"
    (mine / "meshes" / "trays").mkdir(parents=True)
    theirs.mkdir()
    vertices, faces = parametric_tray_mesh(TrayConfig())
    trimesh.Trimesh(vertices, faces, process=False).export(mine / "meshes" / "trays" / "t.stl")
    spec = tiny_spec(trial="t-mesh", scenario={**TINY_SCENARIO, "tray": {"mesh_file": "trays/t.stl"}})

    here = SimulationResult.model_validate(run_trial(spec, data_dir=mine))
    elsewhere = SimulationResult.model_validate(run_trial(spec, data_dir=theirs))

    assert here.status is SimulationStatus.OK, here.message
    assert elsewhere.status is SimulationStatus.ERROR
    assert f"tray.mesh_file {theirs / 'meshes' / 'trays' / 't.stl'} does not exist" in elsewhere.message


def test_a_relative_mesh_path_leaving_the_mesh_directory_is_an_error_result(tmp_path):
    (tmp_path / "outside.stl").write_text("solid x\nendsolid x\n")
    spec = tiny_spec(trial="t-out", scenario={**TINY_SCENARIO, "tray": {"mesh_file": "../outside.stl"}})

    result = SimulationResult.model_validate(run_trial(spec, data_dir=tmp_path))

    assert result.status is SimulationStatus.ERROR
    assert "leaves the mesh directory" in result.message


def test_uploaded_shapes_are_fed_from_this_workers_data_dir(tmp_path):
    import trimesh

    from dem.scenarios.paths import shape_file

    kept = shape_file(tmp_path, "sh-box")
    kept.parent.mkdir(parents=True)
    trimesh.creation.box(extents=(0.14, 0.07, 0.01)).export(kept)
    items = {"uploaded": True, "counts": {"sh-box": 2}, "masses": {"sh-box": 0.15}, "resolution": 4}
    spec = tiny_spec(trial="t-up", scenario={**TINY_SCENARIO, "items": items})

    fed = SimulationResult.model_validate(run_trial(spec, data_dir=tmp_path))
    elsewhere = SimulationResult.model_validate(run_trial(spec))

    assert fed.status is SimulationStatus.OK, fed.message
    assert fed.n_items == 2
    assert elsewhere.status is SimulationStatus.ERROR
    assert "uploaded shapes are kept by the service" in elsewhere.message


def test_longest_first_starts_the_stiffest_trials_first():
    specs = [TrialSpec(f"t-{i}", "t", i, 0, 0, i, {**PARAMS, "E": E}, TINY_SCENARIO) for i, E in
             enumerate([1e6, 1e8, 1e7])]

    ordered = longest_first(specs)

    assert [spec.params["E"] for spec in ordered] == [1e8, 1e7, 1e6]
