"""The statistics of ``optimizer/noise.py`` against their textbook formulas."""

from __future__ import annotations

import numpy as np

from optimizer.noise import anderson_darling_pairs


def _scholz_stephens(first, second) -> float:
    """A2kN of Scholz and Stephens (1987, eq. 3) for k = 2 samples without ties:
    (1/N) sum_i (1/n_i) sum_{j<N} (N M_ij - j n_i)^2 / (j (N - j)), M_ij the number of sample
    i's values among the j smallest pooled ones."""
    pooled = np.sort(np.concatenate([first, second]))
    big_n = len(pooled)
    j = np.arange(1, big_n)
    total = 0.0
    for sample in (first, second):
        below = np.array([(sample <= pooled[k - 1]).sum() for k in j])
        total += ((big_n * below - j * len(sample)) ** 2 / (j * (big_n - j))).sum() / len(sample)
    return total / big_n


def test_anderson_darling_equals_the_scholz_stephens_two_sample_statistic():
    rng = np.random.default_rng(4)
    first, second = rng.normal(size=(6, 10)), rng.normal(0.7, 1.3, size=(6, 13))

    ours = anderson_darling_pairs(first, second)

    expected = [_scholz_stephens(a, b) for a, b in zip(first, second, strict=True)]
    np.testing.assert_allclose(ours, expected, rtol=1e-12)


def test_anderson_darling_of_identical_samples_is_zero_and_grows_with_the_shift():
    sample = np.arange(10.0)
    shifts = anderson_darling_pairs(np.tile(sample, (4, 1)), sample[None, :] + np.arange(4.0)[:, None])

    assert shifts[0] == 0.0
    assert np.all(np.diff(shifts) > 0)
