"""Pareto fronts, the recommendation rule and the equivalent sets."""

from __future__ import annotations

from optimizer.objectives import Evaluation
from optimizer.pareto import fronts, rank
from optimizer.space import ParameterSpace
from optimizer.study import Parameters

SPACE = ParameterSpace(Parameters())


def individual(index, f1, f2, mu=0.5, failure=""):
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": mu}
    return Evaluation(index, 0, params, f1, f2, [], 0.0, f2, [f"t{index}"], failure)


def test_fronts_follow_dominance():
    a, b, c, d = individual(0, 0, 10), individual(1, 2, 5), individual(2, 3, 6), individual(3, 5, 1)

    ranked = fronts([a, b, c, d])

    assert [[ev.individual for ev in front] for front in ranked] == [[3, 1, 0], [2]]


def test_recommendation_is_the_fastest_within_tolerance():
    exact_but_slow = individual(0, 0.0, 100.0)
    close_and_fast = individual(1, 0.5, 40.0, mu=0.9)
    fastest_but_off = individual(2, 3.0, 10.0)

    ranking = rank([exact_but_slow, close_and_fast, fastest_but_off], tolerance=0.5, space=SPACE)

    assert ranking.recommendation.individual == 1
    assert [ev.individual for ev in ranking.pareto] == [2, 1, 0]


def test_failed_individual_is_never_recommended():
    crashed = individual(0, 0.0, 1.0, failure="unstable: NaN")

    ranking = rank([crashed, individual(1, 3.0, 5.0)], tolerance=0.5, space=SPACE)

    assert ranking.recommendation is None
    assert ranking.best_f1 == 3.0


def test_equivalent_sets_are_distinct_in_parameter_space():
    chosen = individual(0, 0.0, 10.0, mu=0.20)
    twin = individual(1, 0.0, 11.0, mu=0.21)  # 0.01 / 0.95 of the mu range, gene distance ~ 0.005
    other_mode = individual(2, 0.5, 30.0, mu=0.90)

    ranking = rank([chosen, twin, other_mode], tolerance=0.5, space=SPACE)

    assert ranking.recommendation.individual == 0
    assert [ev.individual for ev in ranking.equivalent] == [2]


def test_no_match_means_no_recommendation():
    ranking = rank([individual(0, 1.0, 1.0)], tolerance=0.5, space=SPACE)

    assert ranking.recommendation is None
    assert ranking.equivalent == []
