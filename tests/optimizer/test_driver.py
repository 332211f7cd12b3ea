"""The driver on the in-memory store and the synthetic executor: the paper's protocol count,
resume after a kill, duplicates, failures, pause, re-evaluation of matching sets."""

from __future__ import annotations

from collections import Counter

import pytest

from dem.result import SimulationResult, SimulationStatus
from optimizer.driver import Driver
from optimizer.memory import MemoryStore, SyntheticExecutor, synthetic_result
from optimizer.protocols import StudyStatus, TrialState
from tests.optimizer.conftest import make_definition


def start(store, definition):
    return store.create_study(definition.model_dump(mode="json"), None)


def results_per_trial(store, study_id):
    return Counter(record.spec.trial_id for record in store.trials(study_id) if record.result is not None)


def test_papers_protocol_runs_exactly_185_simulations(paper_definition):
    store, executor = MemoryStore(), SyntheticExecutor()
    study_id = start(store, paper_definition)

    progress = Driver(store, executor).run_to_completion(study_id, poll_timeout=0)

    trials = store.trials(study_id)
    assert progress.status is StudyStatus.DONE
    assert len(executor.submitted) == len(trials) == 185
    assert Counter(record.spec.generation for record in trials) == {0: 50, **{g: 15 for g in range(1, 10)}}
    assert store.load_study(study_id).generation == 10
    assert progress.trials_done == progress.trials_planned == 185


@pytest.fixture(params=["memory", "sqlite"])
def any_store(request, tmp_path):
    """The in-memory store, and the SQL store the CLI and the service use, on a SQLite file."""
    if request.param == "memory":
        return MemoryStore()
    from api.db import create_db_engine, upgrade_database
    from api.store import SqlStore

    url = f"sqlite:///{tmp_path}/store.db"
    upgrade_database(url)
    return SqlStore(create_db_engine(url))


def test_resume_after_kill_mid_generation_reruns_nothing_finished(small_definition, any_store):
    simulated = Counter()

    def respond(spec):
        simulated[spec.trial_id] += 1
        return synthetic_result(spec)

    store = any_store
    study_id = start(store, small_definition)
    first = Driver(store, SyntheticExecutor(respond, per_poll=3))
    while store.load_study(study_id).generation < 2:
        first.step(study_id, timeout=0)
    first.step(study_id, timeout=0)  # batch 2 submitted, 3 of its 4 trials finished
    assert Counter(r.state for r in store.trials(study_id) if r.spec.generation == 2)[TrialState.QUEUED] == 1
    # Kill: the driver and its executor vanish with one trial in flight.

    progress = Driver(store, SyntheticExecutor(respond, per_poll=3)).run_to_completion(
        study_id, poll_timeout=0
    )

    reference_store = MemoryStore()
    reference_id = start(reference_store, small_definition)
    reference = Driver(reference_store, SyntheticExecutor()).run_to_completion(reference_id, poll_timeout=0)
    assert progress.status is StudyStatus.DONE
    assert sum(simulated.values()) == len(simulated) == 8 + 3 * 4
    assert set(results_per_trial(store, study_id).values()) == {1}
    assert progress.recommendation["params"] == reference.recommendation["params"]


class DuplicatingExecutor(SyntheticExecutor):
    """Reports every outcome twice, like a worker presumed dead that was only slow."""

    def poll(self, timeout=0.0):
        outcomes = super().poll(timeout)
        return outcomes + outcomes


def test_duplicate_results_are_recorded_once(small_definition):
    store = MemoryStore()
    study_id = start(store, small_definition)

    progress = Driver(store, DuplicatingExecutor()).run_to_completion(study_id, poll_timeout=0)

    assert progress.status is StudyStatus.DONE
    assert sum(results_per_trial(store, study_id).values()) == 20
    assert progress.trials_done == 20


def test_failed_simulations_are_penalised_and_the_study_goes_on(paper_definition):
    def respond(spec):
        if spec.params["E"] > 1e8:
            return SimulationResult(status=SimulationStatus.UNSTABLE, message="overlap > 50 %", n_items=30)
        return synthetic_result(spec)

    store = MemoryStore()
    study_id = start(store, paper_definition)

    progress = Driver(store, SyntheticExecutor(respond)).run_to_completion(study_id, poll_timeout=0)

    assert progress.status is StudyStatus.DONE
    assert progress.trials_done == 185
    assert any(r.result.status is SimulationStatus.UNSTABLE for r in store.trials(study_id))
    assert progress.recommendation["params"]["E"] <= 1e8


def test_pause_withdraws_work_and_resume_finishes_the_same_budget(small_definition):
    store, executor = MemoryStore(), SyntheticExecutor(per_poll=2)
    study_id = start(store, small_definition)
    driver = Driver(store, executor, reconcile_every_s=0)
    driver.step(study_id, timeout=0)
    store.set_status(study_id, StudyStatus.PAUSED)

    paused = driver.step(study_id, timeout=0)
    store.set_status(study_id, StudyStatus.RUNNING)
    done = driver.run_to_completion(study_id, poll_timeout=0)

    assert paused.status is StudyStatus.PAUSED
    assert len(executor.cancelled) == 8 - 2
    assert executor.in_flight() == set()
    assert done.status is StudyStatus.DONE
    assert sum(results_per_trial(store, study_id).values()) == 20


def test_elite_reevaluation_adds_fresh_seeds_to_every_matching_set(small_definition):
    definition = make_definition(ga={"population": 8, "offspring": 4, "generations": 3}, elite_reevaluation=2)
    store = MemoryStore()
    study_id = start(store, definition)

    progress = Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    extra = [r for r in store.trials(study_id) if r.spec.generation == 4]
    assert progress.status is StudyStatus.DONE
    assert extra and {r.spec.replicate for r in extra} == {1, 2}
    assert len(set(r.spec.seed for r in store.trials(study_id))) == len(store.trials(study_id))
    assert len(progress.recommendation["n_remaining"]) == 3


def test_step_is_bounded_and_reports_progress(small_definition):
    store = MemoryStore()
    study_id = start(store, small_definition)
    driver = Driver(store, SyntheticExecutor(per_poll=1))

    progress = driver.step(study_id, timeout=0)

    assert progress.status is StudyStatus.RUNNING
    assert (progress.batch, progress.batches) == (0, 4)
    assert (progress.trials_done, progress.trials_in_flight, progress.trials_planned) == (1, 7, 20)


@pytest.mark.parametrize("algorithm", ["random", "spea2"])
def test_other_algorithms_run_the_same_budget(algorithm):
    definition = make_definition(
        ga={"algorithm": algorithm, "population": 8, "offspring": 4, "generations": 3}
    )
    store = MemoryStore()
    study_id = start(store, definition)

    progress = Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    assert progress.status is StudyStatus.DONE
    assert len(store.trials(study_id)) == 20


def test_study_whose_last_batch_was_saved_is_finished_on_restart(small_definition):
    store = MemoryStore()
    study_id = start(store, small_definition)
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    store.set_status(study_id, StudyStatus.RUNNING)  # as if the process stopped before "done"

    progress = Driver(store, SyntheticExecutor()).step(study_id, timeout=0)

    assert progress.status is StudyStatus.DONE
    assert len(store.trials(study_id)) == 20 and store.load_study(study_id).generation == 4
