"""The SQL store keeps the optimiser's Store contract on SQLite and PostgreSQL: idempotent
results, atomic generations, the driver's whole loop, and the single-simulation queue."""

from __future__ import annotations

import math
import threading
from datetime import timedelta

import pytest

from api.errors import NotFoundError
from api.models import TrialRow, decode_value
from dem.result import SimulationResult, SimulationStatus
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_with_failures
from optimizer.objectives import evaluate
from optimizer.outcomes import shown_objectives
from optimizer.protocols import StudyStatus, TrialOutcome, TrialSpec, TrialState, trial_id
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


def _definition() -> dict:
    return StudyDefinition.model_validate(study_definition()).model_dump(mode="json")


def _specs(study_id: str, count: int, generation: int = 0) -> list[TrialSpec]:
    return [
        TrialSpec(
            trial_id=trial_id(study_id, i, 0), study_id=study_id, individual=i, generation=generation,
            replicate=0, seed=100 + i, params={"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.1 * (i + 1)},
            scenario={"items": {"counts": {"camera": 1}}},
        )
        for i in range(count)
    ]


def _result(n_remaining: int, wall: float = 1.0) -> SimulationResult:
    return SimulationResult(status=SimulationStatus.OK, n_items=30, n_remaining=n_remaining, wall_time_s=wall,
                            cost=wall * 1000)


def test_add_trials_stores_pending_and_keeps_existing_ones(store):
    study_id = store.create_study(_definition(), owner="alice")
    specs = _specs(study_id, 3)
    store.add_trials(specs)
    store.mark_queued([specs[0].trial_id])

    store.add_trials(specs)

    states = {record.spec.trial_id: record.state for record in store.trials(study_id)}
    assert states == {specs[0].trial_id: TrialState.QUEUED, specs[1].trial_id: TrialState.PENDING,
                      specs[2].trial_id: TrialState.PENDING}
    assert store.trials(study_id)[1].spec == specs[1]


def test_record_result_is_idempotent(store):
    study_id = store.create_study(_definition(), owner=None)
    spec = _specs(study_id, 1)[0]
    store.add_trials([spec])

    first = store.record_result(TrialOutcome(spec.trial_id, _result(4), worker="w1"))
    second = store.record_result(TrialOutcome(spec.trial_id, _result(9), worker="w2"))

    record = store.trials(study_id)[0]
    assert (first, second) == (True, False)
    assert record.state is TrialState.DONE
    assert record.result.n_remaining == 4
    assert record.worker == "w1"


def test_racing_results_are_recorded_exactly_once(store):
    study_id = store.create_study(_definition(), owner=None)
    spec = _specs(study_id, 1)[0]
    store.add_trials([spec])
    outcomes, barrier = [], threading.Barrier(8)

    def send(n: int) -> None:
        barrier.wait()
        outcomes.append(store.record_result(TrialOutcome(spec.trial_id, _result(n))))

    threads = [threading.Thread(target=send, args=(n,)) for n in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()

    assert sorted(outcomes) == [False] * 7 + [True]


def test_result_for_an_unknown_trial_changes_nothing(store):
    assert store.record_result(TrialOutcome("st-gone-i00000-r00", _result(1))) is False


def test_save_generation_is_atomic(store):
    study_id = store.create_study(_definition(), owner=None)
    specs = _specs(study_id, 2)
    store.add_trials(specs)
    store.save_generation(study_id, 1, b"state-1", [specs[0].trial_id], {"params": {"E": 1.0}})

    with pytest.raises(TypeError):
        # A malformed objective fails after the generation, GA state and flags were written.
        store.save_generation(study_id, 2, b"state-2", [specs[1].trial_id], None,
                              objectives={specs[1].trial_id: ("not a number", 1.0)})

    study = store.load_study(study_id)
    pareto = {row.id for row in store.pareto_rows(study_id)}
    assert (study.generation, study.ga_state, study.recommendation) == (1, b"state-1", {"params": {"E": 1.0}})
    assert pareto == {specs[0].trial_id}


def test_save_generation_stores_infinite_objectives_portably(store):
    study_id = store.create_study(_definition(), owner=None)
    specs = _specs(study_id, 2)
    store.add_trials(specs)

    objectives = {specs[0].trial_id: (math.inf, 2.5), specs[1].trial_id: (0.5, -math.inf)}

    store.save_generation(study_id, 1, b"s", [], None, objectives=objectives)

    rows = {row.id: row for row in store.trial_columns(study_id)}
    assert (rows[specs[0].trial_id].f1_kind, rows[specs[0].trial_id].f2_value) == ("inf", 2.5)
    assert (rows[specs[1].trial_id].f1_value, rows[specs[1].trial_id].f2_kind) == (0.5, "-inf")


def test_matching_trials_are_the_ok_ones_with_a_finite_f1_within_tolerance(store):
    # What the recommendation reads: the filter runs in the database, so it must agree with the
    # objectives' portable storage (specials in a kind column) on both backends.
    study_id = store.create_study(_definition(), owner=None)
    specs = _specs(study_id, 6)
    store.add_trials(specs)
    for spec in specs[:5]:
        store.record_result(TrialOutcome(spec.trial_id, _result(4)))
    store.record_result(TrialOutcome(specs[5].trial_id, SimulationResult(status=SimulationStatus.UNSTABLE)))
    f1s = [0.0, 0.5, 0.7, math.inf, math.nan, 0.0]
    store.save_generation(study_id, 1, b"s", [], None,
                          objectives={spec.trial_id: (f1, 1.0) for spec, f1 in zip(specs, f1s, strict=True)})

    matching = store.trial_columns(study_id, f1_at_most=0.5)

    assert [row.id for row in matching] == [specs[0].trial_id, specs[1].trial_id]
    assert len(store.trial_columns(study_id)) == 6


def test_a_result_committed_with_a_clock_behind_is_not_missed_by_the_next_read(store, monkeypatch):
    # The driver reads only what changed since its cursor. With the newest updated_at read as the
    # cursor, a write stamped earlier by another process (its clock behind) fell behind it.
    import api.store.trials as trial_writes

    study_id = store.create_study(_definition(), owner=None)
    specs = _specs(study_id, 2)
    store.add_trials(specs)
    _, cursor = store.changed_trials(study_id)
    store.record_result(TrialOutcome(specs[0].trial_id, _result(4)))
    first, cursor = store.changed_trials(study_id, cursor)
    clock = trial_writes.utcnow
    monkeypatch.setattr(trial_writes, "utcnow", lambda: clock() - timedelta(seconds=5))
    store.record_result(TrialOutcome(specs[1].trial_id, _result(3)))  # another process, 5 s behind
    monkeypatch.undo()

    late, _ = store.changed_trials(study_id, cursor)

    results = {record.spec.trial_id: record.result for record in late}
    assert specs[0].trial_id in {record.spec.trial_id for record in first}
    assert results[specs[1].trial_id].n_remaining == 3


def test_the_stored_objectives_are_those_the_driver_told_the_search(store):
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 3}, max_replicates=3, seed=3)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")

    Driver(store, SyntheticExecutor(synthetic_with_failures)).run_to_completion(study_id, poll_timeout=0)

    told = shown_objectives(evaluate(store.trials(study_id), definition, definition.n_items()))
    stored = {
        row.id: (decode_value(row.f1_value, row.f1_kind), decode_value(row.f2_value, row.f2_kind))
        for row in store.trial_columns(study_id)
    }
    assert any(values == (None, None) for values in told.values())  # failed sets are not measurements
    trials = store.trials(study_id)
    assert set(told) == {r.spec.trial_id for r in trials if r.spec.generation < definition.validation_batch()}
    assert any(r.spec.replicate > 0 for r in trials)  # sets earned extra replicates
    assert {tid: stored[tid] for tid in told} == told


