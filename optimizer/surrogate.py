"""Surrogate-assisted batch search (``ga.algorithm = "surrogate"``): models of the simulator
decide where the next batch of simulations goes, so that far fewer DEM runs reach a match.

The problem it serves is "match first": among parameter sets whose simulated N_t reproduces the
experiment, the cheapest. Each batch is chosen as follows.

- **Response distribution** (a two-part "hurdle" model, because the feeder either empties
  or clogs: the full feeder's N_t at one set was 0, 3, 19 over three seeds, so a single normal
  around a mean would put the median where no run lands):
  - a Gaussian-process classifier gives ``p(x) = P(N_t > 0)`` (the chance that a run clogs);
  - a Gaussian process on ``y = 2 sqrt(N_t + 3/8)`` of the runs that clogged gives how many
    items stay when it clogs (Anscombe's transform makes a count's seed-to-seed variance roughly
    independent of its level, so one white-noise term, learned from the data, is that spread).
  Both use a constant x Matern 5/2 kernel with one length scale per parameter (ARD) over the
  genes (log E, nu, e, mu in [0, 1]). At a set x they give a distribution of N_t (0 with
  probability 1 - p, else the clog's size), so the match can be judged on the median, the mean
  or the Wasserstein-1 distance to all measured values, as the study asks.
- **Probability of a match** ``P(f1 <= tolerance)``: f1 (the study's own distance) of the
  distribution above, integrated over both models' posteriors (the classifier's latent and the
  size's latent, Gauss-Hermite quadrature, 12 x 12 nodes).
- **Feasibility.** A Gaussian-process classifier on ok vs failed (invalid, unstable, ...) runs
  gives ``P(ok)``; failures never enter the response model.
- **Cost.** A Gaussian process on log(cost) (f2) of the successful sets.
- **Several experiments** (a heap's angle and the feeder's N_t, say): one clog and size model
  per experiment's response, each judged by its own rule; the study's combined f1 (max over
  experiments of distance / tolerance, ``optimizer/objectives.py``) is <= 1 exactly when every
  experiment matches, so P(match) is the product of the experiments' P(match) (the models are
  fitted apart, so their posteriors are independent). A real-valued response (an angle) goes
  through the same two parts: it is never 0, so the clog part is then a constant near 1 and the
  size part models the value. Feasibility and cost are one model each: they belong to the run,
  not to a response.
- **Acquisition** (constrained expected improvement, Gardner et al. 2014, "Bayesian optimization
  with inequality constraints"): while nothing has matched, ``P(ok) P(match)``: every simulation
  goes to the match; once a set matched, ``P(ok) P(match) EI(log cost)`` below the cheapest
  matching set. This is the lexicographic order of the problem itself (issue 11, item 0); a
  hypervolume or ParEGO scalarisation would keep spending simulations on the cheap sets that do
  not match, which is what went wrong with NSGA-II on the paper's study.
- **Batches** for parallel workers: greedy selection on 2048 scrambled Sobol candidates plus
  local perturbations of the best sets so far; after each pick, the acquisition is damped by
  ``1 - rho(x, pick)`` with rho the fitted kernel's correlation (the variance reduction a
  "kriging believer" would give), so one batch spreads over distinct sets.
  The first batch is a Latin hypercube (space-filling, better than uniform for the first fit).

Library: scikit-learn's ``GaussianProcessRegressor`` / ``GaussianProcessClassifier``: exact GPs
with ARD Matern kernels and a Laplace classifier, CPU-only, small, already the standard for
n < 1000 points (a study has at most a few hundred). BoTorch would bring qEHVI and exact
constrained acquisitions, but also PyTorch (~800 MB) into every worker image for four
dimensions and a few hundred points; an inner pymoo optimisation is not needed either, because
the acquisition is cheap to evaluate densely in four dimensions.

Determinism: everything random (Latin hypercube, Sobol scrambling, perturbations, the GP
optimiser's restarts) draws from a generator seeded with (study seed, batch index), so a study's
proposals are a function of its seed and its results, and a re-asked batch after a restart is
identical. State is the observed data only (models are refitted at each ask), plain numpy and
dataclasses, pickled by ``optimizer.ga.to_bytes`` like the GA.

This module proposes genes; it must not run simulations, read stores or know about parameters'
units (the driver maps genes to parameters).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import norm, qmc

N_CANDIDATES = 2048
N_LOCAL = 512


@dataclass(frozen=True)
class Observation:
    """What one simulated parameter set told the search."""

    n_remaining: tuple[int, ...]  # N_t (the first experiment's response) of each successful replicate
    cost: float  # f2 of the set (mean over replicates), > 0
    ok: bool  # False: the set failed (invalid, unstable, timeout, error): a constraint violation
    responses: dict[str, tuple[float, ...]] = field(default_factory=dict)  # every experiment's

    def values(self, rule: MatchRule) -> tuple[float, ...]:
        """The replicates' values of the response ``rule`` judges (N_t when only that is known)."""
        return tuple(self.responses[rule.response]) if self.responses else self.n_remaining


