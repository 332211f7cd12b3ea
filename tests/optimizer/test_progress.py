"""Progress against simulations: the hypervolume (checked against rectangles computed by hand)
and the best f1, one point per batch of a study run by the real driver."""

from __future__ import annotations

import pytest

import optimizer.progress
from optimizer.driver import Driver
from optimizer.memory import MemoryStore, SyntheticExecutor, synthetic_with_failures
from optimizer.objectives import Evaluation
from optimizer.progress import ProgressTracker, hypervolume, reference_point, study_progress
from tests.optimizer.conftest import make_definition


def individual(f1: float, f2: float, failure: str = "") -> Evaluation:
    return Evaluation(0, 0, {}, f1, f2, [], 0.0, f2, failure=failure)


def test_hypervolume_of_one_point_is_its_dominated_rectangle():
    reference = (30.0, 200.0)

    value = hypervolume([individual(6.0, 50.0)], reference)

    assert value == pytest.approx((1 - 6 / 30) * (1 - 50 / 200))


def test_hypervolume_of_two_points_counts_their_overlap_once():
    reference = (10.0, 10.0)
    a, b = individual(2.0, 6.0), individual(5.0, 1.0)

    value = hypervolume([a, b], reference)

    # Union of [2, 10] x [6, 10] and [5, 10] x [1, 10], over the 10 x 10 box.
    assert value == pytest.approx((8 * 4 + 5 * 9 - 5 * 4) / 100)


def test_failed_and_out_of_box_individuals_add_no_hypervolume():
    reference = (10.0, 10.0)

    value = hypervolume([individual(0.0, 0.0, failure="unstable: boom"), individual(3.0, 12.0)], reference)

    assert value == 0.0


def test_reference_point_is_the_item_count_and_the_initial_populations_worst_cost_with_margin():
    initial = [individual(1.0, 40.0), individual(2.0, 90.0), individual(30.0, 500.0, failure="error: x")]

    assert reference_point(initial, 30) == (30.0, pytest.approx(99.0))


def test_progress_has_a_point_per_batch_with_growing_hypervolume_and_falling_best_f1(small_definition):
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    records = store.trials(study_id)

    progress = study_progress(records, small_definition, store.load_study(study_id).generation)
    running = study_progress(records, small_definition, 2)  # as seen while batch 2 still ran

    points = progress.points
    assert [p.batch for p in points] == [0, 1, 2, 3]
    assert [p.simulations for p in points] == [8, 12, 16, 20]
    assert points[-1].failed == sum(not r.result.ok for r in records)
    hv = [p.hypervolume for p in points]
    assert all(0 < v < 1 for v in hv) and hv == sorted(hv)
    best = [p.best_f1 for p in points]
    assert best == sorted(best, reverse=True)
    assert all(p.best_validated_f1 is None for p in points)  # nothing validated without a validation
    assert progress.reference[0] == 30
    assert running.points == points[:2]


def test_best_validated_f1_is_the_lowest_fresh_f1_of_a_validated_set_at_the_last_batch(small_definition):
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    validation = [
        {"individual": 3, "f1": 0.4, "verdict": "validated"},
        {"individual": 5, "f1": 0.1, "verdict": "not reproduced"},
        {"individual": 9, "f1": 0.2, "verdict": "validated"},
    ]

    points = study_progress(store.trials(study_id), small_definition, 4, validation).points

    assert [p.best_validated_f1 for p in points] == [None, None, None, 0.2]


def test_progress_evaluates_each_record_about_once_however_many_batches(monkeypatch):
    definition = make_definition(
        ga={"population": 8, "offspring": 4, "generations": 12}, validation={"seeds": 0}
    )
    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    records = store.trials(study_id)
    evaluated = []
    real = optimizer.progress.evaluate

    def counted(group, *args, **options):
        evaluated.append(len(group))
        return real(group, *args, **options)

    monkeypatch.setattr(optimizer.progress, "evaluate", counted)

    points = study_progress(records, definition, 13).points

    assert len(points) == 13
    # Re-evaluating every earlier batch for each point would be sum(8 + 4 b) = 416 records here.
    assert sum(evaluated) <= 2 * len(records) == 2 * 56


def test_a_tracker_fed_batch_by_batch_gives_the_points_of_one_pass(small_definition):
    store = MemoryStore()
    study_id = store.create_study(small_definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)
    records = store.trials(study_id)
    tracker = ProgressTracker(small_definition)

    for completed in (1, 1, 3, 4):  # as a server folds what completed since its previous read
        tracker.advance([r for r in records if r.spec.generation >= tracker.next_batch], completed)

    assert tracker.progress() == study_progress(records, small_definition, 4)
