"""The driver on the in-memory store and the synthetic executor: the paper's protocol count,
resume after a kill, duplicates, failures, pause, re-evaluation of matching sets."""

from __future__ import annotations

from collections import Counter

import pytest

from dem.result import SimulationResult, SimulationStatus
from optimizer.driver import Driver
from optimizer.memory import MemoryStore, SyntheticExecutor, synthetic_result
from optimizer.protocols import StudyStatus, TrialState
from optimizer.seeds import trial_seed
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
    search = [record for record in trials if record.spec.generation <= 9]
    checks = [record for record in trials if record.spec.generation == 11]
    assert progress.status is StudyStatus.DONE
    assert len(search) == 185 and len(executor.submitted) == len(trials) == 185 + len(checks)
    assert Counter(record.spec.generation for record in search) == {0: 50, **{g: 15 for g in range(1, 10)}}
    assert len(checks) == 10 * len({record.spec.individual for record in checks}) <= 30
    assert store.load_study(study_id).generation == 12
    assert progress.trials_done == progress.trials_planned == len(trials)


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
    assert sum(simulated.values()) == len(simulated) == len(store.trials(study_id))
    assert set(results_per_trial(store, study_id).values()) == {1}
    assert progress.recommendation["params"] == reference.recommendation["params"]


def test_a_resumed_batch_runs_its_stored_trials_on_their_stored_seeds(small_definition):
    """What was simulated is the truth: a study whose seeding rule reads differently on resume (a
    definition stored before ``common_seeds``, read with today's default) finishes its batch on the
    seeds its rows hold, not on seeds the rule would give now."""
    store = MemoryStore()
    study_id = start(store, small_definition.model_copy(update={"common_seeds": "study"}))
    first = Driver(store, SyntheticExecutor(per_poll=3))
    while store.load_study(study_id).generation < 2:
        first.step(study_id, timeout=0)
    first.step(study_id, timeout=0)  # batch 2 submitted, 3 of its 4 trials finished
    stored = {r.spec.trial_id: r.spec.seed for r in store.trials(study_id) if r.spec.generation == 2}
    assert len(set(stored.values())) == 1
    store._studies[study_id].definition["common_seeds"] = "generation"
    submitted = {}

    def respond(spec):
        submitted[spec.trial_id] = spec.seed
        return synthetic_result(spec)

    Driver(store, SyntheticExecutor(respond)).step(study_id, timeout=0)

    resubmitted = set(submitted) & set(stored)
    assert resubmitted and all(submitted[trial] == stored[trial] for trial in resubmitted)


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
    assert sum(r.spec.generation <= 9 for r in store.trials(study_id)) == 185
    assert any(r.result.status is SimulationStatus.UNSTABLE for r in store.trials(study_id))
    assert progress.recommendation["params"]["E"] <= 1e8


class TakingExecutor(SyntheticExecutor):
    """Finishes nothing; ``take`` stands for a worker that has taken a trial off the queue and not
    yet said so (an RQ worker of several queues, between its BLPOP and the started registry): the
    executor cannot list that trial, but finds it when asked about it."""

    def __init__(self):
        super().__init__(per_poll=0)
        self.taken: set[str] = set()

    def take(self) -> str:
        trial = self.queue.popleft().trial_id
        self.taken.add(trial)
        return trial

    def in_flight(self, expected=()):
        return super().in_flight() | (self.taken & set(expected))


def test_a_trial_a_worker_is_taking_is_not_sent_again_by_reconciliation(small_definition):
    store, executor = MemoryStore(), TakingExecutor()
    study_id = start(store, small_definition)
    driver = Driver(store, executor, reconcile_every_s=0)
    driver.step(study_id, timeout=0)
    taken = executor.take()

    driver.step(study_id, timeout=0)

    [record] = [record for record in store.trials(study_id) if record.spec.trial_id == taken]
    assert executor.submitted.count(taken) == 1
    assert (record.state, record.attempts) == (TrialState.QUEUED, 1)


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


