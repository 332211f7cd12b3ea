"""Identifiability: Sobol indices against an analytic case, and verdicts on a synthetic study
whose response ignores nu."""

from __future__ import annotations

import numpy as np
import pytest

from optimizer.identifiability import identifiability, sobol_indices
from optimizer.objectives import Evaluation
from optimizer.space import ParameterSpace
from optimizer.study import Parameters


def test_sobol_indices_of_a_linear_function_are_its_variance_shares():
    # f = x0 + 2 x1 with x uniform: Var = 1/12 + 4/12, so S0 = 0.2, S1 = 0.8, x2 has none.
    first, total = sobol_indices(lambda x: x[:, 0] + 2.0 * x[:, 1], n_genes=3)

    assert first == pytest.approx([0.2, 0.8, 0.0], abs=0.02)
    assert total == pytest.approx([0.2, 0.8, 0.0], abs=0.02)


def test_sobol_total_index_sees_an_interaction_the_first_order_misses():
    # f = (x0 - 1/2)(x1 - 1/2): no main effects, all variance in the interaction.
    first, total = sobol_indices(lambda x: (x[:, 0] - 0.5) * (x[:, 1] - 0.5), n_genes=2)

    assert first == pytest.approx([0.0, 0.0], abs=0.05)
    assert total == pytest.approx([1.0, 1.0], abs=0.05)


def synthetic_study(n: int = 60):
    space = ParameterSpace(Parameters())
    rng = np.random.default_rng(0)
    evaluations = []
    for individual, genes in enumerate(rng.random((n, 4))):
        n_t = int(round(30 / (1 + np.exp(-10 * (genes[3] - 0.6) + 4 * (genes[2] - 0.5)))))
        evaluations.append(Evaluation(individual, 0, space.params(genes), abs(n_t - 4), 1.0, [n_t], 1.0, 1.0))
    return evaluations, space


def test_a_parameter_the_response_ignores_is_not_identifiable():
    evaluations, space = synthetic_study()

    result = identifiability(evaluations, space, tolerance=0.5)

    by_name = {row["name"]: row for row in result["parameters"]}
    assert by_name["nu"]["verdict"] == "not identifiable"
    assert by_name["E"]["verdict"] == "not identifiable"
    assert by_name["mu"]["total"] > by_name["e"]["total"] > 0.02
    assert by_name["mu"]["total"] > 0.5
    assert result["simulations"] == 60 and result["reason"] == ""


def test_too_few_or_constant_simulations_say_why():
    evaluations, space = synthetic_study(5)
    assert "at least 8" in identifiability(evaluations, space, 0.5)["reason"]

    flat = [
        Evaluation(i, 0, ev.params, 4.0, 1.0, [0], 1.0, 1.0) for i, ev in enumerate(synthetic_study(10)[0])
    ]
    result = identifiability(flat, space, 0.5)
    assert "does not vary" in result["reason"] and result["parameters"] == []


def test_a_large_study_is_assessed_from_a_bounded_subsample_with_the_same_verdicts(monkeypatch):
    import optimizer.identifiability as module

    fitted = []
    fit = module.fit_gp
    monkeypatch.setattr(module, "fit_gp", lambda genes, values, **kw: fitted.append(len(genes)) or fit(
        genes, values, **kw))
    evaluations, space = synthetic_study(5 * module.MAX_GP_POINTS)

    result = identifiability(evaluations, space, tolerance=0.5)

    assert fitted == [module.MAX_GP_POINTS]
    assert result["simulations"] == 5 * module.MAX_GP_POINTS  # every simulation is counted
    by_name = {row["name"]: row for row in result["parameters"]}
    assert by_name["nu"]["total"] < 0.02 and by_name["E"]["total"] < 0.02
    assert by_name["mu"]["total"] > by_name["e"]["total"] > 0.02


