"""Experiments name responses: one or several per study, validated against what the scenario
measures, and several combined into one match objective by the documented rule
f1 = max_k |simulated_k - target_k| / tolerance_k."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from dem.result import SimulationResult, SimulationStatus
from optimizer.objectives import evaluate
from optimizer.protocols import TrialRecord, TrialSpec, TrialState
from optimizer.study import StudyDefinition

PARAMS = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}
COMBINED = {
    "kind": "combined",
    "parts": {
        "heap": {"kind": "angle_of_repose"},
        "feeder": {"kind": "feeder", "items": {"counts": {"camera": 2}}},
    },
}


def combined_definition(**overrides) -> StudyDefinition:
    data = {
        "scenario": COMBINED,
        "experiments": [
            {"response": "heap.angle_deg", "measured": [30.0, 32.0], "tolerance": 2.0},
            {"response": "feeder.n_remaining", "measured": [1, 1, 2], "tolerance": 0.5},
        ],
    }
    data.update(overrides)
    return StudyDefinition.model_validate(data)


def record(individual, replicate, responses, status="ok"):
    spec = TrialSpec(
        f"s-{individual}-{replicate}", "s", individual, 0, replicate, replicate, PARAMS, COMBINED
    )
    result = SimulationResult(
        status=SimulationStatus(status), responses=responses, wall_time_s=1.0, cost=10.0
    )
    return TrialRecord(spec, TrialState.DONE, result)


def test_one_experiment_defaults_to_the_scenarios_first_response_and_its_rounding():
    feeder = StudyDefinition.model_validate({"scenario": {}, "experiment": {"measured": [3, 4]}})
    assert feeder.experiment.response == "n_remaining" and feeder.experiment.round == "half_up"
    assert feeder.experiment.target() == 4  # median 3.5 used as 4, as the paper did
    heap = StudyDefinition.model_validate(
        {"scenario": {"kind": "angle_of_repose"}, "experiment": {"measured": [30.0, 31.0]}}
    )
    assert heap.experiment.response == "angle_deg" and heap.experiment.round == "none"
    assert heap.experiment.target() == 30.5  # an angle is not rounded to a count
    assert heap.model_dump(mode="json")["experiments"][0]["response"] == "angle_deg"


def test_an_unknown_response_or_engine_is_named():
    with pytest.raises(
        ValidationError, match="experiments.0..response: .*no response 'N_t'.*angle_deg, height"
    ):
        StudyDefinition.model_validate(
            {"scenario": {"kind": "angle_of_repose"}, "experiment": {"response": "N_t", "measured": [30]}}
        )
    with pytest.raises(ValidationError, match="engine 'liggghts' does not run scenario 'feeder'"):
        StudyDefinition.model_validate(
            {"scenario": {}, "engine": "liggghts", "experiment": {"measured": [3]}}
        )
    with pytest.raises(ValidationError, match="unknown engine 'yade'"):
        StudyDefinition.model_validate({"scenario": {}, "engine": "yade", "experiment": {"measured": [3]}})
    with pytest.raises(ValidationError, match="either 'experiment'"):
        StudyDefinition.model_validate({"scenario": {}, "experiment": {"measured": [3]}, "experiments": []})


def test_combined_scenario_declares_its_parts_responses_with_units():
    definition = combined_definition()
    from dem.scenarios.registry import for_config

    scenario = for_config(definition.scenario)
    declared = {r.name: r for r in scenario.declared(definition.scenario)}
    assert list(declared) == ["heap.angle_deg", "heap.height", "feeder.n_remaining"]
    assert declared["heap.angle_deg"].unit == "deg" and declared["feeder.n_remaining"].integer
    assert definition.failed_responses()["feeder.n_remaining"] == 2  # its own item count
    assert definition.match_tolerance() == 1.0


def test_several_experiments_combine_as_the_worst_distance_over_its_tolerance():
    definition = combined_definition()
    # heap: median of 31, 35 = 33 vs target 31 -> 2 deg / 2 = 1.0; feeder: median 1 vs 1 -> 0.
    records = [
        record(0, 0, {"heap.angle_deg": 31.0, "heap.height": 0.04, "feeder.n_remaining": 1}),
        record(0, 1, {"heap.angle_deg": 35.0, "heap.height": 0.04, "feeder.n_remaining": 1}),
        # feeder off by 3 items / 0.5 = 6 dominates; the heap matches exactly.
        record(1, 0, {"heap.angle_deg": 31.0, "heap.height": 0.04, "feeder.n_remaining": 4}),
        record(1, 1, {"heap.angle_deg": 31.0, "heap.height": 0.04, "feeder.n_remaining": 4}),
    ]
    first, second = evaluate(records, definition, n_items=definition.n_items())
    assert first.f1 == pytest.approx(1.0) and first.matches(definition.match_tolerance())
    assert second.f1 == pytest.approx(6.0) and not second.matches(definition.match_tolerance())
    assert second.responses == {"heap.angle_deg": [31.0, 31.0], "feeder.n_remaining": [4, 4]}


def test_a_failed_or_unmeasured_run_counts_as_every_responses_failed_value():
    definition = combined_definition()
    records = [
        record(0, 0, {"heap.angle_deg": None, "heap.height": None, "feeder.n_remaining": 1}, status="error"),
        record(1, 0, {"heap.angle_deg": None, "heap.height": 0.0, "feeder.n_remaining": 1}),
    ]
    failed, unmeasured = evaluate(records, definition, n_items=definition.n_items())
    # heap: |90 - 31| / 2 = 29.5 beats feeder |2 - 1| / 0.5 = 2.
    assert failed.f1 == unmeasured.f1 == pytest.approx(29.5)
    assert failed.failure.startswith("error") and unmeasured.failure


def test_the_surrogate_search_calibrates_several_experiments():
    """A heap and a feeder measured together: the surrogate models each response and the study
    runs to its end (it used to be refused with several experiments)."""
    from optimizer.driver import Driver
    from optimizer.memory import MemoryStore, SyntheticExecutor

    definition = combined_definition(
        ga={"algorithm": "surrogate", "population": 6, "offspring": 3, "generations": 2},
        validation={"seeds": 0},
        seed=3,
    )

    def respond(spec):
        mu, e = spec.params["mu"], spec.params["e"]
        responses = {
            "heap.angle_deg": 20.0 + 20.0 * mu,
            "heap.height": 0.05,
            "feeder.n_remaining": int(e < 0.5),
        }
        return SimulationResult(status=SimulationStatus.OK, responses=responses, wall_time_s=1.0, cost=1e6)

    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"))
    progress = Driver(store, SyntheticExecutor(respond)).run_to_completion(study_id, poll_timeout=0)

    trials = store.trials(study_id)
    assert progress.status.value == "done" and len(trials) == 6 + 3 * 2
    assert all(0.0 <= t.spec.params["mu"] <= 1.0 and 0.0 <= t.spec.params["e"] <= 1.0 for t in trials)