@dataclass(frozen=True)
class MatchRule:
    """How f1 is formed from a distribution of N_t: the study's experiment, in plain numbers."""

    measured: tuple[float, ...]
    target: float
    tolerance: float
    aggregate: str = "median"  # "median" or "mean"
    distance: str = "aggregate"  # "aggregate" or "wasserstein"
    n_items: float = 30  # the response's value of a failed run: the largest a count can be
    response: str = "n_remaining"


def anscombe(n_remaining: np.ndarray) -> np.ndarray:
    return 2.0 * np.sqrt(np.asarray(n_remaining, dtype=float) + 0.375)


def inverse_anscombe(y: np.ndarray) -> np.ndarray:
    return np.maximum(np.asarray(y, dtype=float) / 2.0, 0.0) ** 2 - 0.375


def mixture_quantiles(p_clog: np.ndarray, latent: np.ndarray, noise_sd: float, levels: np.ndarray):
    """Quantiles of N_t: 0 with probability 1 - p, else inverse-Anscombe of Normal(latent, noise_sd)."""
    p = np.clip(p_clog, 1e-9, 1.0)[..., None]
    within = np.clip((levels - (1.0 - p)) / p, 1e-9, 1.0 - 1e-9)
    size = inverse_anscombe(latent[..., None] + noise_sd * norm.ppf(within))
    return np.where(levels < 1.0 - p, 0.0, np.maximum(size, 0.0))


def f1_of_distribution(rule: MatchRule, p_clog, latent, noise_sd: float) -> np.ndarray:
    """f1 of the N_t distribution given by the clog probability and the clog size's latent."""
    p_clog, latent = np.broadcast_arrays(np.asarray(p_clog, float), np.asarray(latent, float))
    if rule.distance == "wasserstein":
        levels = (np.arange(32) + 0.5) / 32
        simulated = np.minimum(mixture_quantiles(p_clog, latent, noise_sd, levels), rule.n_items)
        measured = np.quantile(np.asarray(rule.measured, dtype=float), levels, method="inverted_cdf")
        return np.abs(simulated - measured).mean(axis=-1)
    if rule.aggregate == "mean":
        # p E[(Y/2)^2 - 3/8] for Y ~ Normal(latent, noise_sd)
        value = p_clog * np.maximum((latent**2 + noise_sd**2) / 4.0 - 0.375, 0.0)
    else:
        value = mixture_quantiles(p_clog, latent, noise_sd, np.array([0.5]))[..., 0]
    return np.abs(np.minimum(value, rule.n_items) - rule.target)


NODES, WEIGHTS = np.polynomial.hermite_e.hermegauss(12)
WEIGHTS = WEIGHTS / WEIGHTS.sum()
PRIOR_SIZE = (anscombe(5.0), 2.5)  # a clog's size before any run clogged: a few to many items