def test_a_second_experiments_real_response_is_assessed_as_it_is_not_as_a_count():
    """A heap's angle (real, degrees) beside N_t: the study's first experiment names the angle,
    which depends on mu only; modelled as it is, not through the count transform of N_t."""
    space = ParameterSpace(Parameters())
    rng = np.random.default_rng(1)
    evaluations = []
    for individual, genes in enumerate(rng.random((60, 4))):
        angle = 20.0 + 15.0 * genes[3]  # grows with mu, nothing else
        n_t = int(round(30 * genes[2]))  # N_t driven by e only, to be ignored here
        evaluations.append(Evaluation(individual, 0, space.params(genes), 1.0, 1.0, [n_t], 1.0, 1.0,
                                      responses={"n_remaining": [n_t], "angle_deg": [angle]}))

    result = identifiability(evaluations, space, 1.0, response="angle_deg", label="angle of repose",
                             count=False)

    by_name = {row["name"]: row for row in result["parameters"]}
    assert "mean of angle of repose" in result["method"]
    assert by_name["mu"]["total"] > 0.9
    assert by_name["e"]["total"] < 0.02


def test_the_study_view_uses_the_first_experiments_declared_response():
    from optimizer.identifiability import study_identifiability
    from optimizer.study import StudyDefinition

    heap = StudyDefinition.model_validate({
        "name": "heap", "scenario": {"kind": "angle_of_repose"},
        "experiment": {"response": "angle_deg", "measured": [31.0, 33.0, 32.0], "tolerance": 1.5},
    })
    evaluations, space = synthetic_study(5)

    result = study_identifiability(evaluations, heap, space)

    assert "angle of repose" in result["method"] and "sqrt" not in result["method"]


def test_a_heap_and_feeder_study_is_assessed_per_experiment_and_together():
    """Each experiment alone leaves a ridge: the angle fixes e + mu, N_t fixes mu - e. Together
    they pin both; E moves neither response. Every experiment is assessed, not just the first."""
    from optimizer.identifiability import study_identifiability
    from optimizer.objectives import match_distance
    from optimizer.study import StudyDefinition

    study = StudyDefinition.model_validate({
        "name": "heap-and-feeder",
        "scenario": {"kind": "combined", "parts": {"heap": {"kind": "angle_of_repose"}, "feeder": {}}},
        "parameters": {"nu": {"fixed": 0.3}},
        "experiments": [
            {"response": "heap.angle_deg", "measured": [30.0, 30.0, 30.0], "tolerance": 1.0},
            {"response": "feeder.n_remaining", "measured": [10, 10, 10], "tolerance": 0.5},
        ],
    })
    space = ParameterSpace(study.parameters)
    rng = np.random.default_rng(3)
    near = np.column_stack([rng.random(60), 0.5 + 0.03 * rng.standard_normal((60, 2))]).clip(0, 1)
    evaluations = []
    for individual, (g_E, g_e, g_mu) in enumerate(np.vstack([rng.random((160, 3)), near])):
        responses = {"heap.angle_deg": [20.0 + 10.0 * (g_e + g_mu)],
                     "feeder.n_remaining": [float(round(10 + 10 * (g_mu - g_e)))]}
        f1 = match_distance(responses, study)
        evaluations.append(Evaluation(individual, 0, space.params([g_E, g_e, g_mu]), f1, 1.0,
                                      responses["heap.angle_deg"], 1.0, 1.0, responses=responses))

    result = study_identifiability(evaluations, study, space)

    alone = {entry["response"]: {row["name"]: row for row in entry["parameters"]}
             for entry in result["experiments"]}
    assert set(alone) == {"heap.angle_deg", "feeder.n_remaining"}
    assert "sqrt" not in result["experiments"][0]["method"] and "sqrt" in result["experiments"][1]["method"]
    for response in alone:  # each alone: a ridge of equally good (e, mu)
        assert alone[response]["mu"]["verdict"] == alone[response]["e"]["verdict"] == "weak"
        assert alone[response]["E"]["verdict"] == "not identifiable"
    together = {row["name"]: row for row in result["parameters"]}
    for name in ("e", "mu"):
        assert together[name]["verdict"] == "pinned", together[name]
        assert together[name]["pinned_together"] and together[name]["pinned_by"] == []
        assert together[name]["matching_spread"] < 0.3
    assert together["E"]["verdict"] == "not identifiable" and not together["E"]["pinned_together"]
