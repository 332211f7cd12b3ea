"""A whole calibration with real LIGGGHTS: ``demcal calibrate`` on the embedded default (SQLite,
local pool) with ``engine = "liggghts"`` searches mu against a small heap's angle of repose.
Every simulation is a LIGGGHTS run written from the scenario (``dem/engines/liggghts.py``); the
study finishes, every trial carries its engine and named response, and a parameter set is
recommended. Six runs of a 200-sphere heap: well under a minute on two cores."""

from __future__ import annotations

import pytest

from optimizer.protocols import StudyStatus
from tests.api.test_calibrate_cli import demcal, finish, store_for

STUDY = """
name = "tiny-liggghts"
seed = 2
engine = "liggghts"
trial_timeout_s = 120
[scenario]
kind = "angle_of_repose"
particles = { count = 200, diameter = 0.01 }
cylinder = { diameter = 0.08, height = 0.13, lift_speed = 0.2, segments = 16 }
plate = { size = 0.3 }
stages = { lift_start = 0.15, rest_speed = 0.02 }
run = { dt_fraction = 0.1 }
params = { E = 1e5 }
[parameters]
E = { fixed = 1e5 }
nu = { fixed = 0.3 }
e = { fixed = 0.5 }
mu = { low = 0.1, high = 1.0 }
[experiment]
response = "angle_deg"
measured = [14.0, 16.0, 18.0]
tolerance = 6.0
[ga]
population = 4
offspring = 2
generations = 1
[validation]
seeds = 0
"""


def test_a_small_liggghts_case_calibrates_end_to_end(tmp_path, liggghts):
    (tmp_path / "study.toml").write_text(STUDY)

    output = finish(demcal(["calibrate", "study.toml"], tmp_path), timeout=600)

    store = store_for(tmp_path)
    [study_id] = store.studies_in([StudyStatus.DONE])
    records = store.trials(study_id)
    assert len(records) == 6, output
    assert "failed: 0 (every simulation measured angle of repose)" in output
    assert "N_t" not in output  # the report names the heap's response, not the feeder's
    for record in records:
        assert record.spec.engine == "liggghts"
        assert record.result.engine == "liggghts" and record.result.ok, record.result.message
        assert 0 < record.result.responses["angle_deg"] < 45
        assert record.result.steps > 0 and record.result.wall_time_s > 0
    study = store.load_study(study_id)
    assert study.recommendation is not None, output
    assert 0.1 <= study.recommendation["params"]["mu"] <= 1.0
    assert "engine liggghts" in output and "target angle_deg = 16" in output


@pytest.mark.parametrize("engine", ["numba", "liggghts"])
def test_simulate_runs_one_case_on_either_engine(tmp_path, engine, request):
    if engine == "liggghts":
        request.getfixturevalue("liggghts")
    config = tmp_path / "heap.toml"
    config.write_text(STUDY.split("[parameters]")[0].split("[scenario]")[1].replace("\n", "\n", 1))
    process = demcal(["simulate", str(config), "--engine", engine, "--json", "--set", "mu=0.5"], tmp_path)
    import json

    result = json.loads(finish(process, timeout=300).strip().splitlines()[-1])
    assert result["status"] == "ok" and result["engine"] == engine
    assert set(result["responses"]) == {"angle_deg", "height"}
