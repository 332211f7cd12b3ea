"""The convergence benchmark's run order: ``--first-seed`` adds seeds to columns run before."""

from __future__ import annotations

from benchmarks.convergence import run_order


def test_first_seed_runs_only_the_later_seeds_each_in_every_cell():
    order = run_order(first_seed=5, seeds=5, sets=["empties", "clogs"], shapes=["24", "poly"])

    assert [seed for seed, _, _ in order] == [s for s in range(5, 10) for _ in range(4)]
    cells = [(name, shape) for _, name, shape in order[:4]]
    assert cells == [("empties", "24"), ("empties", "poly"), ("clogs", "24"), ("clogs", "poly")]
    assert order[4:8] == [(6, name, shape) for name, shape in cells]
