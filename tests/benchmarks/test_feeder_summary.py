"""The feeder benchmark's verdict figures: the ratio's bootstrap interval resamples seeds in pairs."""

from __future__ import annotations

import numpy as np

from benchmarks.feeder import ratio_interval


def test_a_ratio_that_is_the_same_on_every_seed_has_no_spread_when_seeds_are_paired():
    # Arrange: each seed's pile path moves both representations alike (a jam doubles both).
    clumps = [10.0, 40.0, 12.0, 35.0, 11.0, 38.0]
    polyhedra = [2.0 * c for c in clumps]

    # Act
    low, high = ratio_interval(polyhedra, clumps)

    # Assert: resampled apart, the jams would spread the ratio over 1.3x-3x
    assert abs(low - 2.0) < 1e-12 and abs(high - 2.0) < 1e-12


def test_the_interval_holds_the_ratio_of_the_means_and_widens_with_the_seeds_spread():
    rng = np.random.default_rng(3)
    clumps = list(rng.uniform(15.0, 20.0, size=10))
    steady = [1.8 * c * f for c, f in zip(clumps, rng.uniform(0.98, 1.02, size=10), strict=True)]
    jams = [c * (4.0 if k % 3 == 0 else 1.2) for k, c in enumerate(clumps)]

    narrow, wide = ratio_interval(steady, clumps), ratio_interval(jams, clumps)

    ratio = np.mean(jams) / np.mean(clumps)
    assert wide[0] < ratio < wide[1]
    assert wide[1] - wide[0] > 10 * (narrow[1] - narrow[0])
