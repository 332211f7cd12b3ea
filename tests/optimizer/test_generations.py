"""The per-generation summary (``optimizer/generations.py``): the Wasserstein-1 distance of a
generation's measured runs to the experiment, with failed runs left out."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import wasserstein_distance

from optimizer.generations import Run, experiment_band, per_generation

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


@pytest.mark.parametrize("n", [1, 10, 15, 50])
def test_the_experiments_own_band_is_the_bootstrap_of_its_median_and_w1(n):
    """The band against a plain bootstrap of the ten values with scipy's W1: same percentiles
    within the resampling error (4000 draws each)."""
    rng = np.random.default_rng(5)
    draws = rng.choice(MEASURED, size=(4000, n))
    w1 = [wasserstein_distance(draw, MEASURED) for draw in draws]

    band = experiment_band(MEASURED, n)

    assert band["w1_95"] == pytest.approx(np.percentile(w1, 95), rel=0.06)
    assert band["median_5"] == pytest.approx(np.percentile(np.median(draws, axis=1), 5), abs=1.0)
    assert band["median_5"] <= 4 <= band["median_95"]  # the experiment's own median lies inside
    assert experiment_band(list(reversed(MEASURED)), n) == band  # the same band in every view


def test_the_band_narrows_with_more_runs_and_each_generation_carries_its_own():
    runs = [Run(0, "ok", {"n_remaining": v}) for v in [0, 4, 12] * 5] + [Run(1, "ok", {"n_remaining": 4})] * 3

    summary = per_generation(runs, {"n_remaining": MEASURED})

    for entry, n in zip(summary, [15, 3], strict=True):
        band = entry["as_experiment"]["n_remaining"]
        assert {key: band[key] for key in ("median_5", "median_95", "w1_95")} == experiment_band(MEASURED, n)
    assert experiment_band(MEASURED, 50)["w1_95"] < experiment_band(MEASURED, 15)["w1_95"] < experiment_band(
        MEASURED, 3
    )["w1_95"]
    # A generation of 15 runs that all measured 4 is no draw from the experiment: W1 beyond the band.
    alike = per_generation([Run(0, "ok", {"n_remaining": 4})] * 15, {"n_remaining": MEASURED})[0]
    assert alike["w1_to_experiment"]["n_remaining"] > alike["as_experiment"]["n_remaining"]["w1_95"]
    assert alike["as_experiment"]["n_remaining"]["alike"] is False


def test_a_generation_is_alike_when_its_w1_is_inside_the_experiments_band():
    """``alike`` is the one home of the rule the CLI's star, pareto.png's bold and the dashboard read."""
    like = [Run(0, "ok", {"n_remaining": v}) for v in MEASURED + MEASURED[:5]]
    emptied = [Run(1, "ok", {"n_remaining": 0})] * 15

    summary = per_generation(like + emptied, {"n_remaining": MEASURED})

    assert [entry["as_experiment"]["n_remaining"]["alike"] for entry in summary] == [True, False]
    band = summary[0]["as_experiment"]["n_remaining"]
    assert summary[0]["w1_to_experiment"]["n_remaining"] <= band["w1_95"]


def test_the_whole_protocols_t_and_cost_are_spread_over_the_runs_that_measured():
    """What f2 ranks, per generation (Fig. 5's T panel): a run that emptied the tray halfway is
    priced at twice its own T and cost; a failed run is left out."""
    from dem.result import SimulationResult, SimulationStatus
    from optimizer.protocols import TrialRecord, TrialSpec, TrialState

    def run(factor, wall, status=SimulationStatus.OK):
        spec = TrialSpec("t", "s", 0, 0, 0, 1, {}, {})
        times = {"wall_time_s": wall, "cost": 10 * wall, "full_load_factor": factor}
        result = SimulationResult(status=status, n_items=30, n_remaining=0, **times)
        return Run.of(TrialRecord(spec, TrialState.DONE, result))

    runs = [run(1.0, 4.0), run(2.0, 3.0), run(1.0, 8.0), run(1.0, 1.0, SimulationStatus.UNSTABLE)]

    [summary] = per_generation(runs)

    assert summary["wall_time_s"]["median"] == 4.0  # the runs' own: 3, 4, 8
    assert summary["protocol_wall_time_s"]["median"] == 6.0  # the protocol's: 4, 6, 8
    assert summary["protocol_cost"]["median"] == 60.0
    assert (summary["protocol_wall_time_s"]["min"], summary["protocol_wall_time_s"]["max"]) == (4.0, 8.0)