def test_driver_runs_a_whole_study_on_the_sql_store(store):
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 6, "offspring": 3, "generations": 2}, seed=3)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")

    progress = Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    trials = store.trials(study_id)
    assert progress.status is StudyStatus.DONE
    assert len(trials) == 12
    assert all(record.state is TrialState.DONE for record in trials)
    assert store.load_study(study_id).recommendation == progress.recommendation
    assert store.pareto_rows(study_id)
    assert store.best_trial(study_id) is not None


def test_queue_bookkeeping_counts_attempts(store):
    study_id = store.create_study(_definition(), owner=None)
    spec = _specs(study_id, 1)[0]
    store.add_trials([spec])

    store.mark_queued([spec.trial_id])
    store.mark_running(spec.trial_id, worker="w1")
    store.mark_queued([spec.trial_id])

    record = store.trials(study_id)[0]
    assert (record.state, record.attempts, record.worker) == (TrialState.QUEUED, 2, "w1")


def test_a_running_trial_the_executor_lost_shows_queued_once_sent_again(store):
    # A restarted server's executor knows nothing of the trial a worker was running: the driver
    # sends it again, and until a worker takes it, it is queued, not "running" on nobody.
    study_id = store.create_study(_definition(), owner=None)
    Driver(store, SyntheticExecutor(per_poll=0)).step(study_id, timeout=0)
    running = store.trials(study_id)[0].spec.trial_id
    store.mark_running(running, worker="w1")

    restarted = SyntheticExecutor(per_poll=0)
    Driver(store, restarted).step(study_id, timeout=0)

    record = next(r for r in store.trials(study_id) if r.spec.trial_id == running)
    assert running in restarted.in_flight()
    assert (record.state, record.attempts) == (TrialState.QUEUED, 2)


