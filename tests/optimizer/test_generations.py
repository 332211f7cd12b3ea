"""The per-generation summary (``optimizer/generations.py``): the Wasserstein-1 distance of a
generation's measured runs to the experiment, with failed runs left out."""

from __future__ import annotations

import pytest

from optimizer.generations import Run, per_generation

MEASURED = [0, 0, 1, 2, 3, 4, 4, 12, 15, 16]


def test_distance_to_the_experiment_uses_only_the_runs_that_measured():
    runs = [
        Run(0, "ok", {"n_remaining": 0}),
        Run(0, "ok", {"n_remaining": 4}),
        Run(0, "invalid", {"n_remaining": 30}),  # where it stopped, never a measurement
        Run(1, "ok", {"n_remaining": 16}),
        Run(2, "unstable", {"n_remaining": 30}),
        Run(2, None),
    ]

    summary = per_generation(runs, {"n_remaining": MEASURED})

    # W1 of {0, 4} to the ten values: half the runs' mass at 0, half at 4, against the
    # experiment's distribution function; by hand: mean |quantile difference| over [0, 1].
    by_hand = sum(abs((0 if q < 0.5 else 4) - sorted(MEASURED)[q_i]) for q_i, q in
                  enumerate([(i + 0.5) / 10 for i in range(10)])) / 10
    assert summary[0]["w1_to_experiment"]["n_remaining"] == pytest.approx(by_hand)
    assert summary[1]["w1_to_experiment"]["n_remaining"] == pytest.approx(16 - sum(MEASURED) / 10)
    assert summary[2]["w1_to_experiment"] == {"n_remaining": None}


def test_without_an_experiment_no_distance_is_given():
    assert per_generation([Run(0, "ok", {"n_remaining": 3})])[0]["w1_to_experiment"] == {}
