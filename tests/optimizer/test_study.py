"""The study definition: the paper's defaults, the rounding rule, and errors that name the field."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from optimizer.study import (
    Experiment,
    StudyDefinitionError,
    StudyLimitError,
    check_limits,
    describe_validation_error,
    load_study_file,
    round_count,
)
from tests.optimizer.conftest import PAPER_MEASURED, make_definition


def test_defaults_are_the_papers_protocol_of_185_simulations():
    definition = make_definition()

    assert definition.ga.population == 50
    assert definition.ga.offspring == 15
    assert definition.ga.generations == 9
    assert (definition.ga.crossover_prob, definition.ga.mutation_prob) == (0.98, 0.02)
    assert definition.search_simulations() == 50 + 9 * 15
    # Then the recommendation and two more candidates on 10 fresh seeds each.
    assert definition.total_simulations() == 185 + 3 * 10


def test_paper_median_3_5_is_used_as_4_with_half_up():
    experiment = Experiment(measured=PAPER_MEASURED)

    assert experiment.target() == 4.0


@pytest.mark.parametrize(
    ("value", "rule", "expected"),
    [(2.5, "half_up", 3.0), (2.5, "half_even", 2.0), (3.5, "half_even", 4.0), (2.5, "none", 2.5)],
)
def test_rounding_rules_are_explicit(value, rule, expected):
    assert round_count(value, rule) == expected


def test_mean_aggregate_of_the_paper_is_5_7():
    experiment = Experiment(measured=PAPER_MEASURED, aggregate="mean", round="none")

    assert experiment.target() == pytest.approx(57 / 10)


@pytest.mark.parametrize(
    ("parameters", "named"),
    [
        ({"nu": {"low": 0.3, "high": 0.2}}, "parameters.nu: low"),
        ({"nu": {"high": 0.5}}, "parameters.nu.high"),
        ({"E": {"low": -1.0}}, "parameters.E.low"),
        ({"e": {"fixed": 1.5}}, "parameters.e.fixed"),
        ({"mu": {"lo": 0.1}}, "mu.lo"),
    ],
)
def test_bad_bounds_name_the_field(tmp_path, parameters, named):
    path = tmp_path / "study.json"
    path.write_text(json.dumps({"scenario": {}, "experiment": {"measured": [4]}, "parameters": parameters}))

    with pytest.raises(StudyDefinitionError, match=named.replace(".", r"\.")):
        load_study_file(path)


def test_scenario_path_is_read_relative_to_the_study_file_and_inlined(tmp_path):
    (tmp_path / "feeder.toml").write_text("[stages]\nvibration_time = 3.0\n")
    study = tmp_path / "study.toml"
    study.write_text('scenario_path = "feeder.toml"\n[experiment]\nmeasured = [1, 2]\n')

    definition = load_study_file(study)

    assert definition.scenario.stages.vibration_time == 3.0
    assert "scenario_path" not in definition.model_dump()


def test_a_study_files_items_folder_is_looked_into_before_the_study_starts(tmp_path):
    import trimesh

    (tmp_path / "scans").mkdir()
    trimesh.creation.box((0.08, 0.04, 0.012)).export(tmp_path / "scans" / "remote.stl")
    inline = {"items": {"folder": str(tmp_path / "scans"), "counts": {"radio": 1}}}
    path = tmp_path / "study.json"
    path.write_text(json.dumps({"scenario": inline, "experiment": {"measured": [1]}}))
    with pytest.raises(StudyDefinitionError, match="counts.radio: no mesh radio.*found: remote"):
        load_study_file(path)
    # The same definition validated as the API validates a request opens nothing.
    assert make_definition(scenario=inline).scenario.items.counts == {"radio": 1}


def test_bad_scenario_key_is_named_as_written():
    with pytest.raises(ValidationError) as refused:
        make_definition(scenario={"vibration": {"amplitude": -1.0}})

    # pydantic's location carries the union's tag (scenario.feeder.vibration); the user wrote none
    message = describe_validation_error(refused.value)
    assert message.startswith("scenario.vibration.amplitude: Input should be")


def test_limits_name_the_setting_and_what_fits():
    definition = make_definition(replicates=3)

    with pytest.raises(StudyLimitError, match="DEMCAL_MAX_SIMULATIONS") as refused:
        check_limits(definition, max_population=500, max_simulations=3 * 185 - 1)
    assert "replicates <= 2" in str(refused.value)
    with pytest.raises(StudyLimitError, match="DEMCAL_MAX_POPULATION"):
        check_limits(definition, max_population=49, max_simulations=10_000)
    check_limits(definition, max_population=50, max_simulations=3 * 185 + 30)


@pytest.mark.parametrize(
    ("overrides", "fits"),
    [
        ({"replicates": 3}, "replicates <= 1"),
        ({"validation": {"seeds": 20}}, "validation.seeds <= 10"),
        ({"ga": {"population": 90}}, "ga.population <= 50"),
    ],
)
def test_a_budget_too_small_for_the_search_and_the_validation_says_what_fits(overrides, fits):
    with pytest.raises(ValueError, match="budget = 215 simulations cannot hold") as refused:
        make_definition(budget=215, **overrides)
    assert fits in str(refused.value)


def test_the_budget_beyond_the_search_and_the_validation_is_the_replicate_pool():
    definition = make_definition(replicates=2, max_replicates=4, budget=500)

    assert definition.replicate_pool() == 500 - 2 * 185 - 30
    assert make_definition(replicates=2, max_replicates=4).replicate_pool() == 2 * 15
    with pytest.raises(ValueError, match="max_replicates"):
        make_definition(replicates=3, max_replicates=2)