def test_a_result_after_the_executors_retries_counts_them_as_attempts(store):
    study_id = store.create_study(_definition(), owner=None)
    spec = _specs(study_id, 1)[0]
    store.add_trials([spec])
    store.mark_queued([spec.trial_id])

    store.record_result(TrialOutcome(spec.trial_id, _result(3), worker="w2", retries=1))
    store.record_result(TrialOutcome(spec.trial_id, _result(3), worker="w3", retries=1))  # a late duplicate

    [record] = store.trials(study_id)
    assert (record.state, record.attempts, record.worker) == (TrialState.DONE, 2, "w2")


def test_cancelling_a_study_cancels_its_waiting_trials(store):
    study_id = store.create_study(_definition(), owner=None)
    specs = _specs(study_id, 2)
    store.add_trials(specs)
    store.record_result(TrialOutcome(specs[0].trial_id, _result(3)))

    store.transition(study_id, [StudyStatus.CREATED], StudyStatus.CANCELLED)

    states = [record.state for record in store.trials(study_id)]
    assert states == [TrialState.DONE, TrialState.CANCELLED]


@pytest.mark.parametrize("end", ["cancel", "fail", "batch saved after a cancel"])
def test_a_study_that_ends_before_its_validation_stores_its_recommendation_not_validated(store, end):
    study_id = store.create_study(_definition(), owner=None)
    pending = {"individual": 3, "validation_status": "pending"}
    store.save_generation(study_id, 0, b"ga", [], pending)
    store.set_status(study_id, StudyStatus.RUNNING)
    assert store.load_study(study_id).recommendation == pending  # a running search's check is to come

    if end == "fail":
        store.set_status(study_id, StudyStatus.FAILED, "worker lost")
    else:
        store.transition(study_id, [StudyStatus.RUNNING], StudyStatus.CANCELLED)
    if end == "batch saved after a cancel":
        store.save_generation(study_id, 1, b"ga", [], pending)

    settled = {"individual": 3, "validation_status": "not validated"}
    assert store.load_study(study_id).recommendation == settled


