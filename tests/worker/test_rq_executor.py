"""The RQ executor against a real Redis and a real (forking, burst-mode) RQ worker.

The job run here is a stand-in for the simulation (``stand_in_trial``: its scenario says whether
it returns a result or raises), because what is under test is the queue path: enqueueing,
exactly-once results, retries of infrastructure failures only, reconciliation snapshots. The real
simulation through this path is covered in ``tests/e2e/``.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import time

import pytest
import redis
from rq import Queue, get_current_job
from rq.job import Job
from rq.registry import StartedJobRegistry
from rq.serializers import JSONSerializer

from dem.result import SimulationResult, SimulationStatus
from dem.scenarios import registry
from optimizer.protocols import TrialSpec, trial_id
from worker.local import DEFAULT_GRACE_S as LOCAL_GRACE_S
from worker.rq_executor import (
    MAX_JOB_TIMEOUT_S,
    MIN_JOB_TIMEOUT_S,
    RedisQueueError,
    RqExecutor,
    engine_queues,
    job_timeout,
)
from worker.rq_job import CancellationCheck, attempt, deliver, results_key
from worker.runner import build_worker

pytestmark = pytest.mark.redis

QUEUE = "demcal-test"


def stand_in_trial(spec: dict) -> dict:
    """A job that does what the scenario's ``behaviour`` says, through the real delivery path."""
    behaviour = spec["scenario"].get("behaviour", "ok")
    if behaviour == "raise" or (behaviour == "raise once" and attempt(get_current_job()) == 1):
        raise OSError("scratch disk full")
    if behaviour == "raise once":
        behaviour = "ok"
    if behaviour == "run until cancelled":
        should_stop = CancellationCheck(get_current_job(), spec["trial_id"], every_s=0.1)
        deadline = time.monotonic() + 30
        while not should_stop() and time.monotonic() < deadline:
            time.sleep(0.05)
        behaviour = "cancelled" if should_stop() else "ok"
    result = SimulationResult(
        status=SimulationStatus(behaviour),
        n_items=3,
        n_remaining=spec["individual"] % 4,
        params=spec["params"],
        seed=spec["seed"],
    ).model_dump(mode="json")
    deliver(get_current_job(), spec, result)
    return result


JOB_FUNCTION = f"{__name__}.stand_in_trial"