@pytest.mark.parametrize("common_seeds", ["generation", "study", "trial"])
def test_validation_reruns_the_fastest_matches_on_seeds_the_search_never_used(common_seeds):
    definition = make_definition(
        ga={"population": 8, "offspring": 4, "generations": 3},
        validation={"seeds": 5, "candidates": 2},
        common_seeds=common_seeds,
    )
    store = MemoryStore()
    study_id = start(store, definition)

    progress = Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    trials = store.trials(study_id)
    fresh = [r for r in trials if r.spec.generation == definition.validation_batch()]
    search_seeds = {r.spec.seed for r in trials if r.spec.generation < definition.validation_batch()}
    assert progress.status is StudyStatus.DONE
    assert 0 < len(fresh) <= 10 and len(fresh) % 5 == 0
    assert not {r.spec.seed for r in fresh} & search_seeds
    assert len({r.spec.seed for r in fresh}) == 5  # the same fresh seeds for every candidate
    rows = progress.recommendation["validation"]
    assert [row["individual"] for row in rows] == sorted({r.spec.individual for r in fresh}, key=[
        row["individual"] for row in rows
    ].index)
    assert progress.recommendation["validation_status"] in ("validated", "not reproduced")
    if progress.recommendation["validation_status"] == "validated":
        validated = [row for row in rows if row["verdict"] == "validated"]
        assert progress.recommendation["individual"] == validated[0]["individual"]
        assert progress.recommendation["f2"] == min(row["f2"] for row in validated)
    assert all(len(row["n_remaining"]) == 5 for row in rows)


@pytest.mark.parametrize(("seeds", "during", "after"), [
    (5, {"pending"}, {"validated", "not reproduced"}), (0, {"not validated"}, {"not validated"}),
])
def test_the_recommendation_is_pending_until_its_validation(seeds, during, after):
    """A set recommended while the search runs has not been checked yet: "not validated" then
    read as a verdict on the dashboard; it is the label of a study without validation seeds."""
    definition = make_definition(
        ga={"population": 8, "offspring": 4, "generations": 3}, validation={"seeds": seeds, "candidates": 2}
    )
    store = MemoryStore()
    study_id = start(store, definition)
    driver = Driver(store, SyntheticExecutor(per_poll=2), reconcile_every_s=0)

    seen = set()
    progress = driver.step(study_id, timeout=0)
    while progress.status is StudyStatus.RUNNING:
        if progress.recommendation and progress.batch < definition.validation_batch():
            seen.add(progress.recommendation["validation_status"])
        progress = driver.step(study_id, timeout=0)

    assert seen == during
    assert progress.recommendation["validation_status"] in after


def test_common_random_numbers_replicate_r_has_one_seed_across_the_individuals_of_a_generation():
    """Each generation draws new common seeds; generation 0 keeps the study-wide seeds, so a study
    stored before ``common_seeds`` re-runs its initial population on the same draws."""
    definition, records = _run_seeded(replicates=3)

    seeds: dict[tuple[int, int], set[int]] = {}
    for record in records:
        seeds.setdefault((record.spec.generation, record.spec.replicate), set()).add(record.spec.seed)
    assert sorted(seeds) == [(g, r) for g in range(3) for r in range(3)]
    assert all(len(values) == 1 for values in seeds.values())
    assert len({next(iter(values)) for values in seeds.values()}) == 9
    assert [seeds[0, r] for r in range(3)] == [{trial_seed(definition.seed, r)} for r in range(3)]


def test_common_seeds_study_keeps_one_seed_per_replicate_for_the_whole_study():
    definition, records = _run_seeded(replicates=3, common_seeds="study")

    seeds: dict[int, set[int]] = {}
    for record in records:
        seeds.setdefault(record.spec.replicate, set()).add(record.spec.seed)
    assert seeds == {r: {trial_seed(definition.seed, r)} for r in range(3)}


