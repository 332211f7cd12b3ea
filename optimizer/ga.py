"""The search algorithm behind a study, driven with ask/tell: ``ask()`` gives the genes of the
next batch (the initial population, then each generation's offspring), something else simulates
them, ``tell(genes, F)`` hands back their objectives. It never calls a simulation.

- ``nsga2`` (default): pymoo's NSGA-II, elitist survival by rank and crowding, as the paper's
  MOGA: one-point crossover (``SinglePointCrossover``, probability ``ga.crossover_prob``),
  polynomial mutation with ``ga.mutation_prob`` per gene, binary tournament selection, duplicate
  elimination. ``ga.population`` individuals first, then ``ga.offspring`` per generation.
- ``spea2``: pymoo's strength Pareto EA (an elitist archive), with the same operators.
  Not offered: SMS-EMOA (pymoo 0.6.2's instance cannot be pickled, so its state could not
  survive a restart) and AGE-MOEA (its numba kernels compile for about 20 s in every process).
- ``random``: uniform random search with the same batch sizes: the honest baseline.

Genes live in [0, 1] (see ``optimizer/space.py``). Randomness comes only from the generator
seeded with the study seed (pymoo 0.6.2 keeps it in ``algorithm.random_state``), so a study is
deterministic given its seed and its objectives.

State is saved after every generation as a pickle of the algorithm (``to_bytes``/``from_bytes``).
Trust assumption: unpickling runs code, so GA state must only ever be read from demcal's own
database, which only demcal writes; it is never accepted from a client.
"""

from __future__ import annotations

import pickle

import numpy as np
from pymoo.core.evaluator import Evaluator
from pymoo.core.population import Population
from pymoo.core.problem import Problem
from pymoo.operators.crossover.pntx import SinglePointCrossover
from pymoo.operators.mutation.pm import PM
from pymoo.problems.static import StaticProblem

from optimizer.study import GASettings

N_OBJECTIVES = 2


class CalibrationProblem(Problem):
    """The box pymoo searches: n genes in [0, 1], two objectives. Never evaluated by pymoo."""

    def __init__(self, n_genes: int):
        super().__init__(n_var=n_genes, n_obj=N_OBJECTIVES, xl=0.0, xu=1.0)


class RandomSearch:
    """Uniform samples in the unit box, batch sizes as the GA's; tell only counts."""

    def __init__(self, n_genes: int, population: int, offspring: int, seed: int):
        self.n_genes = n_genes
        self.population = population
        self.offspring = offspring
        self.rng = np.random.default_rng(seed)
        self.told = 0

    def ask(self) -> np.ndarray:
        size = self.population if self.told == 0 else self.offspring
        return self.rng.random((size, self.n_genes))

    def tell(self, genes: np.ndarray, objectives: np.ndarray) -> None:
        self.told += 1


class PymooSearch:
    """A pymoo algorithm behind the same two calls."""

    def __init__(self, settings: GASettings, n_genes: int, seed: int):
        operators = dict(
            pop_size=settings.population,
            n_offsprings=settings.offspring,
            crossover=SinglePointCrossover(prob=settings.crossover_prob),
            mutation=PM(prob=1.0, prob_var=settings.mutation_prob),
            eliminate_duplicates=True,
        )
        if settings.algorithm == "spea2":
            from pymoo.algorithms.moo.spea2 import SPEA2 as Algorithm
        else:
            from pymoo.algorithms.moo.nsga2 import NSGA2 as Algorithm
        self.algorithm = Algorithm(**operators)
        # The driver decides when to stop; pymoo's own termination must never fire first.
        self.algorithm.setup(CalibrationProblem(n_genes), termination=("n_gen", 10**9), seed=seed)

    def ask(self) -> np.ndarray:
        return np.asarray(self.algorithm.ask().get("X"), dtype=float)

    def tell(self, genes: np.ndarray, objectives: np.ndarray) -> None:
        population = Population.new("X", np.asarray(genes, dtype=float))
        Evaluator().eval(
            StaticProblem(self.algorithm.problem, F=np.asarray(objectives, dtype=float)), population
        )
        self.algorithm.tell(infills=population)


Search = RandomSearch | PymooSearch


def create_search(settings: GASettings, n_genes: int, seed: int) -> Search:
    if settings.algorithm == "random":
        return RandomSearch(n_genes, settings.population, settings.offspring, seed)
    return PymooSearch(settings, n_genes, seed)


def to_bytes(search: Search) -> bytes:
    return pickle.dumps(search, protocol=pickle.HIGHEST_PROTOCOL)


def from_bytes(state: bytes) -> Search:
    """Restore a search saved by :func:`to_bytes`; only for state read from demcal's own store."""
    return pickle.loads(state)  # noqa: S301 - trusted by construction, see the module docstring