@dataclass
class ResponseModel:
    """The fitted models at one moment; rebuilt from the data at every ask."""

    clog: object | None  # GaussianProcessClassifier on N_t > 0 (ok runs); None: one class only
    clog_share: float  # with one class only: the smoothed share of runs that clogged
    size: object | None  # GaussianProcessRegressor on anscombe(N_t) of runs that clogged
    size_prior: tuple[float, float]  # (mean, sd) of the size latent when there is no size model
    noise_sd: float  # spread of one run's size around its latent (Anscombe units)
    cost: object | None  # GaussianProcessRegressor on log(cost)
    feasibility: object | None  # GaussianProcessClassifier (ok = 1), None when one class only
    all_failed: bool = False

    def clog_latent(self, genes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and sd of the classifier's latent f, with P(clog) = sigmoid(f)."""
        if self.clog is None:
            share = np.clip(self.clog_share, 1e-6, 1 - 1e-6)
            return np.full(len(genes), np.log(share / (1 - share))), np.full(len(genes), 1.0)
        mean, variance = self.clog.latent_mean_and_variance(genes)
        return mean, np.sqrt(np.maximum(variance, 1e-10))

    def size_latent(self, genes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.size is None:
            return np.full(len(genes), self.size_prior[0]), np.full(len(genes), self.size_prior[1])
        mean, sd = self.size.predict(genes, return_std=True)
        return mean, np.sqrt(np.maximum(sd**2 - self.noise_sd**2, 1e-10))

    def p_ok(self, genes: np.ndarray) -> np.ndarray:
        if self.feasibility is None:
            return np.full(len(genes), 0.5 if self.all_failed else 1.0)
        return self.feasibility.predict_proba(genes)[:, 1]

    def p_match(self, genes: np.ndarray, rule: MatchRule) -> np.ndarray:
        """P(f1 <= tolerance) over both latents' posteriors (Gauss-Hermite, independent)."""
        if self.all_failed:
            return np.full(len(genes), 0.5)
        f_mean, f_sd = self.clog_latent(genes)
        m_mean, m_sd = self.size_latent(genes)
        p = 1.0 / (1.0 + np.exp(-(f_mean[:, None] + f_sd[:, None] * NODES[None, :])))  # (n, 12)
        m = m_mean[:, None] + m_sd[:, None] * NODES[None, :]  # (n, 12)
        inside = (
            f1_of_distribution(rule, p[:, :, None], m[:, None, :], self.noise_sd) <= rule.tolerance + 1e-9
        )
        return np.einsum("nij,i,j->n", inside.astype(float), WEIGHTS, WEIGHTS)

    def log_cost(self, genes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.cost.predict(genes, return_std=True)


@dataclass
class Models:
    """One :class:`ResponseModel` per experiment (same order as the rules); the first carries the
    feasibility and cost models, which belong to the run, not to a response."""

    responses: list[ResponseModel]

    @property
    def size(self):
        return self.responses[0].size

    @property
    def cost(self):
        return self.responses[0].cost

    def p_ok(self, genes: np.ndarray) -> np.ndarray:
        return self.responses[0].p_ok(genes)

    def log_cost(self, genes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.responses[0].log_cost(genes)

    def p_match(self, genes: np.ndarray, rules: Sequence[MatchRule]) -> np.ndarray:
        """P(every experiment matches): the product over experiments (independent models)."""
        value = np.ones(len(genes))
        for model, rule in zip(self.responses, rules, strict=True):
            value = value * model.p_match(genes, rule)
        return value


def _kernel(n_genes: int, noise: bool):
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    kernel = ConstantKernel(1.0, (1e-2, 1e2)) * Matern(
        length_scale=np.full(n_genes, 0.3), length_scale_bounds=(0.1, 30.0), nu=2.5
    )
    # The noise floor (in units of the data's variance) keeps a few single-seed runs from being
    # interpolated as if they were exact: DEM counts scatter from seed to seed.
    return kernel + WhiteKernel(0.2, (0.03, 10.0)) if noise else kernel


def fit_gp(genes: np.ndarray, values: np.ndarray, random_state: int):
    """An exact GP with ARD Matern 5/2 + white noise, hyperparameters by maximum likelihood."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor

    model = GaussianProcessRegressor(
        kernel=_kernel(genes.shape[1], noise=True),
        normalize_y=True,
        n_restarts_optimizer=1,
        random_state=random_state,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(genes, values)
    return model


def noise_sd(model) -> float:
    """The fitted white-noise standard deviation in the response's own units."""
    white = model.kernel_.k2.noise_level
    return float(np.sqrt(white) * np.atleast_1d(model._y_train_std)[0])


def length_scales(model) -> np.ndarray:
    return np.atleast_1d(model.kernel_.k1.k2.length_scale).astype(float)


def fit_classifier(genes: np.ndarray, labels: np.ndarray, random_state: int):
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessClassifier

    model = GaussianProcessClassifier(kernel=_kernel(genes.shape[1], noise=False), random_state=random_state)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(genes, labels.astype(int))
    return model


def fit_models(
    genes: np.ndarray,
    observations: Sequence[Observation],
    random_state: int,
    with_cost: bool = True,
    rule: MatchRule | None = None,
    with_feasibility: bool = True,
) -> ResponseModel:
    """Fit the clog and size models of ``rule``'s response (default: N_t), and the feasibility
    (``with_feasibility``) and cost (``with_cost``) models, to everything observed."""
    ok = np.array([observation.ok for observation in observations], dtype=bool)
    runs = [
        (gene, n)
        for gene, observation in zip(genes, observations, strict=True)
        if observation.ok
        for n in (observation.n_remaining if rule is None else observation.values(rule))
    ]
    x = np.array([gene for gene, _ in runs]).reshape(len(runs), genes.shape[1])
    counts = np.array([n for _, n in runs], dtype=float)
    clogged = counts > 0
    clog = None
    share = (clogged.sum() + 0.5) / (len(counts) + 1.0)
    if 0 < clogged.sum() < len(counts):
        clog = fit_classifier(x, clogged, random_state)
    size, noise, prior = None, 1.0, PRIOR_SIZE
    if clogged.sum() >= 3:
        size = fit_gp(x[clogged], anscombe(counts[clogged]), random_state)
        noise = noise_sd(size)
    elif clogged.any():
        prior = (float(anscombe(counts[clogged]).mean()), 1.5)
    cost = None
    if with_cost and ok.sum() >= 2:
        costs = np.log(np.array([max(observations[i].cost, 1e-300) for i in np.flatnonzero(ok)]))
        cost = fit_gp(genes[ok], costs, random_state)
    feasibility = None
    if with_feasibility and 0 < ok.sum() < len(ok):
        feasibility = fit_classifier(genes, ok, random_state)
    return ResponseModel(clog, float(share), size, prior, noise, cost, feasibility, all_failed=not ok.any())


def one_blas_thread():
    """BLAS on one thread: a study's matrices are small (n < 1000), and BLAS threads only
    contend with the simulations (one ask took 2.1 s of CPU with OpenBLAS threads on the loaded
    2-core machine, 0.18 s on one)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def expected_improvement(mean: np.ndarray, sd: np.ndarray, best: float) -> np.ndarray:
    """EI of a quantity to minimise below ``best``."""
    sd = np.maximum(sd, 1e-12)
    z = (best - mean) / sd
    return (best - mean) * norm.cdf(z) + sd * norm.pdf(z)


@dataclass
class SurrogateSearch:
    """Ask/tell like the GA: ``population`` sets first, then ``offspring`` per batch."""

    n_genes: int
    population: int
    offspring: int
    seed: int
    rule: MatchRule | tuple[MatchRule, ...]  # one per experiment (a bare rule: one experiment)
    genes: list[list[float]] = field(default_factory=list)
    observations: list[Observation] = field(default_factory=list)
    told: int = 0

    @property
    def rules(self) -> tuple[MatchRule, ...]:
        return self.rule if isinstance(self.rule, tuple) else (self.rule,)

    def _rng(self) -> np.random.Generator:
        return np.random.default_rng([self.seed, self.told, 0x5EED])

    def ask(self) -> np.ndarray:
        rng = self._rng()
        if self.told == 0 or not self.observations:
            size = self.population if self.told == 0 else self.offspring
            return qmc.LatinHypercube(d=self.n_genes, seed=rng).random(size)
        with one_blas_thread():
            return self.propose(self.offspring, rng)

    def tell(
        self,
        genes: np.ndarray,
        objectives: np.ndarray,
        constraints: np.ndarray | None = None,
        observations: Sequence[Observation] | None = None,
    ) -> None:
        """Record a batch. ``objectives`` and ``constraints`` are what the GA ranks on; the
        models need what they summarise, so ``observations`` (N_t of every run, failure) are
        required."""
        genes = self._checked(genes, observations)
        self.genes.extend(genes.tolist())
        self.observations.extend(observations)
        self.told += 1

    def revise(
        self,
        genes: np.ndarray,
        objectives: np.ndarray,
        constraints: np.ndarray | None = None,
        observations: Sequence[Observation] | None = None,
    ) -> None:
        """Sets simulated earlier got more replicates: their observations replace the old ones."""
        genes = self._checked(genes, observations)
        known = np.array(self.genes)
        for gene, observation in zip(genes, observations, strict=True):
            for index in np.flatnonzero(np.all(np.abs(known - gene) <= 1e-12, axis=1)):
                self.observations[index] = observation

    @staticmethod
    def _checked(genes: np.ndarray, observations) -> np.ndarray:
        if observations is None:
            raise ValueError("the surrogate search needs the observations of each set, not only F")
        genes = np.asarray(genes, dtype=float)
        if len(genes) != len(observations):
            raise ValueError(f"{len(genes)} gene rows but {len(observations)} observations")
        return genes

    # -- the model ------------------------------------------------------------------------------

    def models(self, random_state: int | None = None) -> Models:
        """The fitted models, one per experiment; the cost model only once a set matched (before,
        cost is not asked)."""
        state = int(self._rng().integers(2**31 - 1)) if random_state is None else random_state
        genes, with_cost = np.array(self.genes), bool(self.matched())
        return Models(
            [
                fit_models(
                    genes, self.observations, state, with_cost and k == 0, rule, with_feasibility=k == 0
                )
                for k, rule in enumerate(self.rules)
            ]
        )

    def matched(self) -> list[int]:
        """Indices of observed sets whose replicates match every experiment within its tolerance."""
        return [
            index
            for index, observation in enumerate(self.observations)
            if observation.ok
            and observation.n_remaining
            and all(_distance(observation.values(rule), rule) <= rule.tolerance + 1e-9 for rule in self.rules)
        ]

    def acquisition(self, model: Models, candidates: np.ndarray) -> np.ndarray:
        """Constrained EI: P(match) on the sets the feasibility model calls valid (P(ok) >= 1/2),
        times the EI of log cost below the cheapest set the models believe matches, once one
        does. The threshold, not P(ok) as a factor: the cheap corner is where runs turn invalid
        (soft E), and a soft factor lets the cost's EI pull the batch across the boundary."""
        p_ok = model.p_ok(candidates)
        value = np.where(p_ok >= 0.5, p_ok, 0.0) * model.p_match(candidates, self.rules)
        believed = self.believed_matches(model)
        if believed and model.cost is not None:
            best = min(np.log(self.observations[i].cost) for i in believed)
            mean, sd = model.log_cost(candidates)
            value = value * expected_improvement(mean, sd, best)
        return value

    def believed_matches(self, model: Models) -> list[int]:
        """Observed sets that matched and that the models, which pool their neighbours' runs,
        also give P(match) >= 1/2: one lucky seed does not start the hunt for cheaper sets."""
        matched = self.matched()
        if not matched:
            return []
        belief = model.p_match(np.array([self.genes[i] for i in matched]), self.rules)
        return [index for index, p in zip(matched, belief, strict=True) if p >= 0.5]

    def candidates(self, rng: np.random.Generator) -> np.ndarray:
        sobol = qmc.Sobol(d=self.n_genes, scramble=True, seed=rng).random(N_CANDIDATES)
        observed = np.array(self.genes)
        ok = [i for i, observation in enumerate(self.observations) if observation.ok]
        if not ok:
            return sobol
        # Local moves around the sets nearest the target (or matching), where the band lies.
        closeness = []
        for i in ok:
            observation = self.observations[i]
            closeness.append(
                max(
                    abs(float(np.median(observation.values(rule))) - rule.target) / max(rule.tolerance, 1e-12)
                    for rule in self.rules
                )
                if observation.n_remaining
                else np.inf
            )
        best = [ok[j] for j in np.argsort(closeness, kind="stable")[:8]]
        centres = observed[rng.choice(best, N_LOCAL)]
        local = np.clip(centres + rng.normal(0.0, 0.08, centres.shape), 0.0, 1.0)
        return np.vstack([sobol, local])

    def propose(self, size: int, rng: np.random.Generator) -> np.ndarray:
        model = self.models(int(rng.integers(2**31 - 1)))
        candidates = self.candidates(rng)
        score = self.acquisition(model, candidates)
        scales = length_scales(model.size) if model.size is not None else np.full(self.n_genes, 0.3)
        chosen: list[int] = []
        # A set already simulated is not proposed again (its neighbourhood may be: noise).
        observed = np.array(self.genes)
        nearest = np.min(np.abs(candidates[:, None, :] - observed[None, :, :]).max(axis=2), axis=1)
        damping = (nearest > 1e-3).astype(float)
        # Where the models cannot tell candidates apart (nothing clogged yet, say), fill the box:
        # the acquisition is then the distance to the nearest set simulated or picked.
        flat = np.ptp(score) <= 1e-9 * max(float(np.max(score)), 1e-300)
        spacing = np.sqrt((((candidates[:, None, :] - observed[None, :, :]) / scales) ** 2).sum(axis=2)).min(
            axis=1
        )
        valid = model.p_ok(candidates)
        for _ in range(size):
            adjusted = (spacing * (valid >= 0.5) if flat else score) * damping
            if not np.any(adjusted > 0):
                adjusted = spacing * valid * damping
            pick = int(np.argmax(adjusted))
            chosen.append(pick)
            damping *= 1.0 - _correlation(candidates, candidates[pick], scales)
            damping[pick] = 0.0
            spacing = np.minimum(
                spacing, np.sqrt((((candidates - candidates[pick]) / scales) ** 2).sum(axis=1))
            )
        return candidates[chosen]


def _distance(values: Sequence[float], rule: MatchRule) -> float:
    """One experiment's f1 of observed replicate values (``objectives.experiment_distance``)."""
    from optimizer.study import aggregate

    if rule.distance == "wasserstein":
        from scipy.stats import wasserstein_distance

        return float(wasserstein_distance(list(values), list(rule.measured)))
    return abs(aggregate(list(values), rule.aggregate) - rule.target)


def _correlation(points: np.ndarray, centre: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Matern 5/2 correlation between each point and ``centre`` with ARD length scales."""
    r = np.sqrt((((points - centre) / scales) ** 2).sum(axis=1)) * np.sqrt(5.0)
    return (1.0 + r + r**2 / 3.0) * np.exp(-r)