def test_common_seeds_trial_gives_every_simulation_its_own_seed():
    """As repeated experiments: a generation samples the draws instead of sharing one."""
    _, records = _run_seeded(replicates=2, common_seeds="trial")

    seeds = [record.spec.seed for record in records]
    assert len(seeds) == (6 + 2 * 3) * 2
    assert len(set(seeds)) == len(seeds)


def _run_seeded(**overrides):
    """A small study (6 + 2 x 3 sets, no validation) run to its end: its definition and trials."""
    definition = make_definition(
        ga={"population": 6, "offspring": 3, "generations": 2}, validation={"seeds": 0}, **overrides
    )
    store = MemoryStore()
    study_id = start(store, definition)
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    return definition, store.trials(study_id)


def test_extra_replicates_go_to_promising_sets_and_stay_within_the_budget():
    definition = make_definition(
        ga={"population": 10, "offspring": 5, "generations": 3},
        replicates=2,
        max_replicates=5,
        budget=(10 + 15) * 2 + 12 + 2 * 4,
        validation={"seeds": 4, "candidates": 2},
    )
    store = MemoryStore()
    study_id = start(store, definition)

    progress = Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    trials = store.trials(study_id)
    extra = [r for r in trials if 2 <= r.spec.replicate < 100]
    assert progress.status is StudyStatus.DONE
    assert len(trials) <= definition.total_simulations() == 70
    assert 0 < len(extra) <= 12 and len(extra) % 3 == 0
    per_individual = Counter(r.spec.individual for r in trials if r.spec.replicate < 100)
    assert set(per_individual.values()) <= {2, 5}
    assert progress.recommendation is None or progress.recommendation["replicates"] == 5


def test_step_is_bounded_and_reports_progress(small_definition):
    store = MemoryStore()
    study_id = start(store, small_definition)
    driver = Driver(store, SyntheticExecutor(per_poll=1))

    progress = driver.step(study_id, timeout=0)

    assert progress.status is StudyStatus.RUNNING
    assert (progress.batch, progress.batches) == (0, 6)
    assert (progress.trials_done, progress.trials_in_flight, progress.trials_planned) == (1, 7, 20)


