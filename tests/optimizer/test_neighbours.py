"""The GA's pooled estimate of a set's match (``ga.match_estimate = "neighbours"``)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.stats import wasserstein_distance

from optimizer.ga import create_search
from optimizer.neighbours import NeighbourEstimate
from optimizer.noise import wasserstein_floor
from optimizer.study import NOISE_FLOOR_QUANTILE, Experiment, GASettings
from optimizer.surrogate import MatchRule, Observation

MEASURED = (0, 0, 1, 2, 3, 4, 4, 12, 15, 16)
RULE = MatchRule(measured=MEASURED, target=4, tolerance=0.5)


def ok(*values):
    return Observation(tuple(values), 1.0, True)


FAILED = Observation((), 1.0, False)


def test_a_set_far_from_all_others_is_judged_on_its_own_runs():
    estimate = NeighbourEstimate((RULE,))
    estimate.remember(np.array([[0.1, 0.1], [0.9, 0.9]]), [ok(0, 2, 13), ok(30)])
    f1, violation = estimate.distances(np.array([[0.1, 0.1]]))
    own = wasserstein_distance([0, 2, 13], MEASURED)
    assert f1[0] == pytest.approx(own, rel=1e-6)  # the far set weighs exp(-0.8^2 2 / 0.08) ~ 1e-7
    # Three runs pooled: the floor is that of the experiment's own ten values, not of three.
    floor = wasserstein_floor(MEASURED, 10, NOISE_FLOOR_QUANTILE)
    assert violation[0] == pytest.approx(own - floor, rel=1e-5)


def test_the_floor_is_the_experiments_own_however_many_runs_pool():
    """A region of 60 runs, each of the experiment's values two items higher (W1 2.0), is as close
    as a repeat of the experiment would be (its floor, 3.1): feasible. The floor for the pooled
    size held it to 1.3 (calibration 19); 60 emptied trays stay infeasible (W1 5.7)."""
    region = np.array([[0.5 + 0.001 * k, 0.5] for k in range(60)])
    empty = np.array([[0.1 + 0.001 * k, 0.1] for k in range(60)])
    estimate = NeighbourEstimate((RULE,))
    estimate.remember(region, [ok(MEASURED[k % 10] + 2) for k in range(60)])
    estimate.remember(empty, [ok(0) for _ in range(60)])

    f1, violation = estimate.distances(np.array([[0.53, 0.5], [0.13, 0.1]]))

    assert estimate.floor(0) == pytest.approx(3.1, abs=0.01)
    assert wasserstein_floor(MEASURED, 60, NOISE_FLOOR_QUANTILE) < 1.4
    assert f1[0] == pytest.approx(2.0, abs=0.1) and violation[0] < 0 < violation[1]


def test_the_pooled_distance_falls_as_the_share_of_jams_nears_the_experiments():
    """From the emptying side the median reads |0 - 4| whatever the share of jams; the pooled W1
    must fall as that share rises towards the experiment's three in ten."""
    genes = np.array([[0.5, 0.5 + 0.01 * k] for k in range(10)])
    readings = []
    for jams in (0, 1, 2, 3):
        estimate = NeighbourEstimate((RULE,))
        estimate.remember(genes, [ok(14) if k < jams else ok(0) for k in range(10)])
        readings.append(estimate.distances(genes[:1])[0][0])
    assert readings[0] > readings[1] > readings[2] > readings[3]


def test_a_set_among_runs_like_the_experiment_is_feasible_and_one_among_empty_trays_is_not():
    cluster = np.array([[0.5 + 0.01 * k, 0.5] for k in range(10)])
    empty = np.array([[0.1 + 0.01 * k, 0.1] for k in range(10)])
    estimate = NeighbourEstimate((RULE,))
    estimate.remember(cluster, [ok(v) for v in MEASURED])
    estimate.remember(empty, [ok(0) for _ in range(10)])
    _, violation = estimate.distances(np.array([[0.52, 0.5], [0.12, 0.1]]))
    assert violation[0] <= 0 < violation[1]


def test_failed_sets_keep_their_violation_and_are_pooled_by_no_one():
    estimate = NeighbourEstimate((RULE,))
    genes = np.array([[0.5, 0.5], [0.51, 0.5]])
    estimate.remember(genes, [ok(4), FAILED])
    assert list(estimate.history) == [(0.5, 0.5)]
    objectives = np.array([[0.0, 1.0], [30.0, 2.0]])
    constraints = np.array([[-0.5, 0.0], [29.5, 1.0]])
    f, g = estimate.pooled(genes, objectives, constraints)
    assert f[1].tolist() == [30.0, 2.0] and g[1].tolist() == [29.5, 1.0]
    assert f[0, 0] == pytest.approx(wasserstein_distance([4], MEASURED)) and f[0, 1] == 1.0


def test_a_re_measured_set_replaces_its_runs():
    estimate = NeighbourEstimate((RULE,))
    estimate.remember(np.array([[0.5, 0.5]]), [ok(0)])
    estimate.remember(np.array([[0.5, 0.5]]), [ok(0, 4, 12)])
    assert estimate.history[(0.5, 0.5)] == {"n_remaining": (0, 4, 12)}