def test_deleting_a_study_deletes_its_trials(store):
    study_id = store.create_study(_definition(), owner=None)
    store.add_trials(_specs(study_id, 2))

    store.delete_study(study_id)

    with pytest.raises(NotFoundError):
        store.load_study(study_id)
    with store.session() as session:
        assert session.query(TrialRow).count() == 0


def test_single_simulation_moves_pending_queued_done_once(store):
    sim_id = store.create_simulation({"items": {}}, {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.4}, 5, "alice")

    pending = store.pending_simulations()
    queued_twice = [store.mark_simulation_queued(sim_id), store.mark_simulation_queued(sim_id)]
    recorded = [store.record_simulation_result(sim_id, _result(2), "w"),
                store.record_simulation_result(sim_id, _result(7), "w")]

    row = store.get_simulation(sim_id)
    assert [spec.trial_id for spec in pending] == [sim_id]
    assert pending[0].seed == 5
    assert queued_twice == [True, False]
    assert recorded == [True, False]
    assert (row.state, row.n_remaining, row.result["n_remaining"]) == ("done", 2, 2)
    assert store.pending_simulations() == []


def test_an_archived_study_restored_into_another_database_finishes_as_the_original(
    store, tmp_path, sqlite_template
):
    """Archive a study mid-generation on one SQLite file, restore it into the fixture's database
    (SQLite or PostgreSQL), and both copies, driven to the end, give the same trials, results and
    recommendation; what was in flight comes back pending, the running study paused."""
    import json
    import shutil

    from api.db import create_db_engine
    from api.store import SqlStore

    shutil.copy(sqlite_template, tmp_path / "source.db")
    source = SqlStore(create_db_engine(f"sqlite:///{tmp_path / 'source.db'}"))
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 6, "offspring": 3, "generations": 2}, seed=3)
    )
    study_id = source.create_study(definition.model_dump(mode="json"), owner="alice")
    driver = Driver(source, SyntheticExecutor(per_poll=2))
    while len([r for r in source.trials(study_id) if r.state is TrialState.DONE]) < 7:
        driver.step(study_id, timeout=0)
    in_flight = [r.spec.trial_id for r in source.trials(study_id) if r.state is not TrialState.DONE]
    source.mark_running(in_flight[0], worker="w1")

    archive = json.loads(json.dumps(source.archive_study(study_id)))
    # The trials share one scenario, kept once (format 2), not in each of them.
    assert len(archive["scenarios"]) == 1 and {t["scenario"] for t in archive["trials"]} == {0}
    restored_id = store.restore_study(archive)

    restored = store.load_study(restored_id)
    original = source.load_study(study_id)
    assert restored_id == study_id
    assert (original.status, restored.status) == (StudyStatus.RUNNING, StudyStatus.PAUSED)
    assert restored.ga_state == original.ga_state and restored.generation == original.generation == 1
    assert {r.spec.trial_id: r.result for r in store.trials(study_id)} == {
        r.spec.trial_id: r.result for r in source.trials(study_id)
    }
    pending = {r.spec.trial_id for r in store.trials(study_id) if r.state is TrialState.PENDING}
    assert pending == set(in_flight)
    assert [r.spec for r in store.trials(study_id)] == [r.spec for r in source.trials(study_id)]

    store.set_status(study_id, StudyStatus.RUNNING)
    ends = [
        Driver(s, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0) for s in (source, store)
    ]
    assert [p.status for p in ends] == [StudyStatus.DONE, StudyStatus.DONE]
    assert ends[0].recommendation == ends[1].recommendation is not None
    assert {r.spec.trial_id: r.result for r in store.trials(study_id)} == {
        r.spec.trial_id: r.result for r in source.trials(study_id)
    }


