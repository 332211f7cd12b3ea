"""The ask/tell search: batch sizes, determinism from the seed, resume from saved state."""

from __future__ import annotations

import numpy as np
import pytest

from optimizer.ga import create_search, from_bytes, to_bytes
from optimizer.study import GASettings


def objectives(genes):
    return np.column_stack([np.abs(genes[:, 0] - 0.3), genes[:, 1]])


@pytest.mark.parametrize("algorithm", ["nsga2", "spea2", "random"])
def test_batches_are_population_then_offspring(algorithm):
    search = create_search(GASettings(algorithm=algorithm, population=10, offspring=4), n_genes=4, seed=1)

    sizes = []
    for _ in range(3):
        genes = search.ask()
        sizes.append(genes.shape)
        assert ((genes >= 0) & (genes <= 1)).all()
        search.tell(genes, objectives(genes))

    assert sizes == [(10, 4), (4, 4), (4, 4)]


def test_same_seed_same_individuals():
    settings = GASettings(population=10, offspring=4)
    first, second = create_search(settings, 4, seed=3), create_search(settings, 4, seed=3)

    for _ in range(3):
        a, b = first.ask(), second.ask()
        np.testing.assert_array_equal(a, b)
        first.tell(a, objectives(a))
        second.tell(b, objectives(b))


def test_restored_state_proposes_the_same_next_batch():
    search = create_search(GASettings(population=10, offspring=4), 4, seed=5)
    genes = search.ask()
    search.tell(genes, objectives(genes))
    restored = from_bytes(to_bytes(search))

    np.testing.assert_array_equal(restored.ask(), search.ask())


def test_nsga2_moves_towards_the_front():
    search = create_search(GASettings(population=20, offspring=10), 2, seed=0)
    first = search.ask()
    search.tell(first, objectives(first))
    for _ in range(15):
        genes = search.ask()
        search.tell(genes, objectives(genes))

    survivors = search.algorithm.pop.get("X")
    # The true front is gene0 = 0.3, gene1 = 0; survivors sit much nearer than random points.
    assert np.median(np.abs(survivors[:, 0] - 0.3)) < np.median(np.abs(first[:, 0] - 0.3)) / 2
