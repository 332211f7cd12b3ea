"""The scenario registry (``dem/scenarios/registry.py``), the declarations every scenario makes
(``dem/scenarios/base.py``) and the engine protocol (``dem/engines/``): LIGGGHTS' material
mapping, refusals with messages, and the command engine with a real program."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from dem.contact import damping_ratio
from dem.engines.base import available_engines, get_engine, refusal, run_scenario
from dem.engines.liggghts import material_fixes
from dem.motion import LinearLift
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios import registry
from dem.scenarios.base import Response


def test_registry_lists_the_built_in_kinds_and_names_unknown_ones():
    assert {"feeder", "angle_of_repose", "combined"} <= set(registry.kinds())
    with pytest.raises(registry.UnknownScenarioError, match="known kinds: angle_of_repose, combined, feeder"):
        registry.get("drum")
    assert registry.for_config({}).kind == "feeder"  # studies stored before kinds existed


@pytest.mark.parametrize("kind", sorted(registry.BUILT_IN))
def test_each_kind_s_light_config_model_is_the_one_its_scenario_validates_with(kind):
    model = registry.config_model(kind)
    assert registry.get(kind).config_model is model
    assert model.model_fields["kind"].default == kind  # the union's tag is the registry's key


def test_a_study_definition_imports_no_engine():
    """The scenario union names every kind's config model; none of them may pull in numba."""
    script = "import sys, optimizer.study; print(sorted({'numba', 'trimesh', 'scipy'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("kind", ["feeder", "angle_of_repose"])
def test_every_scenario_declares_what_callers_need(kind):
    scenario = registry.get(kind)
    config = scenario.config({})
    assert config.kind == kind
    again = scenario.config(json.loads(json.dumps(config.model_dump(mode="json"))))
    assert again == config  # travels to workers as JSON
    assert scenario.responses and all(isinstance(r, Response) and r.unit for r in scenario.responses)
    failed = scenario.failed_responses(config)
    assert set(failed) == {r.name for r in scenario.responses}
    assert scenario.time_step(config, {"E": 1e6}) > scenario.time_step(config, {"E": 1e8}) > 0
    # A stiffer material needs more steps, so it is estimated as the longer job.
    assert scenario.cost_estimate(config, {"E": 1e8}) > scenario.cost_estimate(config, {"E": 1e6}) > 0
    assert "numba" in scenario.engines


def test_feeder_worst_case_is_its_own_item_count():
    feeder = registry.get("feeder")
    config = feeder.config({"items": {"counts": {"smartphone": 2, "camera": 1}}})
    assert feeder.failed_responses(config) == {"n_remaining": 3}


def test_feeder_run_reports_its_response_by_name():
    feeder = registry.get("feeder")
    config = feeder.config(
        {
            "items": {"counts": {"camera": 1}},
            "stages": {"insertion_time": 0.05, "vibration_start": 0.3, "vibration_time": 0.1},
        }
    )
    result = feeder.run(config, {"E": 1e6}, 1)
    assert result.status is SimulationStatus.OK, result.message
    assert result.responses == {"n_remaining": result.n_remaining} == {"n_remaining": 1}


def test_bad_parameters_are_an_error_result_not_an_exception():
    heap = registry.get("angle_of_repose")
    result = heap.run({}, {"mu": -1.0}, 0)
    assert result.status is SimulationStatus.ERROR and "mu" in result.message
    result = heap.run({}, {"friction": 0.3}, 0)
    assert result.status is SimulationStatus.ERROR and "unknown parameter" in result.message


def test_linear_lift_moves_at_its_speed_then_stops():
    lift = LinearLift((0, 0, 2), distance=0.1, speed=0.2, start_time=0.5)
    assert lift.displacement(0.4).tolist() == [0, 0, 0]
    assert lift.displacement(0.75)[2] == pytest.approx(0.05)
    assert lift.velocity(0.75)[2] == pytest.approx(0.2)
    assert lift.displacement(2.0)[2] == pytest.approx(0.1) and lift.velocity(2.0)[2] == 0
    assert lift.end_time == pytest.approx(1.0)


def test_liggghts_material_mapping_reproduces_our_contact_law():
    # Two identical spheres: K = E D / 2 (paper eq. 1); against the wall the same K; damping
    # 2 zeta sqrt(K / m*) which LIGGGHTS multiplies by m* (absolute_damping off).
    d, m = 0.01, 1.3e-3
    text = material_fixes({"E": 1e6, "nu": 0.3, "e": 0.5, "mu": 0.4}, [d], [m])
    rows = {line.split()[4]: [float(v) for v in line.split()[7:]] for line in text.splitlines()}
    kn, kt, gn, mu = rows["kn"], rows["kt"], rows["gamman"], rows["coefficientFriction"]
    assert kn[0] == pytest.approx(1e6 * d / 2) and kn[1] == pytest.approx(1e6 * d / 2)
    assert kt[0] / kn[0] == pytest.approx(2 * (1 - 0.3) / (2 - 0.3))
    zeta = damping_ratio(0.5)
    assert gn[0] * (m / 2) == pytest.approx(2 * zeta * math.sqrt(kn[0] * m / 2))  # pair: m* = m/2
    assert gn[1] * m == pytest.approx(2 * zeta * math.sqrt(kn[1] * m))  # wall: m* = m
    assert mu == [0.4] * 4


