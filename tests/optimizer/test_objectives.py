"""f1 and f2 from results, and the worst-case objectives of failed simulations."""

from __future__ import annotations

import pytest
from scipy.stats import wasserstein_distance

from dem.result import SimulationResult, SimulationStatus
from optimizer.objectives import evaluate
from optimizer.protocols import TrialRecord, TrialSpec, TrialState
from tests.optimizer.conftest import PAPER_MEASURED, make_definition

PARAMS = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}


def record(
    individual, replicate, status="ok", n_remaining=4, wall=10.0, cost=1e6, message="", overlap=None,
    factor=1.0,
):
    spec = TrialSpec(f"s-{individual}-{replicate}", "s", individual, 0, replicate, replicate, PARAMS, {})
    result = SimulationResult(
        status=SimulationStatus(status),
        message=message,
        max_overlap=overlap,
        n_items=30,
        n_remaining=n_remaining if status == "ok" else None,
        wall_time_s=wall,
        cost=cost,
        full_load_factor=factor,
    )
    return TrialRecord(spec, TrialState.DONE, result)


def test_f1_is_the_distance_of_the_replicates_median_to_the_target():
    experiment = {"measured": PAPER_MEASURED, "distance": "aggregate"}
    definition = make_definition(replicates=3, experiment=experiment)
    records = [record(0, 0, n_remaining=2), record(0, 1, n_remaining=9), record(0, 2, n_remaining=7)]

    [evaluation] = evaluate(records, definition, n_items=30)

    assert evaluation.f1 == abs(7 - 4)
    assert evaluation.n_remaining == [2, 9, 7]


def test_f2_is_the_mean_cost_or_the_mean_wall_time():
    records = [record(0, 0, wall=10.0, cost=100.0), record(0, 1, wall=20.0, cost=300.0)]

    [by_cost] = evaluate(records, make_definition(replicates=2, objective_time="cost"), 30)
    [by_wall] = evaluate(records, make_definition(replicates=2, objective_time="wall"), 30)

    assert by_cost.f2 == 200.0
    assert by_wall.f2 == 15.0


def test_f2_prices_the_whole_protocol_of_a_run_that_stopped_early():
    # A run whose tray emptied did half the protocol's item-seconds: its f2 is what the whole
    # protocol would cost, so emptying the tray is not rewarded as speed.
    records = [record(0, 0, wall=10.0, cost=100.0, factor=2.0), record(0, 1, wall=20.0, cost=300.0)]

    [by_cost] = evaluate(records, make_definition(replicates=2, objective_time="cost"), 30)
    [by_wall] = evaluate(records, make_definition(replicates=2, objective_time="wall"), 30)

    assert by_cost.f2 == by_cost.cost == (200.0 + 300.0) / 2
    assert by_wall.f2 == by_wall.wall_time_s == (20.0 + 20.0) / 2


def test_wasserstein_distance_of_one_replicate_is_its_mean_absolute_difference():
    definition = make_definition(experiment={"measured": PAPER_MEASURED, "distance": "wasserstein"})

    [evaluation] = evaluate([record(0, 0, n_remaining=5)], definition, 30)

    assert evaluation.f1 == pytest.approx(sum(abs(5 - m) for m in PAPER_MEASURED) / len(PAPER_MEASURED))


@pytest.mark.parametrize("status", ["invalid", "unstable", "timeout", "error", "cancelled"])
def test_failed_trial_gets_worst_case_objectives_and_keeps_its_reason(status):
    definition = make_definition()
    records = [
        record(0, 0, cost=5e6),
        record(1, 0, cost=9e6),
        record(2, 0, status=status, cost=1e3, message="velocity 1e4 m/s"),
    ]

    evaluations = evaluate(records, definition, n_items=30)

    failed = evaluations[2]
    assert (failed.f1, failed.f2) == (30.0, 9e6)
    assert failed.failure == f"{status}: velocity 1e4 m/s"
    assert not failed.matches(definition.experiment.tolerance)


def test_one_failed_replicate_fails_the_individual():
    definition = make_definition(replicates=2)

    [evaluation] = evaluate([record(0, 0), record(0, 1, status="unstable")], definition, 30)

    assert evaluation.f1 == 30.0
    assert evaluation.failure.startswith("unstable")


def test_individual_with_a_missing_replicate_is_not_evaluated_yet():
    definition = make_definition(replicates=2)
    waiting = TrialRecord(TrialSpec("s-0-1", "s", 0, 0, 1, 1, PARAMS, {}), TrialState.QUEUED)

    assert evaluate([record(0, 0), waiting], definition, 30) == []


def test_three_replicates_default_to_wasserstein_with_the_experiments_noise_floor():
    definition = make_definition(replicates=3)
    counts = [2, 9, 7]

    [evaluation] = evaluate([record(0, r, n_remaining=n) for r, n in enumerate(counts)], definition, 30)

    assert definition.experiment.distance == "wasserstein"
    assert evaluation.f1 == pytest.approx(wasserstein_distance(counts, PAPER_MEASURED))
    # The tolerance is what the experiment itself scores against itself with 3 draws, 90 % of the time.
    assert definition.experiment.tolerance == definition.experiment.noise_floor(3) > 0
    low, high = evaluation.f1_interval
    assert low <= evaluation.f1 <= high and low < high


def test_invalid_and_failed_sets_violate_the_constraints_more_than_any_measured_set():
    definition = make_definition()
    records = [
        record(0, 0, n_remaining=30),  # the worst possible measurement
        record(1, 0, n_remaining=4),  # a match
        record(2, 0, status="invalid", overlap=0.6),
        record(3, 0, status="invalid", overlap=2.0),
        record(4, 0, status="unstable"),
    ]

    worst, match, shallow, deep, unstable = evaluate(records, definition, n_items=30)

    assert match.violation == 0 and match.g_match <= 0
    assert 0 < worst.violation < shallow.violation < deep.violation
    assert shallow.g_validity == 1.2 and deep.g_validity == 4.0 and unstable.g_validity == 1.0
    assert (shallow.status, unstable.status) == ("invalid", "unstable")