def make_spec(study: str, individual: int, behaviour: str = "ok", **overrides) -> TrialSpec:
    fields = dict(
        trial_id=trial_id(study, individual, 0),
        study_id=study,
        individual=individual,
        generation=0,
        replicate=0,
        seed=1000 + individual,
        params={"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.4},
        scenario={"behaviour": behaviour},
    )
    fields.update(overrides)
    return TrialSpec(**fields)


@pytest.fixture
def connection(redis_url):
    client = redis.Redis.from_url(redis_url)
    yield client
    client.close()


@pytest.fixture
def executor(connection):
    return RqExecutor(connection, QUEUE, job_function=JOB_FUNCTION)


def run_worker_until_empty(connection) -> None:
    build_worker(connection, [QUEUE], heartbeat_s=2).work(burst=True, logging_level="WARNING")


def take_as_a_two_queue_worker(connection) -> Job:
    """Take the next job as a worker with an engine of its own does (BLPOP from its engine's queue
    and the base queue), without registering it as started: the job is then in no list."""
    queues = [
        Queue(name, connection=connection, serializer=JSONSerializer)
        for name in engine_queues(QUEUE, ["numba", "liggghts"])
    ]
    job, _ = Queue.dequeue_any(queues, None, connection=connection, serializer=JSONSerializer)
    return job


def test_a_generation_is_enqueued_with_trial_ids_as_job_ids(executor, connection):
    specs = [make_spec("s1", i) for i in range(5)]

    executor.submit(specs)

    assert executor.queue.job_ids == [spec.trial_id for spec in specs]
    job = Job.fetch(specs[0].trial_id, connection=connection, serializer=JSONSerializer)
    assert job.args[0]["scenario"] == {"behaviour": "ok"}
    assert job.timeout >= MIN_JOB_TIMEOUT_S
    assert job.retries_left == 2


def test_submitting_a_trial_already_queued_is_a_no_op(executor):
    specs = [make_spec("s1", i) for i in range(3)]
    executor.submit(specs)

    executor.submit(specs + [make_spec("s1", 3)])

    assert executor.queue.count == 4


def test_every_result_is_taken_exactly_once(executor, connection):
    specs = [make_spec("s1", i) for i in range(4)]
    executor.submit(specs)
    run_worker_until_empty(connection)

    first = executor.poll(timeout=1.0)
    second = executor.poll()

    assert sorted(outcome.trial_id for outcome in first) == [spec.trial_id for spec in specs]
    assert all(outcome.worker for outcome in first)
    assert [outcome.result.n_remaining for outcome in sorted(first, key=lambda o: o.trial_id)] == [0, 1, 2, 3]
    assert second == []


def test_a_late_duplicate_result_is_dropped(executor, connection):
    spec = make_spec("s1", 0)
    executor.submit([spec])
    run_worker_until_empty(connection)
    executor.poll(timeout=1.0)
    duplicate = {"trial_id": spec.trial_id, "study_id": "s1", "worker": "w", "result": {"status": "ok"}}
    connection.rpush(results_key(QUEUE, "s1"), json.dumps(duplicate))

    outcomes = executor.poll()

    assert outcomes == []


def test_services_take_only_the_results_of_studies_they_watch(connection):
    mine = RqExecutor(connection, QUEUE, job_function=JOB_FUNCTION)
    theirs = RqExecutor(connection, QUEUE, job_function=JOB_FUNCTION)
    mine.submit([make_spec("mine", 0)])
    theirs.submit([make_spec("theirs", 0)])
    run_worker_until_empty(connection)

    taken_by_mine = mine.poll(timeout=1.0)
    taken_by_theirs = theirs.poll(timeout=1.0)

    assert [outcome.trial_id for outcome in taken_by_mine] == [trial_id("mine", 0, 0)]
    assert [outcome.trial_id for outcome in taken_by_theirs] == [trial_id("theirs", 0, 0)]


def test_an_unstable_simulation_is_a_result_and_is_not_retried(executor, connection):
    spec = make_spec("s1", 0, behaviour="unstable")
    executor.submit([spec])

    run_worker_until_empty(connection)
    outcomes = executor.poll(timeout=1.0)

    assert [outcome.result.status for outcome in outcomes] == [SimulationStatus.UNSTABLE]
    job = Job.fetch(spec.trial_id, connection=connection, serializer=JSONSerializer)
    assert len(job.results()) == 1


def test_a_job_that_keeps_failing_is_retried_then_reported_as_an_error(executor, connection):
    spec = make_spec("s1", 0, behaviour="raise")
    executor.submit([spec])

    run_worker_until_empty(connection)
    outcomes = executor.poll()

    assert len(outcomes) == 1
    result = outcomes[0].result
    assert result.status is SimulationStatus.ERROR
    assert "failed 3 time(s)" in result.message
    assert "scratch disk full" in result.message
    assert result.seed == spec.seed
    assert executor.poll() == []


def test_a_retried_job_reports_its_failed_runs_and_the_store_counts_them_as_attempts(
    executor, connection
):
    from optimizer.memory import MemoryStore

    spec = make_spec("s1", 0, behaviour="raise once")
    clean = make_spec("s1", 1)
    store = MemoryStore()
    store.add_trials([spec, clean])
    store.mark_queued([spec.trial_id, clean.trial_id])
    executor.submit([spec, clean])

    run_worker_until_empty(connection)
    outcomes = {outcome.trial_id: outcome for outcome in executor.poll(timeout=1.0)}
    for outcome in outcomes.values():
        store.record_result(outcome)

    assert outcomes[spec.trial_id].result.status is SimulationStatus.OK
    assert (outcomes[spec.trial_id].retries, outcomes[clean.trial_id].retries) == (1, 0)
    attempts = {record.spec.trial_id: record.attempts for record in store.trials("s1")}
    assert attempts == {spec.trial_id: 2, clean.trial_id: 1}


def test_a_job_failing_for_good_reports_every_run_as_an_attempt(executor, connection):
    spec = make_spec("s1", 0, behaviour="raise")
    executor.submit([spec])

    run_worker_until_empty(connection)
    [outcome] = executor.poll()

    assert outcome.retries == 2


def test_a_failed_trial_submitted_again_runs_again(executor, connection):
    failing = make_spec("s1", 0, behaviour="raise")
    executor.submit([failing])
    run_worker_until_empty(connection)
    executor.poll()

    executor.submit([make_spec("s1", 0, behaviour="ok")])
    run_worker_until_empty(connection)
    outcomes = executor.poll(timeout=1.0)

    assert [outcome.result.status for outcome in outcomes] == [SimulationStatus.OK]


def test_in_flight_holds_queued_trials_and_untaken_results_and_nothing_after_a_flush(executor, connection):
    executor.submit([make_spec("s1", i) for i in range(2)])
    run_worker_until_empty(connection)
    executor.submit([make_spec("s1", 2)])

    before_flush = executor.in_flight()
    connection.flushdb()  # stands for FLUSHALL on a shared Redis
    after_flush = executor.in_flight()

    assert before_flush == {trial_id("s1", i, 0) for i in range(3)}
    assert after_flush == set()


def test_a_trial_a_worker_is_taking_from_one_of_several_queues_is_in_flight(executor, connection):
    # A worker with an engine of its own listens on two queues; RQ then takes a job with BLPOP and
    # registers it as started only a few round trips later: in between, the job is in no list.
    # A reconciliation falling there must not take the trial for lost (an attempt it never made).
    spec = make_spec("s1", 0)
    executor.submit([spec])

    job = take_as_a_two_queue_worker(connection)

    assert job.id == spec.trial_id and executor.queue.count == 0
    assert executor.in_flight([spec.trial_id]) == {spec.trial_id}


def test_a_trial_left_between_lists_by_a_dead_worker_is_lost_and_sent_again(
    executor, connection, monkeypatch
):
    # A worker took the job from one of its queues and died before registering it as started:
    # the job stays "queued" in no list, which RQ never recovers. In flight while a live worker
    # could still be registering it; past that, lost, and submit enqueues it again.
    import worker.rq_executor as rq_executor

    spec, other = make_spec("s1", 0), make_spec("s2", 0)
    executor.submit([spec, other])
    for _ in range(2):
        take_as_a_two_queue_worker(connection)
    assert executor.queue.count == 0 and executor.in_flight() == set()  # in no list

    monkeypatch.setattr(rq_executor, "BETWEEN_LISTS_S", 0.2)
    assert executor.in_flight([spec.trial_id]) == {spec.trial_id}
    time.sleep(0.1)
    assert executor.in_flight([other.trial_id]) == {other.trial_id}  # another caller's trial
    time.sleep(0.15)
    assert executor.in_flight([spec.trial_id]) == set()  # its time kept through the other call
    assert executor.in_flight([other.trial_id]) == {other.trial_id}

    executor.submit([spec, other])

    assert executor.queue.job_ids == [spec.trial_id]
    assert executor.in_flight([spec.trial_id]) == {spec.trial_id}
    run_worker_until_empty(connection)
    assert [outcome.trial_id for outcome in executor.poll(timeout=1.0)] == [spec.trial_id]


def test_an_expected_trial_whose_job_finished_or_was_flushed_is_not_in_flight(executor, connection):
    done, flushed = make_spec("s1", 0), make_spec("s1", 1)
    executor.submit([done])
    run_worker_until_empty(connection)
    executor.poll(timeout=1.0)  # its result taken: Redis holds nothing more to do or take for it
    executor.submit([flushed])
    connection.delete(Job.key_for(flushed.trial_id), executor.queue.key)  # a flush, of this trial only

    assert executor.in_flight([done.trial_id, flushed.trial_id]) == set()


def test_a_dead_workers_job_is_retried_once_while_a_worker_may_clean_the_queue_too(executor, connection):
    # A worker took the job and died: its started entry has expired. A worker cleaning the queue
    # holds RQ's maintenance lock; the service's cleanup then leaves the queue to it (two
    # cleanups at once would both retry the job, queueing it twice), and cleans it once it is free.
    spec = make_spec("s1", 0)
    executor.submit([spec])
    queue = executor.queue
    connection.lpop(queue.key)
    started = StartedJobRegistry(queue=queue)
    connection.zadd(started.key, {f"{spec.trial_id}:dead-worker-execution": 1})

    assert queue.acquire_maintenance_lock()
    executor.maintain()
    assert started.get_job_ids(cleanup=False) == [spec.trial_id] and queue.job_ids == []

    queue.release_maintenance_lock()
    executor.maintain()
    assert started.get_job_ids(cleanup=False) == [] and queue.job_ids == [spec.trial_id]
    assert queue.acquire_maintenance_lock()  # released again for the workers


def test_a_trial_lost_in_a_flush_can_be_submitted_again(executor, connection):
    spec = make_spec("s1", 0)
    executor.submit([spec])
    connection.flushdb()

    executor.submit([spec])
    run_worker_until_empty(connection)

    assert [outcome.trial_id for outcome in executor.poll(timeout=1.0)] == [spec.trial_id]


def test_cancelled_trials_leave_the_queue_and_are_never_reported(executor, connection):
    specs = [make_spec("s1", i) for i in range(3)]
    executor.submit(specs)

    executor.cancel([specs[0].trial_id])
    run_worker_until_empty(connection)

    assert sorted(o.trial_id for o in executor.poll(timeout=1.0)) == [s.trial_id for s in specs[1:]]


def test_a_trial_cancelled_while_between_lists_leaves_no_time_behind(executor, connection):
    # A job taken from one of several queues is in no list until its worker registers it; the
    # executor keeps when it first saw it so. Cancelled, the trial is never expected again, so
    # only cancel can drop that time (a long-lived service would keep one per such trial).
    spec = make_spec("s1", 0)
    executor.submit([spec])
    take_as_a_two_queue_worker(connection)
    assert executor.in_flight([spec.trial_id]) == {spec.trial_id}
    assert spec.trial_id in executor._between

    executor.cancel([spec.trial_id])

    assert spec.trial_id not in executor._between


def test_an_unreachable_redis_is_an_error_naming_the_url():
    with pytest.raises(RedisQueueError, match="127.0.0.1:1/0"):
        RqExecutor.from_url("redis://127.0.0.1:1/0")


def test_job_timeout_is_the_deadline_with_a_margin_when_the_spec_has_one():
    # A scenario whose estimate is far above every deadline below: the job timeout must follow
    # the spec's deadline, not the estimate, and leave the run time to stop and report.
    long_run = {"stages": {"vibration_time": 1e5}}  # the paper's 30 items
    estimate = job_timeout(make_spec("s1", 0, scenario=long_run))
    timeouts = {
        deadline: job_timeout(make_spec("s1", 0, scenario=long_run, timeout_s=deadline))
        for deadline in (1000.0, 3600.0, 7200.0)
    }

    for deadline, seconds in timeouts.items():
        margin = seconds - deadline
        # The run checks its deadline between chunks, then still has to deliver its result: at
        # least the overrun the local pool allows before it kills a process.
        assert margin >= LOCAL_GRACE_S, f"{deadline} s deadline: only {margin} s to stop and report"
        assert seconds < estimate
    assert timeouts[1000.0] < timeouts[3600.0] < timeouts[7200.0]


def test_job_timeout_grows_with_simulated_time_and_has_a_floor_and_a_ceiling():
    def scenario(seconds: float) -> dict:
        return {"stages": {"vibration_start": 1.0, "vibration_time": seconds}}

    short = job_timeout(make_spec("s", 0, scenario=scenario(0.1)))
    paper = job_timeout(make_spec("s", 0, scenario=scenario(60.0)))
    huge = job_timeout(make_spec("s", 0, scenario=scenario(1e7)))

    assert short == MIN_JOB_TIMEOUT_S
    assert short < paper < huge == MAX_JOB_TIMEOUT_S


def test_estimated_time_step_scales_as_one_over_root_e():
    feeder = registry.get("feeder")
    soft = feeder.time_step({}, {"E": 1e6})
    stiff = feeder.time_step({}, {"E": 4e6})

    assert stiff == pytest.approx(soft / 2)


def test_estimated_time_step_takes_the_stiffer_wall_contact_of_a_harder_wall():
    feeder = registry.get("feeder")
    same = feeder.time_step({}, {"E": 1e6})
    softer_walls = feeder.time_step({}, {"E": 1e6, "E_wall": 1e5})
    steel_walls = feeder.time_step({}, {"E": 1e6, "E_wall": 2e11})

    assert softer_walls == pytest.approx(same)  # the item-item contact is then the stiffer one
    # E and E_wall in series: K -> 2 x (E D / 2) as E_wall -> infinity, so the step -> 1 / sqrt(2).
    assert steel_walls == pytest.approx(same / math.sqrt(2), rel=1e-4)


def test_a_running_trial_is_cancelled_and_its_outcome_never_reported(executor, connection, redis_url):
    spec = make_spec("s1", 0, behaviour="run until cancelled")
    executor.submit([spec])
    worker = multiprocessing.get_context("fork").Process(
        target=lambda: run_worker_until_empty(redis.Redis.from_url(redis_url))
    )
    worker.start()
    job = Job.fetch(spec.trial_id, connection=connection, serializer=JSONSerializer)
    deadline = time.monotonic() + 20
    while job.get_status() != "started" and time.monotonic() < deadline:
        time.sleep(0.05)

    executor.cancel([spec.trial_id])
    worker.join(20)
    outcomes = executor.poll()

    assert worker.exitcode == 0
    assert outcomes == []
    assert job.latest_result().return_value["status"] == "cancelled"


def test_a_cancelled_simulation_is_never_reported_even_by_another_service(connection):
    submitter = RqExecutor(connection, QUEUE, job_function=JOB_FUNCTION)
    submitter.submit([make_spec("s1", 0, behaviour="cancelled")])
    run_worker_until_empty(connection)
    other_service = RqExecutor(connection, QUEUE, job_function=JOB_FUNCTION)
    other_service.watch(["s1"])

    outcomes = other_service.poll()

    assert outcomes == []


def test_a_trial_for_an_engine_no_worker_has_waits_and_says_so(executor, connection):
    spec = make_spec("s1", 0, engine="liggghts")
    plain = make_spec("s1", 1)
    executor.submit([spec, plain])

    assert "liggghts" in executor.waiting() and "numba" not in executor.waiting()
    assert "no worker takes queue 'demcal-test.liggghts'" in executor.waiting()["liggghts"]
    run_worker_until_empty(connection)  # a worker without LIGGGHTS takes only the plain trial
    assert [outcome.trial_id for outcome in executor.poll(timeout=1.0)] == [plain.trial_id]
    assert spec.trial_id in executor.in_flight() and executor.queue_depth() == 1

    # A worker that has the engine takes its queue; the result reaches the service as any other.
    queues = engine_queues(QUEUE, ["numba", "command", "liggghts"])
    assert queues == ["demcal-test.liggghts", QUEUE]
    build_worker(connection, queues, heartbeat_s=2).work(burst=True, logging_level="WARNING")
    assert [outcome.trial_id for outcome in executor.poll(timeout=1.0)] == [spec.trial_id]
    assert executor.in_flight() == set()