def test_engines_refuse_what_they_cannot_run_with_a_message():
    heap, feeder = registry.get("angle_of_repose"), registry.get("feeder")
    assert refusal("liggghts", feeder, {}).startswith("engine 'liggghts' does not run scenario 'feeder'")
    assert "spheres only" in refusal("liggghts", heap, {"particles": {"shape": "items"}})
    assert "engine_options.command" in refusal("command", heap, {})
    result = run_scenario(heap, {}, {}, 0, engine="liggghts", options={"binary": "no-such-liggghts"})
    assert result.status is SimulationStatus.ERROR and "not installed" in result.message


def test_an_installed_liggghts_is_an_available_engine(liggghts):
    assert {"numba", "liggghts", "command"} <= set(available_engines())


COMMAND_TEMPLATE = """
import json
# A stand-in program: the heap's angle from mu by a rule, with the config read from the template.
angle = 10.0 + 20.0 * $mu
json.dump({"angle_deg": angle, "height": $particles_diameter * 4, "sim_time": 1.5},
          open("responses.json", "w"))
print("angle of repose:", angle)
"""


def test_command_engine_renders_runs_and_reads_a_program(tmp_path):
    template = tmp_path / "heap.py.in"
    template.write_text(COMMAND_TEMPLATE)
    heap = registry.get("angle_of_repose")
    options = {"template": str(template), "command": [sys.executable, "$input"]}
    result = run_scenario(heap, {}, {"mu": 0.5}, 3, engine="command", options=options)
    assert result.status is SimulationStatus.OK, result.message
    assert result.responses == {"angle_deg": 20.0, "height": pytest.approx(0.04)}
    assert result.engine == "command" and result.sim_time == 1.5 and result.seed == 3

    # Responses may also be read from the screen with one pattern per response.
    template.write_text('print("angle of repose: 31.5"); print("height 0.05")')
    patterns = {"angle_deg": r"angle of repose: ([-0-9.eE+]+)", "height": r"height ([-0-9.eE+]+)"}
    result = get_engine("command").run(
        heap, heap.config({}), {}, 0, _control(), {**options, "patterns": patterns}
    )
    assert result.responses == {"angle_deg": 31.5, "height": 0.05}


def test_command_engine_failures_say_what_went_wrong(tmp_path):
    heap = registry.get("angle_of_repose")
    template = tmp_path / "t.py.in"
    cases = {
        "import sys; sys.exit(3)": "exited with 3",
        "pass": "wrote no responses.json",
        'import json; json.dump({"angle_deg": 1}, open("responses.json", "w"))': "did not report height",
        "x = $no_such_key": "unknown placeholder",
    }
    for program, message in cases.items():
        template.write_text(program)
        options = {"template": str(template), "command": [sys.executable, "$input"]}
        result = run_scenario(heap, {}, {}, 0, engine="command", options=options)
        assert result.status is SimulationStatus.ERROR and message in result.message, (
            program,
            result.message,
        )
        SimulationResult.model_validate(result.model_dump(mode="json"))


def test_command_engine_honours_the_deadline(tmp_path):
    import time

    template = tmp_path / "slow.py.in"
    template.write_text("import time; time.sleep(30)")
    heap = registry.get("angle_of_repose")
    control = _control()
    control.deadline = time.monotonic() + 0.5
    started = time.monotonic()
    options = {"template": str(template), "command": [sys.executable, "$input"]}
    result = get_engine("command").run(heap, heap.config({}), {}, 0, control, options)
    assert result.status is SimulationStatus.TIMEOUT
    assert time.monotonic() - started < 5


def _control():
    from dem.scenarios.base import RunControl

    return RunControl()


def test_threads_asking_at_once_all_see_every_built_in_kind():
    """``serve`` asks from request threads and its driver thread at once, in a fresh process."""
    script = (
        "import threading\n"
        "from dem.scenarios import registry\n"
        "seen, start = [], threading.Barrier(8)\n"
        "def ask():\n"
        "    start.wait()\n"
        "    seen.append([registry.get(kind).kind for kind in registry.kinds()])\n"
        "threads = [threading.Thread(target=ask) for _ in range(8)]\n"
        "[t.start() for t in threads]\n"
        "[t.join() for t in threads]\n"
        "print(*map(len, seen))\n"
    )
    for _ in range(3):
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
        assert out.stdout.split() == [str(len(registry.BUILT_IN))] * 8, out.stdout