@pytest.mark.parametrize("algorithm", ["random", "spea2", "surrogate"])
def test_other_algorithms_run_the_same_budget(algorithm):
    definition = make_definition(
        ga={"algorithm": algorithm, "population": 8, "offspring": 4, "generations": 3},
        validation={"seeds": 0},
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
    assert len(store.trials(study_id)) == 20 and store.load_study(study_id).generation == 6


def test_surrogate_study_resumed_from_the_sql_store_proposes_what_an_uninterrupted_one_does(any_store):
    definition = make_definition(
        ga={"algorithm": "surrogate", "population": 6, "offspring": 3, "generations": 2},
        validation={"seeds": 0},
    )
    reference_store = MemoryStore()
    reference_id = start(reference_store, definition)
    Driver(reference_store, SyntheticExecutor()).run_to_completion(reference_id, poll_timeout=0)

    study_id = start(any_store, definition)
    first = Driver(any_store, SyntheticExecutor())
    while any_store.load_study(study_id).generation < 2:
        first.step(study_id, timeout=0)
    Driver(any_store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)

    def proposals(store, sid):
        return sorted((r.spec.individual, tuple(r.spec.params.values())) for r in store.trials(sid))

    assert len(proposals(any_store, study_id)) == 6 + 2 * 3
    assert [p for _, p in proposals(any_store, study_id)] == [
        p for _, p in proposals(reference_store, reference_id)
    ]


def _invalid_when_soft(spec):
    """Below E = 1e7 the runs are invalid, and would 'match' if their N_t were read."""
    if spec.params["E"] < 1e7:
        return SimulationResult(
            status=SimulationStatus.INVALID, message="overlap", n_items=30, n_remaining=4, max_overlap=0.8
        )
    return synthetic_result(spec)


def test_invalid_runs_are_never_on_the_front_and_never_recommended(small_definition):
    store = MemoryStore()
    study_id = start(store, small_definition)

    driver = Driver(store, SyntheticExecutor(_invalid_when_soft))
    progress = driver.run_to_completion(study_id, poll_timeout=0)

    trials = {record.spec.trial_id: record for record in store.trials(study_id)}
    invalid = {tid for tid, record in trials.items() if record.result.status is SimulationStatus.INVALID}
    fronts = [set(ids) for _, _, ids in store.generations]
    assert progress.status is StudyStatus.DONE
    assert invalid and all(not front & invalid for front in fronts)
    recommended = progress.recommendation
    assert recommended is None or recommended["params"]["E"] >= 1e7


def test_bounds_entirely_invalid_end_the_study_with_a_message_and_no_recommendation():
    definition = make_definition(
        ga={"population": 6, "offspring": 3, "generations": 3}, parameters={"E": {"low": 1e5, "high": 1e6}}
    )
    store, executor = MemoryStore(), SyntheticExecutor(_invalid_when_soft)
    study_id = start(store, definition)

    progress = Driver(store, executor).run_to_completion(study_id, poll_timeout=0)

    assert progress.status is StudyStatus.FAILED
    assert "all 6 sets of the initial population were invalid" in progress.message
    assert "raise parameters.E" in progress.message
    assert progress.recommendation is None
    assert len(executor.submitted) == 6  # nothing after the initial population


def test_validation_seeds_skip_a_seed_the_search_used():
    from optimizer.seeds import VALIDATION_STREAM, validation_seeds

    clash = trial_seed(7, 0, VALIDATION_STREAM)

    assert validation_seeds(7, 2, {clash}) == [trial_seed(7, k, VALIDATION_STREAM) for k in (1, 2)]
    assert validation_seeds(7, 2, set())[0] == clash


@pytest.mark.parametrize("restarted", [False, True])
def test_the_validation_rows_carry_the_pooled_evidence_its_candidates_were_chosen_on(monkeypatch, restarted):
    """The driver computes ``pooled_evidence`` once, when it chooses the candidates, and the rows
    carry that; a driver restarted while the fresh runs go computes it again from the store.
    Either way the rows read what the whole search's runs say after it ended."""
    import optimizer.driver as driver_module
    from optimizer.neighbours import pooled_evidence
    from optimizer.objectives import evaluate
    from optimizer.space import ParameterSpace

    definition = make_definition(
        ga={"population": 8, "offspring": 4, "generations": 3, "match_estimate": "neighbours"},
        validation={"seeds": 3, "candidates": 2},
    )
    store = MemoryStore()
    study_id = start(store, definition)
    calls = []
    monkeypatch.setattr(
        driver_module, "pooled_evidence", lambda *args: calls.append(1) or pooled_evidence(*args)
    )
    driver = Driver(store, SyntheticExecutor(per_poll=2))
    while store.load_study(study_id).generation < definition.validation_batch():
        driver.step(study_id, timeout=0)
    driver.step(study_id, timeout=0)  # the validation batch: its candidates, sent
    if restarted:
        driver = Driver(store, SyntheticExecutor())

    progress = driver.run_to_completion(study_id, poll_timeout=0)

    space = ParameterSpace(definition.parameters)
    evaluations = evaluate(store.trials(study_id), definition, definition.n_items())
    expected = pooled_evidence(evaluations, definition, space)
    rows = progress.recommendation["validation"]
    assert progress.status is StudyStatus.DONE and rows
    assert len(calls) == 1 + restarted
    assert [
        (row["search_pooled_w1"], row["search_pooled_violation"], row["search_pooled_failed_share"])
        for row in rows
    ] == [tuple(expected[row["individual"]]) for row in rows]
