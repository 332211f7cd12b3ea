"""What the GA ranks a set's match on when each set has one run or a few: the distribution of
its own runs pooled with its neighbours' in the search's history (``ga.match_estimate =
"neighbours"``), judged as a distribution against all measured values.

Why: on the full feeder the response is bimodal (the tray empties, N_t 0, or a jam keeps 7-27
items) and one run says little (N_t 0-19 over three seeds at one set). Ranked on its own run's
|N_t - 4|, a set that emptied the tray is 4 items from the paper's target and most jams are
further, so NSGA-II kept the sets that empty the tray: the median N_t of its generations sat at 0
in two seeds of the paper's study (benchmarks/README.md, "Full-feeder calibration", sections 10
and 12), although the experiment itself (0 0 1 2 3 4 4 12 15 16) jams in three runs of ten.

How:
- **Pooling.** The distribution of N_t changes smoothly with the parameters, so the runs of
  nearby sets are draws from nearly the same distribution. A set's sample is every run of the
  history, weighted ``exp(-d^2 / 2 h^2)`` by the distance d between the sets' genes (the unit box
  of log E, nu, e, mu; h = ``BANDWIDTH``; its own runs weigh 1). This is memory-based fitness
  estimation for noisy evolutionary search (Branke, Schmidt and Schmeck 2001, "Efficient fitness
  estimation in noisy environments"; Sano and Kita 2002): no extra simulation, and each new batch
  sharpens the estimates of the sets already in the population, so survivors are re-estimated
  before every survival. A set far from all others is judged on its own runs.
- **A distribution distance, whatever the study's own f1.** The pooled sample's Wasserstein-1
  distance to the measured values. A median is blind to how often the tray jams until it jams in
  half the runs: from the emptying side every set reads |0 - 4|. W1 falls steadily as the share
  of jams nears the experiment's, so the search has a slope to climb towards the match.
- **Feasible** when that W1 is within the experiment's own noise floor
  (``optimizer.noise.wasserstein_floor`` for the experiment's own number of values), however
  many runs pool: as close to the experiment as a repeat of it would be. Not a floor for the
  pooled size: for few runs it is loose (5.0 items for three runs against the paper's experiment,
  whose emptied tray scores 5.7: in the first generations most sets then counted as matching,
  and among matching sets NSGA-II keeps the cheapest, which empty the tray early), and for many
  it falls towards 0 (it resamples the ten measured values and compares them with themselves),
  while a perfect model's runs keep the ten values' own noise. With the floor for the pooled
  size (at least the experiment's), the regions the GA converged to, 50-70 pooled runs, were held
  to 1.2-1.3 items against 3.1 for sparse sets, so the estimate called infeasible exactly the
  regions the search sampled most (benchmarks/README.md, calibration 19). On the synthetic
  feeder of ``benchmarks/search_synthetic.py`` (the paper's protocol, a seed per run, 60 study
  seeds) the experiment's own floor brought the last three generations' true W1 from 2.84 to
  2.41 and the recommendation's from 3.01 to 2.49 (paired: -0.52 +- 0.17), validated 58 of 60
  recommendations against 53, at a fifth of the cost. Several experiments: the largest ratio
  W1 / floor must be <= 1.

What it changes: the F and G the GA compares (f1 = the pooled W1), and which sets the validation
re-simulates (``pooled_evidence``; ``optimizer/validation.py``). Views, the Pareto front and the
running recommendation use each set's own runs and the study's own f1. Failed sets (invalid,
unstable, ...) keep their own violation: they pool nothing and are pooled by no one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.stats import wasserstein_distance

from optimizer.noise import wasserstein_floor
from optimizer.objectives import Evaluation, match_rule, observation
from optimizer.space import ParameterSpace
from optimizer.study import NOISE_FLOOR_QUANTILE, StudyDefinition
from optimizer.surrogate import MatchRule, Observation

BANDWIDTH = 0.2  # h in genes: a neighbour 0.1 away weighs 0.88, 0.2 away 0.61, 0.4 away 0.14


@dataclass
class NeighbourEstimate:
    """The search's history of measured sets, and the pooled W1 of any set against the experiments."""

    rules: tuple[MatchRule, ...]
    bandwidth: float = BANDWIDTH
    history: dict[tuple[float, ...], dict[str, tuple[float, ...]]] = field(default_factory=dict)
    floors: dict[tuple[int, int], float] = field(default_factory=dict)  # (rule, its size) -> floor

    def remember(self, genes: np.ndarray, observations: Sequence[Observation]) -> None:
        """Add (or, for re-measured sets, replace) the runs of measured sets; failed ones are left out."""
        for row, seen in zip(np.asarray(genes, dtype=float), observations, strict=True):
            key = tuple(float(g) for g in row)
            if seen.ok:
                self.history[key] = {rule.response: seen.values(rule) for rule in self.rules}
            else:
                self.history.pop(key, None)

    def floor(self, index: int) -> float:
        """The experiment's own noise floor: that of as many runs as it has values."""
        n = len(self.rules[index].measured)
        if (index, n) not in self.floors:
            self.floors[index, n] = wasserstein_floor(self.rules[index].measured, n, NOISE_FLOOR_QUANTILE)
        return self.floors[index, n]

    def distances(self, genes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each row of ``genes``: the pooled W1 (several experiments: the largest W1 / floor)
        and the violation (W1 - floor; several: that ratio - 1). nan where the history is empty."""
        genes = np.atleast_2d(np.asarray(genes, dtype=float))
        if not self.history:
            return np.full(len(genes), np.nan), np.full(len(genes), np.nan)
        known = np.array(list(self.history), dtype=float)
        runs = list(self.history.values())
        gap = np.linalg.norm(genes[:, None, :] - known[None, :, :], axis=2)
        weights = np.exp(-0.5 * (gap / self.bandwidth) ** 2)  # (rows, known sets)
        samples = []  # per rule: every run's value and the index of the set it belongs to
        for rule in self.rules:
            values = [np.asarray(run[rule.response], dtype=float) for run in runs]
            owner = np.repeat(np.arange(len(runs)), [len(v) for v in values])
            samples.append((np.concatenate(values), owner))
        f1, violation = np.empty(len(genes)), np.empty(len(genes))
        for i, row in enumerate(weights):
            ratios = []
            for index, (rule, (values, owner)) in enumerate(zip(self.rules, samples, strict=True)):
                w = row[owner]
                w1 = float(wasserstein_distance(values, np.asarray(rule.measured, float), u_weights=w))
                ratios.append((w1, self.floor(index)))
            if len(ratios) == 1:
                f1[i], violation[i] = ratios[0][0], ratios[0][0] - ratios[0][1]
            else:
                f1[i] = max(w1 / max(floor, 1e-12) for w1, floor in ratios)
                violation[i] = f1[i] - 1.0
        return f1, violation

    def pooled(
        self, genes: np.ndarray, objectives: np.ndarray, constraints: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """F and G with f1 and g_match of the measured rows (g_validity <= 0) replaced by the
        pooled W1 and its violation; failed rows are returned as given."""
        objectives = np.array(objectives, dtype=float)
        constraints = np.array(constraints, dtype=float)
        rows = np.flatnonzero(constraints[:, 1] <= 0.0)
        if len(rows) == 0 or not self.history:
            return objectives, constraints
        objectives[rows, 0], constraints[rows, 0] = self.distances(np.asarray(genes, dtype=float)[rows])
        return objectives, constraints


class PooledMatch(NamedTuple):
    """What the search's runs around a set say of it: the pooled W1 and its violation (as the GA
    ranks it), and the share of the neighbourhood's runs that failed (invalid, unstable, ...),
    weighted as the pooling weighs them, which the pooled W1 leaves out."""

    w1: float
    violation: float
    failed_share: float


def pooled_evidence(
    evaluations: Sequence[Evaluation], definition: StudyDefinition, space: ParameterSpace
) -> dict[int, PooledMatch] | None:
    """Each measured set's pooled match over the whole search's history, by individual: what the
    GA's estimate reads after its last generation, rebuilt from the stored runs. None for a study
    whose search does not rank on it (``ga.match_estimate = "own"``)."""
    if definition.ga.match_estimate != "neighbours":
        return None
    rule = match_rule(definition, definition.n_items())
    estimate = NeighbourEstimate(rule if isinstance(rule, tuple) else (rule,))
    measured = [evaluation for evaluation in evaluations if evaluation.ok]
    if not measured:
        return {}
    genes = np.array([space.genes(evaluation.params) for evaluation in measured])
    estimate.remember(genes, [observation(evaluation) for evaluation in measured])
    w1, violation = estimate.distances(genes)
    every = np.array([space.genes(evaluation.params) for evaluation in evaluations])
    runs = np.array([max(evaluation.n_replicates, 1) for evaluation in evaluations], dtype=float)
    failed = np.array([not evaluation.ok for evaluation in evaluations], dtype=float)
    gap = np.linalg.norm(genes[:, None, :] - every[None, :, :], axis=2)
    weights = np.exp(-0.5 * (gap / estimate.bandwidth) ** 2) * runs
    failed_share = (weights * failed).sum(axis=1) / weights.sum(axis=1)
    return {
        evaluation.individual: PooledMatch(float(w), float(v), float(f))
        for evaluation, w, v, f in zip(measured, w1, violation, failed_share, strict=True)
    }
