"""The ask/tell search: batch sizes, determinism from the seed, resume from saved state."""

from __future__ import annotations

import numpy as np
import pytest

from optimizer.ga import create_search, from_bytes, to_bytes
from optimizer.study import GASettings


def objectives(genes):
    return np.column_stack([np.abs(genes[:, 0] - 0.3), genes[:, 1]])


def feasible(genes):
    return np.full((len(genes), 2), -1.0)


@pytest.mark.parametrize("algorithm", ["nsga2", "spea2", "random"])
def test_batches_are_population_then_offspring(algorithm):
    search = create_search(GASettings(algorithm=algorithm, population=10, offspring=4), n_genes=4, seed=1)

    sizes = []
    for _ in range(3):
        genes = search.ask()
        sizes.append(genes.shape)
        assert ((genes >= 0) & (genes <= 1)).all()
        search.tell(genes, objectives(genes), feasible(genes))

    assert sizes == [(10, 4), (4, 4), (4, 4)]


def test_same_seed_same_individuals():
    settings = GASettings(population=10, offspring=4)
    first, second = create_search(settings, 4, seed=3), create_search(settings, 4, seed=3)

    for _ in range(3):
        a, b = first.ask(), second.ask()
        np.testing.assert_array_equal(a, b)
        first.tell(a, objectives(a), feasible(a))
        second.tell(b, objectives(b), feasible(b))


def test_restored_state_proposes_the_same_next_batch():
    search = create_search(GASettings(population=10, offspring=4), 4, seed=5)
    genes = search.ask()
    search.tell(genes, objectives(genes), feasible(genes))
    restored = from_bytes(to_bytes(search))

    np.testing.assert_array_equal(restored.ask(), search.ask())


@pytest.mark.parametrize("algorithm", ["nsga2", "spea2"])
def test_the_ga_never_asks_again_for_a_set_already_simulated(algorithm):
    """A set already simulated is known (its runs already count in its own and its neighbours'
    estimates): asking for it again spends a simulation on one more draw at a point the search
    has already measured, not on a new set. Before, crossover recreated dead sets (29 of 205 here
    for NSGA-II)."""
    search = create_search(GASettings(algorithm=algorithm, population=10, offspring=5), 4, seed=11)
    asked = []
    for _ in range(40):
        genes = search.ask()
        asked.extend(map(tuple, genes))
        search.tell(genes, objectives(genes), feasible(genes))
        search = from_bytes(to_bytes(search))  # as the driver stores it between batches

    assert len(asked) == 10 + 39 * 5
    assert len(set(asked)) == len(asked)


def test_nsga2_moves_towards_the_front():
    search = create_search(GASettings(population=20, offspring=10), 2, seed=0)
    first = search.ask()
    search.tell(first, objectives(first), feasible(first))
    for _ in range(15):
        genes = search.ask()
        search.tell(genes, objectives(genes), feasible(genes))

    survivors = search.algorithm.pop.get("X")
    # The true front is gene0 = 0.3, gene1 = 0; survivors sit much nearer than random points.
    assert np.median(np.abs(survivors[:, 0] - 0.3)) < np.median(np.abs(first[:, 0] - 0.3)) / 2


def _conflicting(genes, tolerance=0.05):
    """f1 is 0 at gene0 = 0.8, f2 falls towards gene0 = 0: match and cost pull apart, as on the
    feeder where the cheap soft sets empty the tray. Below gene0 = 0.2 runs are 'invalid'."""
    f1 = np.abs(genes[:, 0] - 0.8)
    f2 = genes[:, 0] + 0.1 * genes[:, 1]
    invalid = genes[:, 0] < 0.2
    f1 = np.where(invalid, 1.0, f1)
    constraints = np.column_stack([f1 - tolerance, np.where(invalid, 1.0 + (0.2 - genes[:, 0]), 0.0)])
    return np.column_stack([f1, f2]), constraints


@pytest.mark.parametrize("algorithm", ["nsga2", "spea2"])
def test_the_match_as_a_constraint_spends_the_budget_on_the_match(algorithm):
    constrained = create_search(GASettings(algorithm=algorithm, population=20, offspring=10), 2, seed=0)
    unconstrained = create_search(GASettings(algorithm=algorithm, population=20, offspring=10), 2, seed=0)
    for _ in range(10):
        genes = constrained.ask()
        constrained.tell(genes, *_conflicting(genes))
        genes = unconstrained.ask()
        objectives_only, _ = _conflicting(genes)
        unconstrained.tell(genes, objectives_only, feasible(genes))

    matched = np.abs(constrained.algorithm.pop.get("X")[:, 0] - 0.8) <= 0.05
    spread = np.abs(unconstrained.algorithm.pop.get("X")[:, 0] - 0.8) <= 0.05
    # Every survivor matches once matches exist; as two equal objectives most survivors sit on
    # the cheap side of the trade-off instead.
    assert matched.all()
    assert spread.mean() < 0.5
    assert (constrained.algorithm.pop.get("X")[:, 0] >= 0.2).all()


def test_infeasible_sets_rank_by_violation_and_never_beat_a_feasible_one():
    search = create_search(GASettings(population=6, offspring=6), 2, seed=0)
    genes = search.ask()
    genes[:, 0] = [0.05, 0.1, 0.15, 0.5, 0.79, 0.81]  # three invalid, one valid miss, two matches
    search.tell(genes, *_conflicting(genes))
    survivors = search.algorithm.pop
    cv = survivors.get("CV")[:, 0]
    by_gene = dict(zip(np.round(survivors.get("X")[:, 0], 2), cv, strict=True))
    assert by_gene[0.79] == by_gene[0.81] == 0
    assert 0 < by_gene[0.5] < by_gene[0.15] < by_gene[0.1] < by_gene[0.05]


@pytest.mark.parametrize("algorithm", ["nsga2", "spea2"])
def test_survivors_carry_the_papers_15_of_an_initial_50_without_changing_the_initial_draws(algorithm):
    """The paper: 50 initial individuals, 15 carried over to each next generation by elitist
    selection. The initial population is the same draw whatever the number kept."""
    kept = create_search(GASettings(algorithm=algorithm, population=12, offspring=4, survivors=4), 4, seed=7)
    whole = create_search(GASettings(algorithm=algorithm, population=12, offspring=4), 4, seed=7)

    first = kept.ask()
    np.testing.assert_array_equal(first, whole.ask())
    kept.tell(first, objectives(first), feasible(first))
    offspring = kept.ask()
    kept.tell(offspring, objectives(offspring), feasible(offspring))

    assert offspring.shape == (4, 4)
    survivors = kept.algorithm.pop.get("X")
    assert len(survivors) == 4
    # Elitist: the four kept are the four best of the sixteen on the (here single-front-ish) objectives.
    everyone = np.vstack([first, offspring])
    best = np.sort(objectives(everyone)[:, 0])[:2]
    assert np.isin(np.round(best, 12), np.round(objectives(survivors)[:, 0], 12)).all()


@pytest.mark.parametrize(
    ("settings", "fix"),
    [
        (dict(population=10, survivors=11), "at most 10"),
        (dict(algorithm="random", survivors=5), "choose a GA"),
        (dict(survivors=1), "greater than or equal to 2"),
    ],
)
def test_survivors_beyond_the_population_or_for_a_search_without_one_say_what_fits(settings, fix):
    with pytest.raises(ValueError, match=fix):
        GASettings(**settings)