def test_restoring_a_study_twice_or_a_foreign_document_is_refused(store):
    from api.errors import ConflictError, InvalidInputError

    study_id = store.create_study(_definition(), owner=None)
    store.add_trials(_specs(study_id, 2))
    archive = store.archive_study(study_id)

    with pytest.raises(ConflictError, match="already in this database"):
        store.restore_study(archive)
    with pytest.raises(InvalidInputError, match="not a study archive"):
        store.restore_study({"trials": []})
    future = {**archive, "study": {**archive["study"], "colour": "red"}}
    with pytest.raises(InvalidInputError, match=r"does not know \(colour\)"):
        store.restore_study(future)
    with pytest.raises(NotFoundError):
        store.archive_study("st-nope")


def test_an_archive_of_format_1_restores_and_a_damaged_scenario_index_is_refused(
    store, tmp_path, sqlite_template
):
    """Format 1 (a scenario in every trial, sessions before 11) still restores; a format 2 trial
    naming a scenario the archive does not hold is refused with what to do."""
    import shutil

    from api.db import create_db_engine
    from api.errors import InvalidInputError
    from api.store import SqlStore

    shutil.copy(sqlite_template, tmp_path / "source.db")
    source = SqlStore(create_db_engine(f"sqlite:///{tmp_path / 'source.db'}"))
    study_id = source.create_study(_definition(), owner=None)
    source.add_trials(_specs(study_id, 2))
    archive = source.archive_study(study_id)
    damaged = {**archive, "trials": [{**archive["trials"][0], "scenario": 5}]}
    old = {
        "format": "demcal-study-archive/1", "study": archive["study"],
        "trials": [{**t, "scenario": archive["scenarios"][t["scenario"]]} for t in archive["trials"]],
    }

    with pytest.raises(InvalidInputError, match="names scenario 5"):
        store.restore_study(damaged)
    assert store.restore_study(old) == study_id
    assert [r.spec for r in store.trials(study_id)] == [r.spec for r in source.trials(study_id)]


def test_an_archive_from_before_the_full_load_factor_column_restores_it_from_each_result(
    store, tmp_path, sqlite_template
):
    """Archives made before migration 0010 (benchmarks/paper-study-seed2023-protocol-cost) have no
    ``full_load_factor`` column; the trial lists read it, so it comes from each result."""
    import shutil

    import sqlalchemy as sa

    from api.db import create_db_engine
    from api.store import SqlStore

    shutil.copy(sqlite_template, tmp_path / "source.db")
    source = SqlStore(create_db_engine(f"sqlite:///{tmp_path / 'source.db'}"))
    study_id = source.create_study(_definition(), owner=None)
    specs = _specs(study_id, 2)
    source.add_trials(specs)
    early = _result(0).model_copy(update={"full_load_factor": 3.25})
    source.record_result(TrialOutcome(specs[0].trial_id, early))
    archive = source.archive_study(study_id)
    trials = [{key: value for key, value in t.items() if key != "full_load_factor"}
              for t in archive["trials"]]
    older = {**archive, "trials": trials}

    store.restore_study(older)

    with store.session() as s:
        query = sa.select(TrialRow.id, TrialRow.full_load_factor).where(TrialRow.study_id == study_id)
        factors = dict(s.execute(query).all())
    assert archive["trials"][0]["full_load_factor"] == 3.25  # what the archive carries now
    assert factors == {specs[0].trial_id: 3.25, specs[1].trial_id: 1.0}


def test_an_archive_from_before_common_seeds_restores_with_the_study_wide_seeds_it_ran_on(store):
    """Archives made before migration 0011 (benchmarks/paper-study-*.archive.json) ran with one
    seed per replicate for the whole study; read with today's default they would resume on others."""
    study_id = store.create_study(_definition(), owner=None)
    archive = store.archive_study(study_id)
    store.delete_study(study_id)
    definition = {k: v for k, v in archive["study"]["definition"].items() if k != "common_seeds"}
    older = {**archive, "study": {**archive["study"], "definition": definition}}

    store.restore_study(older)

    assert store.load_study(study_id).definition["common_seeds"] == "study"
    assert "common_seeds" not in older["study"]["definition"]
