"""The search algorithm behind a study, driven with ask/tell: ``ask()`` gives the genes of the
next batch (the initial population, then each generation's offspring), something else simulates
them, ``tell(genes, F, G)`` hands back their objectives and constraints. It never calls a
simulation.

The interface every algorithm implements (``Search``), rows in ``ask()``'s order:

- ``F`` (n x 2): f1 (match) and f2 (cost), both minimised (``optimizer/objectives.py``);
- ``G`` (n x 2): ``g_match = f1 - tolerance`` and ``g_validity`` (0 for a set whose replicates are
  all measurements, > 0 for ``invalid`` or otherwise failed runs), feasible when <= 0;
- ``observations``: optional, by keyword: each row's measured N_t (the surrogate models them);
- ``revise(genes, F, G)``: earlier individuals got more replicates; their F and G changed.

Why constraints: the paper's problem is "equate N_t with the experiment, then minimise T". With
match and cost as two equal objectives NSGA-II spent the paper's budget in the cheap corner where
the tray empties (185 simulations, no match). With the match as a constraint, pymoo's feasibility
rules (Deb 2000: feasible beats infeasible, two infeasible sets compare by violation, two feasible
ones by rank and crowding on F) make every comparison before the first match a comparison of f1,
so the budget goes to the match; among matching sets the search is multi-objective on (f1, f2),
which keeps the fastest matching set and the trade-off within the tolerance. An invalid run is a
violation larger than any valid set's, never a measurement of N_t. A lexicographic order would
rank the same way but lose the spread within the tolerance that NSGA-II's crowding keeps.

- ``nsga2`` (default): pymoo's NSGA-II, elitist survival by rank and crowding, as the paper's
  MOGA: one-point crossover (``SinglePointCrossover``, probability ``ga.crossover_prob``),
  polynomial mutation with ``ga.mutation_prob`` per gene, binary tournament selection, duplicate
  elimination. ``ga.population`` individuals first, then ``ga.offspring`` per generation, bred
  from the ``ga.survivors`` that each elitist survival keeps (the paper: 50, 15 and 15).
- ``spea2``: pymoo's strength Pareto EA (an elitist archive), with the same operators.
  Not offered: SMS-EMOA (pymoo 0.6.2's instance cannot be pickled, so its state could not
  survive a restart) and AGE-MOEA (its numba kernels compile for about 20 s in every process).
- ``random``: uniform random search with the same batch sizes: the honest baseline.
- ``surrogate``: Gaussian-process models of the response's distribution, the cost and the
  failures choose each batch (``optimizer/surrogate.py``).

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
from pymoo.core.duplicate import DefaultDuplicateElimination
from pymoo.core.evaluator import Evaluator
from pymoo.core.population import Population
from pymoo.core.problem import Problem
from pymoo.operators.crossover.pntx import SinglePointCrossover
from pymoo.operators.mutation.pm import PM
from pymoo.operators.sampling.rnd import FloatRandomSampling
from pymoo.problems.static import StaticProblem

from optimizer.neighbours import NeighbourEstimate
from optimizer.study import GASettings
from optimizer.surrogate import MatchRule, SurrogateSearch

N_OBJECTIVES = 2
N_CONSTRAINTS = 2  # g_match, g_validity


class CalibrationProblem(Problem):
    """The box pymoo searches: n genes in [0, 1], two objectives, two inequality constraints.
    Never evaluated by pymoo."""

    def __init__(self, n_genes: int):
        super().__init__(n_var=n_genes, n_obj=N_OBJECTIVES, n_ieq_constr=N_CONSTRAINTS, xl=0.0, xu=1.0)


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

    def tell(
        self,
        genes: np.ndarray,
        objectives: np.ndarray,
        constraints: np.ndarray | None = None,
        observations=None,
    ) -> None:
        self.told += 1

    def revise(
        self, genes: np.ndarray, objectives: np.ndarray, constraints: np.ndarray, observations=None
    ) -> None:
        """Nothing to revise: random search keeps no memory of its samples."""


class InitialSampling(FloatRandomSampling):
    """Uniform initial individuals, ``ga.population`` of them even when the survivors are fewer:
    pymoo otherwise samples as many as it keeps. The draws are the same as pymoo's own sampling of
    that many, so the initial population does not depend on ``ga.survivors``."""

    def __init__(self, size: int):
        super().__init__()
        self.size = size

    def _do(self, problem, n_samples, **kwargs):
        return super()._do(problem, self.size, **kwargs)


class EvaluatedDuplicateElimination(DefaultDuplicateElimination):
    """pymoo's duplicate check, also against every set already simulated. pymoo compares offspring
    only with the living population, so crossover recreated sets that had died out: 29 of 205 sets
    asked of NSGA-II on a toy problem, and 8 of 60 simulations of a full-feeder search re-ran a set
    already measured (then on the same seed; with new seeds per generation it would be one more
    draw at a known point, which the budget buys better as a new set)."""

    def __init__(self) -> None:
        super().__init__()
        self.evaluated = Population.new("X", np.empty((0, 0)))

    def remember(self, genes: np.ndarray) -> None:
        self.evaluated = Population.merge(self.evaluated, Population.new("X", np.asarray(genes, dtype=float)))

    def do(self, pop, *args, **kwargs):
        earlier = (self.evaluated,) if len(self.evaluated) else ()
        return super().do(pop, *args, *earlier, **kwargs)


class PymooSearch:
    """A pymoo algorithm behind the same two calls."""

    estimate: NeighbourEstimate | None = None  # None: each set is ranked on its own runs (and in
    # searches pickled before the neighbours' estimate existed)

    def __init__(
        self, settings: GASettings, n_genes: int, seed: int, estimate: NeighbourEstimate | None = None
    ):
        self.estimate = estimate
        operators = dict(
            pop_size=settings.survivors_kept(),
            sampling=InitialSampling(settings.population),
            n_offsprings=settings.offspring,
            crossover=SinglePointCrossover(prob=settings.crossover_prob),
            mutation=PM(prob=1.0, prob_var=settings.mutation_prob),
            eliminate_duplicates=EvaluatedDuplicateElimination(),
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

    def tell(
        self,
        genes: np.ndarray,
        objectives: np.ndarray,
        constraints: np.ndarray | None = None,
        observations=None,
    ) -> None:
        population = Population.new("X", np.asarray(genes, dtype=float))
        duplicates = self.algorithm.eliminate_duplicates
        if isinstance(duplicates, EvaluatedDuplicateElimination):  # searches saved before it: plain
            duplicates.remember(genes)
        objectives = np.asarray(objectives, dtype=float)
        if constraints is None:  # no constraint known: every set counts as feasible
            constraints = np.zeros((len(objectives), N_CONSTRAINTS))
        constraints = np.asarray(constraints, dtype=float)
        if self.estimate is not None and observations is not None:
            self.estimate.remember(genes, observations)
            objectives, constraints = self.estimate.pooled(genes, objectives, constraints)
            self._re_estimate_survivors()
        values = dict(F=objectives, G=constraints)
        Evaluator().eval(StaticProblem(self.algorithm.problem, **values), population)
        self.algorithm.tell(infills=population)

    def _re_estimate_survivors(self) -> None:
        """The new runs sharpen the pooled f1 of the living population: update it before survival."""
        population = self.algorithm.pop
        if population is None or len(population) == 0:
            return
        objectives, constraints = self.estimate.pooled(
            population.get("X"), population.get("F"), population.get("G")
        )
        for individual, f, g in zip(population, objectives, constraints, strict=True):
            _set_objectives(individual, f, g)

    def revise(
        self, genes: np.ndarray, objectives: np.ndarray, constraints: np.ndarray, observations=None
    ) -> None:
        """Earlier individuals were re-measured (extra replicates): survivors with these genes take
        the new F and G, so an elite that stopped matching loses its place at the next survival.
        With the neighbours' estimate the new runs then re-pool every survivor; a set whose new
        replicate failed keeps its own violation."""
        population = self.algorithm.pop
        if population is None or len(population) == 0:
            return
        kept = population.get("X")
        for row, gene in enumerate(np.asarray(genes, dtype=float)):
            for index in np.flatnonzero(np.all(np.isclose(kept, gene, rtol=0, atol=1e-12), axis=1)):
                _set_objectives(population[index], objectives[row], constraints[row])
        if self.estimate is not None and observations is not None:
            self.estimate.remember(genes, observations)
            self._re_estimate_survivors()


def _set_objectives(individual, objectives, constraints) -> None:
    individual.F = np.asarray(objectives, dtype=float)
    individual.G = np.asarray(constraints, dtype=float)
    individual.CV = None  # recomputed from G on the next read


Search = RandomSearch | PymooSearch | SurrogateSearch


def create_search(
    settings: GASettings, n_genes: int, seed: int, rule: MatchRule | tuple[MatchRule, ...] | None = None
) -> Search:
    """The study's search; ``rule`` (how f1 is formed, one per experiment) is needed by the
    surrogate and by the GA's neighbours' estimate (``optimizer/neighbours.py``)."""
    if settings.algorithm == "random":
        return RandomSearch(n_genes, settings.population, settings.offspring, seed)
    if settings.algorithm == "surrogate":
        if rule is None:
            raise ValueError("the surrogate search needs the study's match rule")
        return SurrogateSearch(n_genes, settings.population, settings.offspring, seed, rule)
    estimate = None
    if settings.match_estimate == "neighbours":
        if rule is None:
            raise ValueError("the neighbours' estimate needs the study's match rule")
        estimate = NeighbourEstimate(rule if isinstance(rule, tuple) else (rule,))
    return PymooSearch(settings, n_genes, seed, estimate)


def to_bytes(search: Search) -> bytes:
    return pickle.dumps(search, protocol=pickle.HIGHEST_PROTOCOL)


def from_bytes(state: bytes) -> Search:
    """Restore a search saved by :func:`to_bytes`; only for state read from demcal's own store."""
    return pickle.loads(state)  # noqa: S301 - trusted by construction, see the module docstring
