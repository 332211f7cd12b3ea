"""Noise-aware statistics of N_t: the Wasserstein-1 distance of many samples at once, and
bootstrap intervals. The feeder's N_t at one parameter set spreads widely across seeds (0-19 on
the full feeder at one set), so a single number is mostly noise; these put an interval on it.

N_t and the measured values are small counts, so W1 is computed on the CDFs over the union of the
values, vectorised over rows (scipy's ``wasserstein_distance`` takes one pair at a time, far too
slow for thousands of bootstrap resamples on every evaluation). Resamples come from a generator
seeded by the caller, so every figure is reproducible.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

BOOTSTRAP_RESAMPLES = 1000
INTERVAL = 0.9  # two-sided coverage of the bootstrap intervals


def wasserstein_many(samples: np.ndarray, reference: Sequence[float]) -> np.ndarray:
    """W1 between each row of ``samples`` (n x k) and ``reference``, as a length-n array."""
    samples = np.atleast_2d(np.asarray(samples, dtype=float))
    reference = np.asarray(reference, dtype=float)
    support = np.union1d(np.unique(samples), reference)
    if len(support) < 2:
        return np.zeros(len(samples))
    widths = np.diff(support)
    points = support[:-1]
    cdf_samples = (samples[:, :, None] <= points[None, None, :]).mean(axis=1)
    cdf_reference = (reference[:, None] <= points[None, :]).mean(axis=0)
    return np.abs(cdf_samples - cdf_reference[None, :]) @ widths


def wasserstein_floor(measured: Sequence[float], replicates: int, quantile: float) -> float:
    """The W1 a perfect model would show with ``replicates`` runs: the ``quantile`` of the W1
    between that many values drawn from the measured ones and the measured ones (a deterministic
    bootstrap of 4000 draws)."""
    rng = np.random.default_rng(0)
    draws = rng.choice(np.asarray(measured, dtype=float), size=(4000, replicates))
    return float(np.quantile(wasserstein_many(draws, measured), quantile))


def wasserstein_pairs(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """W1 between row i of ``first`` (r x n) and row i of ``second`` (r x m), as a length-r array."""
    first, second = np.atleast_2d(first).astype(float), np.atleast_2d(second).astype(float)
    support = np.union1d(np.unique(first), np.unique(second))
    if len(support) < 2:
        return np.zeros(len(first))
    points = support[:-1]
    cdf_first = (first[:, :, None] <= points[None, None, :]).mean(axis=1)
    cdf_second = (second[:, :, None] <= points[None, None, :]).mean(axis=1)
    return np.abs(cdf_first - cdf_second) @ np.diff(support)


def anderson_darling_pairs(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The two-sample Anderson-Darling statistic between row i of ``first`` (r x n) and row i of
    ``second`` (r x m), as a length-r array: (n m / N) sum_j (F_j - G_j)^2 / (H_j (1 - H_j)) h_j
    over the pooled distinct values z_j (F, G the rows' CDFs at z_j, H the pooled CDF, h_j the
    pooled share at z_j, the last value left out as H = 1 there; Pettitt 1976, in the discrete
    form of Scholz and Stephens 1987 without midranks). Why beside W1: it weighs the CDFs' gap by
    1 / (H (1 - H)), so a difference in the tails (how large the jams are, how often the tray
    empties) counts more than W1 gives it, which is where a feeder set that clogs too hard
    differs from the experiment. Compared with W1 as the validation's statistic in
    ``benchmarks/validation_power.py``; the validation keeps W1 (``optimizer/validation.py``)."""
    first, second = np.atleast_2d(first).astype(float), np.atleast_2d(second).astype(float)
    n, m = first.shape[1], second.shape[1]
    pooled = np.concatenate([first, second], axis=1)
    support = np.unique(pooled)
    if len(support) < 2:
        return np.zeros(len(first))
    points = support[:-1]
    cdf_first = (first[:, :, None] <= points[None, None, :]).mean(axis=1)
    cdf_second = (second[:, :, None] <= points[None, None, :]).mean(axis=1)
    cdf_pooled = (pooled[:, :, None] <= points[None, None, :]).mean(axis=1)
    share = np.diff(cdf_pooled, axis=1, prepend=0.0)
    inside = (cdf_pooled > 0.0) & (cdf_pooled < 1.0)
    weight = np.where(inside, share / np.where(inside, cdf_pooled * (1.0 - cdf_pooled), 1.0), 0.0)
    return n * m / (n + m) * ((cdf_first - cdf_second) ** 2 * weight).sum(axis=1)


def permutation_quantile(
    sample: Sequence[float],
    reference: Sequence[float],
    statistic: Callable[[np.ndarray, np.ndarray], np.ndarray],
    quantile: float,
    seed: int = 0,
    resamples: int = BOOTSTRAP_RESAMPLES,
) -> float:
    """The ``quantile`` of ``statistic`` (row-wise, of an r x n and an r x m array) over random
    splits of the pooled values into groups of the sizes of ``sample`` and ``reference``: what
    the statistic does when both are draws of one distribution (a permutation test)."""
    pool = np.concatenate([np.asarray(sample, dtype=float), np.asarray(reference, dtype=float)])
    rng = np.random.default_rng(seed)
    shuffled = pool[np.argsort(rng.random((resamples, len(pool))), axis=1)]
    stats = statistic(shuffled[:, : len(sample)], shuffled[:, len(sample) :])
    return float(np.quantile(stats, quantile))


def median_many(samples: np.ndarray) -> np.ndarray:
    return np.median(np.atleast_2d(np.asarray(samples, dtype=float)), axis=1)


def bootstrap_interval(
    values: Sequence[float],
    statistic: Callable[[np.ndarray], np.ndarray],
    seed: int = 0,
    resamples: int = BOOTSTRAP_RESAMPLES,
    coverage: float = INTERVAL,
) -> tuple[float, float]:
    """Percentile bootstrap interval of ``statistic`` (a function of a resamples x n array that
    returns one value per row) over ``values``; a single value gives a zero-width interval."""
    values = np.asarray(values, dtype=float)
    if len(values) == 0:
        raise ValueError("no values to bootstrap")
    if len(values) == 1:
        # Every resample is the value itself: the same interval, without 1,000 resamples (a
        # study of single-replicate trials evaluates thousands of these: benchmarks/README.md).
        stat = float(statistic(values[None, :])[0])
        return stat, stat
    rng = np.random.default_rng(seed)
    draws = values[rng.integers(0, len(values), size=(resamples, len(values)))]
    stats = statistic(draws)
    tail = (1.0 - coverage) / 2.0
    return float(np.quantile(stats, tail)), float(np.quantile(stats, 1.0 - tail))