def test_the_ga_re_estimates_its_survivors_when_new_runs_arrive():
    rule = MatchRule(measured=MEASURED, target=4, tolerance=0.5)
    search = create_search(GASettings(population=8, offspring=4, match_estimate="neighbours"), 2, 0, rule)
    genes = search.ask()
    empty = [ok(0) for _ in genes]
    search.tell(genes, np.column_stack([np.full(len(genes), 4.0), genes[:, 1]]), np.zeros((8, 2)), empty)
    first = search.algorithm.pop
    before = {tuple(x): f[0] for x, f in zip(first.get("X"), first.get("F"), strict=True)}
    offspring = search.ask()
    jams = [ok(14) for _ in offspring]
    search.tell(offspring, np.column_stack([np.full(4, 10.0), offspring[:, 1]]), np.zeros((4, 2)), jams)
    now = search.algorithm.pop
    kept = [(tuple(x), f[0]) for x, f in zip(now.get("X"), now.get("F"), strict=True) if tuple(x) in before]
    changed = [f1 != before[x] for x, f1 in kept]
    assert changed and any(changed)  # the jams nearby moved the old survivors' pooled W1


def test_the_neighbours_estimate_is_deterministic_for_a_study_seed():
    rule = MatchRule(measured=MEASURED, target=4, tolerance=0.5)
    batches = []
    for _ in range(2):
        search = create_search(GASettings(population=8, offspring=4, match_estimate="neighbours"), 2, 7, rule)
        asked = []
        for _ in range(3):
            genes = search.ask()
            asked.append(genes)
            runs = [ok(int(14 * (g[0] > 0.6))) for g in genes]
            search.tell(genes, np.column_stack([genes[:, 0], genes[:, 1]]), np.zeros((len(genes), 2)), runs)
        batches.append(np.vstack(asked))
    assert np.array_equal(batches[0], batches[1])


def test_an_unknown_match_estimate_is_refused_with_the_choices():
    with pytest.raises(ValidationError, match="'own' or 'neighbours'"):
        GASettings(match_estimate="pooled")


def test_the_noise_floor_is_the_shared_bootstrap_rounded():
    experiment = Experiment(measured=list(MEASURED))
    assert experiment.noise_floor(3) == round(wasserstein_floor(MEASURED, 3, NOISE_FLOOR_QUANTILE), 2) == 5.03


@pytest.mark.parametrize("algorithm", ["surrogate", "random"])
def test_the_neighbours_estimate_with_a_search_that_is_no_ga_is_refused(algorithm):
    with pytest.raises(ValidationError, match="applies to 'nsga2' and 'spea2'"):
        GASettings(algorithm=algorithm, match_estimate="neighbours")


def test_a_survivor_whose_extra_replicate_failed_keeps_its_own_violation():
    search = create_search(GASettings(population=8, offspring=4, match_estimate="neighbours"), 2, 0, RULE)
    genes = search.ask()
    runs = [ok(4) for _ in genes]
    search.tell(genes, np.column_stack([np.full(8, 4.0), genes[:, 1]]), np.zeros((8, 2)), runs)
    survivor = search.algorithm.pop.get("X")[:1]
    search.revise(survivor, np.array([[30.0, 1.0]]), np.array([[29.5, 1.0]]), [FAILED])
    pop = search.algorithm.pop
    row = np.flatnonzero(np.all(pop.get("X") == survivor[0], axis=1))[0]
    assert pop.get("G")[row, 1] == 1.0 and pop.get("CV")[row, 0] > 0
    assert tuple(survivor[0]) not in search.estimate.history


def test_the_validation_reads_the_pooled_estimate_the_ga_ranked_with():
    """``pooled_evidence`` rebuilds the estimate from the stored runs; after the last generation
    it must read each measured set as the GA's own estimate, kept in its saved state, does."""
    from optimizer.driver import Driver
    from optimizer.ga import from_bytes
    from optimizer.memory import MemoryStore, SyntheticExecutor
    from optimizer.neighbours import pooled_evidence
    from optimizer.objectives import evaluate
    from optimizer.space import ParameterSpace
    from tests.optimizer.conftest import make_definition

    definition = make_definition(
        ga={"population": 10, "offspring": 5, "generations": 3, "match_estimate": "neighbours"},
        validation={"seeds": 0},
    )
    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"), None)
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    records = store.trials(study_id)
    evaluations = [ev for ev in evaluate(records, definition, definition.n_items()) if ev.ok]
    space = ParameterSpace(definition.parameters)

    pooled = pooled_evidence(evaluations, definition, space)
    estimate = from_bytes(store.load_study(study_id).ga_state).estimate
    w1, violation = estimate.distances(np.array([space.genes(ev.params) for ev in evaluations]))

    assert len(evaluations) >= 15
    assert [pooled[ev.individual].w1 for ev in evaluations] == pytest.approx(list(w1), abs=1e-9)
    assert [pooled[ev.individual].violation for ev in evaluations] == pytest.approx(list(violation), abs=1e-9)
