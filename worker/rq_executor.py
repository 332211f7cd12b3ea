"""The optimiser's Executor on an RQ queue: trials become jobs that ``demcal worker`` processes on
any machine run, and their results come back through Redis.

Decisions, and why:

* **One round trip per generation.** ``submit`` first reads the status of every job in one
  pipeline (a trial already queued or running is left alone, so re-submitting is a no-op), then
  enqueues all new jobs with ``Queue.enqueue_many`` on one pipeline.
* **Job id = trial id** (``optimizer.protocols.trial_id``: study, individual, replicate), so a
  re-submitted trial is the same job, and RQ's registries speak in trial ids.
* **Job timeout** (RQ's hard kill) comes from the spec's own deadline when it has one, otherwise
  from the scenario's cost estimate in body-steps (``Scenario.cost_estimate``, ``job_timeout``).
* **Retries only for infrastructure.** ``Retry(max=2)``: a job fails only when an exception
  escapes the simulation (a worker killed or lost, memory exhausted). An ``unstable`` or ``error``
  simulation is a result and is never retried (see ``worker/rq_job.py``). After the last retry the
  trial is reported as an ``error`` result carrying RQ's message, so the study goes on.
* **Results exactly once.** Workers push results onto one Redis list per study; ``poll`` pops
  them (atomic), and claims a failed job by removing it from RQ's failed registry (``ZREM``
  returns 1 to one caller only). A second result for the same trial (a presumed-dead worker that
  finished after all) is dropped here when this executor already reported the trial, and by the
  store's idempotent ``record_result`` otherwise.
* **Several services, one queue.** An executor only takes results of the studies it *watches*
  (``watch``; ``submit`` watches the studies it submits for), so two ``demcal serve`` replicas
  driving different studies never take each other's results.
* **Reconciliation support.** ``in_flight`` is one atomic snapshot of everything Redis still
  holds for a trial (queued, being dequeued, running, waiting for a retry, failed but not yet
  reported, finished but not yet taken); a trial the database thinks is queued and that is not in
  it was lost (Redis flushed or restarted) and must be submitted again. ``maintain`` moves jobs
  of dead workers (no heartbeat) out of the started registry, into a retry or the failed registry.
* **A job between two lists is still in flight.** A worker that listens on several queues (an
  engine's own and the base queue, ``engine_queues``) takes a job with BLPOP, which removes it
  from its queue, and only a few round trips later registers it as started: for those
  milliseconds the job is in no list or registry. RQ moves a job atomically (BLMOVE into the
  queue's intermediate list) only for a worker with a single queue, and Redis has no blocking
  move from several lists. So the snapshot also reads, in the same transaction, the job status
  of each trial the caller ``expected`` in flight: one still ``queued`` or ``started`` is in
  flight, as ``submit`` would judge it. Without this, a reconciliation that fell in those
  milliseconds took a trial a healthy worker was starting for lost, and counted an attempt the
  trial never made. A worker killed within those milliseconds leaves its job ``queued`` in no
  list, which RQ never recovers: a job seen between lists for longer than ``BETWEEN_LISTS_S``
  is taken for lost, and ``submit`` enqueues it again although its status still says queued
  (without that, its study would wait for it forever).

Must not: touch the database or decide a trial's state; the driver and the store do that.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Collection, Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from redis import Redis
from rq import Queue, Retry
from rq.job import Job, JobStatus
from rq.registry import FailedJobRegistry, StartedJobRegistry
from rq.serializers import JSONSerializer
from rq.worker import Worker

from dem.result import SimulationResult, SimulationStatus
from optimizer.protocols import TrialOutcome, TrialSpec
from worker.jobs import estimated_cost, longest_first
from worker.rq_job import cancel_key, results_key

logger = logging.getLogger(__name__)

JOB_FUNCTION = "worker.rq_job.perform_trial"
MAX_RETRIES = 2
# Job timeout bounds, seconds. The floor covers JIT compilation and clump generation on a cold
# worker; the ceiling stops a mis-estimated job from holding a worker for days.
MIN_JOB_TIMEOUT_S = 600
MAX_JOB_TIMEOUT_S = 48 * 3600
# Margin of the hard kill over the simulation's own deadline: the simulation stops itself between
# two chunks and still has to deliver its result.
DEADLINE_MARGIN = 1.5
DEADLINE_GRACE_S = 120
# Pessimistic cost of one step per item (clump, contacts, walls) and a safety factor: the job
# timeout is a guard against hangs, not a budget, so overestimating is cheap.
STEP_COST_PER_ITEM_S = 5e-6
TIMEOUT_SAFETY = 4.0
# Finished jobs and failures stay inspectable in Redis for a day (``rq info``, the dashboard).
RESULT_TTL_S = 24 * 3600
FAILURE_TTL_S = 7 * 24 * 3600
ACTIVE_STATES = frozenset({JobStatus.QUEUED, JobStatus.STARTED, JobStatus.SCHEDULED, JobStatus.DEFERRED})
# A cancel request outlives any trial it could concern.
CANCEL_TTL_S = 24 * 3600
# How many results one LPOP takes at most from a study's list.
POP_BATCH = 500
# A worker registers a job it took as started a few round trips after taking it; one in no list
# or registry for longer than this was left there by a worker that died in between.
BETWEEN_LISTS_S = 30.0


class RedisQueueError(RuntimeError):
    """Redis cannot be reached or refused the queue's commands; the message says which URL."""


def job_timeout(spec: TrialSpec, data_dir: Path | None = None) -> int:
    """Seconds after which RQ kills the job: the spec's deadline with a margin, or an estimate
    from simulated duration x steps per second x items, bounded by a floor and a ceiling."""
    if spec.timeout_s:
        seconds = spec.timeout_s * DEADLINE_MARGIN + DEADLINE_GRACE_S
    else:
        # The scenario's body-steps estimate (bodies x steps, from its own time step estimate).
        seconds = TIMEOUT_SAFETY * estimated_cost(spec.scenario, spec.params, data_dir) * STEP_COST_PER_ITEM_S
    return int(min(MAX_JOB_TIMEOUT_S, max(MIN_JOB_TIMEOUT_S, seconds)))


def spec_to_payload(spec: TrialSpec) -> dict[str, Any]:
    """The job's argument: the whole spec, JSON-able, so the worker needs nothing else."""
    return asdict(spec)


# Engines every worker has: their trials share the base queue. Any other engine has a queue of
# its own, "<base>.<engine>", taken only by workers that have it (``engine_queues``).
SHARED_ENGINES = frozenset({"numba", "command"})


def engine_queue_name(base: str, engine: str) -> str:
    """The queue a trial for ``engine`` goes to."""
    return base if engine in SHARED_ENGINES else f"{base}.{engine}"


def engine_queues(base: str, engines: Iterable[str]) -> list[str]:
    """The queues a worker with these engines takes trials from: the engines' own, then the base."""
    own = sorted({engine_queue_name(base, engine) for engine in engines} - {base})
    return [*own, base]


def _text(value: bytes | str) -> str:
    return value.decode() if isinstance(value, bytes) else value


class RqExecutor:
    """Runs trials as RQ jobs on ``queue_name``; see the module docstring for the guarantees."""

    def __init__(
        self,
        connection: Redis,
        queue_name: str = "demcal",
        *,
        job_function: str = JOB_FUNCTION,
        max_retries: int = MAX_RETRIES,
        data_dir: Path | None = None,
    ) -> None:
        self._redis = connection
        self._queue = Queue(queue_name, connection=connection, serializer=JSONSerializer)
        from dem.engines.base import engine_names

        # Every engine's queue, known from the start: a restarted service finds trials in any.
        self._queues = {
            engine: Queue(name, connection=connection, serializer=JSONSerializer)
            for engine, name in ((e, engine_queue_name(queue_name, e)) for e in engine_names())
        }
        self._waiting: dict[str, str] = {}
        self._job_function = job_function
        self._max_retries = max_retries
        self._data_dir = data_dir  # the service's: its meshes size the trials' estimates
        self._watched: set[str] = set()
        # Trials reported since they were last submitted: a late duplicate result is dropped.
        self._reported: set[str] = set()
        self._cancelled: set[str] = set()
        # trial -> when first seen in no list (module docstring); past BETWEEN_LISTS_S, lost
        self._between: dict[str, float] = {}

    @classmethod
    def from_url(cls, url: str, queue_name: str = "demcal", **kwargs: Any) -> RqExecutor:
        """Connect to Redis at ``url``; fails at once with a message if Redis is not there."""
        connection = Redis.from_url(url, socket_connect_timeout=5, health_check_interval=30)
        try:
            connection.ping()
        except Exception as exc:
            connection.close()
            raise RedisQueueError(
                f"cannot reach Redis at {url} ({exc}); start Redis or fix DEMCAL_REDIS_URL"
            ) from exc
        return cls(connection, queue_name, **kwargs)

    @property
    def queue(self) -> Queue:
        return self._queue

    @property
    def connection(self) -> Redis:
        return self._redis

    # -- the Executor protocol ---------------------------------------------------------------

    def submit(self, specs: Sequence[TrialSpec]) -> None:
        """Enqueue every trial not already queued or running, in one round trip."""
        if not specs:
            return
        self.watch(spec.study_id for spec in specs)
        statuses = self._job_statuses([spec.trial_id for spec in specs])
        fresh = longest_first(
            [
                spec
                for spec in specs
                if statuses.get(spec.trial_id) not in ACTIVE_STATES or self._left_between(spec.trial_id)
            ],
            self._data_dir,
        )
        if not fresh:
            return
        by_queue: dict[str, list[TrialSpec]] = {}
        for spec in fresh:
            by_queue.setdefault(self._queue_of(spec.engine).name, []).append(spec)
        with self._redis.pipeline() as pipe:
            for name, group in by_queue.items():
                queue = Queue(name, connection=self._redis, serializer=JSONSerializer)
                jobs = [
                    Queue.prepare_data(
                        self._job_function,
                        args=(spec_to_payload(spec),),
                        job_id=spec.trial_id,
                        timeout=job_timeout(spec, self._data_dir),
                        result_ttl=RESULT_TTL_S,
                        failure_ttl=FAILURE_TTL_S,
                        description=f"demcal trial {spec.trial_id}",
                        # Results of every engine's queue go to the base queue's result lists.
                        meta={
                            "study_id": spec.study_id,
                            "max_retries": self._max_retries,
                            "results_queue": self._queue.name,
                        },
                        retry=Retry(max=self._max_retries) if self._max_retries else None,
                    )
                    for spec in group
                ]
                # A trial submitted again after it failed must not be reported failed again by poll.
                pipe.zrem(FailedJobRegistry(queue=queue).key, *[spec.trial_id for spec in group])
                pipe.delete(*[cancel_key(spec.trial_id) for spec in group])
                queue.enqueue_many(jobs, pipeline=pipe)
            pipe.execute()
        self._check_engines({spec.engine for spec in fresh})
        for spec in fresh:
            self._reported.discard(spec.trial_id)
            self._cancelled.discard(spec.trial_id)
            self._between.pop(spec.trial_id, None)
        logger.info(
            "queued %d trials on %s (%d already in flight)",
            len(fresh),
            self._queue.name,
            len(specs) - len(fresh),
        )

    def poll(self, timeout: float = 0.0) -> list[TrialOutcome]:
        """Results of watched studies that arrived since the last call, each returned once."""
        if not self._watched:
            if timeout > 0:
                time.sleep(timeout)
            return []
        outcomes = self._take_failed() + self._take_results()
        if not outcomes and timeout > 0:
            outcomes = self._take_results(block=timeout)
        fresh = []
        for outcome in outcomes:
            # A cancelled simulation is not a result: if the trial is still wanted (a study paused
            # then resumed), reconciliation submits it again.
            cancelled = outcome.result.status is SimulationStatus.CANCELLED
            if cancelled or outcome.trial_id in self._reported or outcome.trial_id in self._cancelled:
                logger.info("trial %s: dropped a duplicate or cancelled result", outcome.trial_id)
                continue
            self._reported.add(outcome.trial_id)
            fresh.append(outcome)
        return fresh

    def in_flight(self, expected: Collection[str] = ()) -> set[str]:
        """Trial ids Redis still holds as work to do or a result to take, and those of
        ``expected`` whose job a worker is taking (one atomic snapshot; module docstring)."""
        queues, studies, expected = self._all_queues(), sorted(self._watched), sorted(set(expected))
        with self._redis.pipeline(transaction=True) as pipe:
            for queue in queues:
                pipe.lrange(queue.key, 0, -1)
                pipe.lrange(queue.intermediate_queue_key, 0, -1)
                pipe.zrange(StartedJobRegistry(queue=queue).key, 0, -1)
                pipe.zrange(queue.scheduled_job_registry.key, 0, -1)
                pipe.zrange(FailedJobRegistry(queue=queue).key, 0, -1)
            for study_id in studies:
                pipe.lrange(results_key(self._queue.name, study_id), 0, -1)
            for trial in expected:
                pipe.hget(Job.key_for(trial), "status")
            replies = pipe.execute()
        listed = 5 * len(queues)
        ids: set[str] = set()
        for index, reply in enumerate(replies[:listed]):
            if index % 5 == 2:
                # Started entries are "<job id>:<execution id>"; trial ids contain no colon.
                ids.update(_text(entry).split(":", 1)[0] for entry in reply)
            else:
                ids.update(_text(job_id) for job_id in reply)
        for reply in replies[listed : listed + len(studies)]:
            ids.update(json.loads(envelope)["trial_id"] for envelope in reply)
        statuses = replies[listed + len(studies) :]
        now = time.monotonic()
        for trial, status in zip(expected, statuses, strict=True):  # others' trials keep their times
            if trial in ids or not (status and _text(status) in ACTIVE_STATES):
                self._between.pop(trial, None)
                continue
            self._between.setdefault(trial, now)
            if not self._left_between(trial, now):
                ids.add(trial)
        return ids

    def _left_between(self, trial: str, now: float | None = None) -> bool:
        """Whether the trial's job has been in no list for longer than ``BETWEEN_LISTS_S``: a
        worker died taking it, and it is lost (module docstring)."""
        since = self._between.get(trial)
        now = time.monotonic() if now is None else now
        return since is not None and now - since > BETWEEN_LISTS_S

    def cancel(self, trial_ids: Sequence[str]) -> None:
        """Remove queued jobs and ask workers to stop running ones (between two chunks of the
        simulation); outcomes of cancelled trials are never reported."""
        if not trial_ids:
            return
        self._cancelled.update(trial_ids)
        for trial in trial_ids:  # no longer expected: its time between lists would stay forever
            self._between.pop(trial, None)
        with self._redis.pipeline(transaction=False) as pipe:
            for trial in trial_ids:
                pipe.set(cancel_key(trial), 1, ex=CANCEL_TTL_S)
            pipe.execute()
        for job in Job.fetch_many(list(trial_ids), connection=self._redis, serializer=JSONSerializer):
            if job is not None and job.get_status(refresh=False) in (JobStatus.QUEUED, JobStatus.SCHEDULED):
                job.cancel()
        logger.info("cancelled %d trials", len(trial_ids))

    def close(self) -> None:
        self._redis.close()

    # -- beyond the protocol: what the service needs -----------------------------------------

    def watch(self, study_ids: Iterable[str]) -> None:
        """Take results of these studies from now on (a service that starts driving them)."""
        self._watched.update(study_ids)

    def unwatch(self, study_id: str) -> None:
        """Stop taking this study's results (it is finished, or another service drives it)."""
        self._watched.discard(study_id)

    @property
    def watched(self) -> frozenset[str]:
        return frozenset(self._watched)

    def maintain(self) -> None:
        """Move jobs whose worker stopped sending heartbeats (killed, machine lost) to a retry,
        or to the failed registry once retries are spent; ``poll`` then reports them. Under RQ's
        maintenance lock, as the workers clean their queues: a cleanup is not atomic, so two at
        once would both retry a dead worker's job and it would run twice; a queue a worker is
        cleaning now is left to it."""
        for queue in self._all_queues():
            if not queue.acquire_maintenance_lock():
                continue
            try:
                StartedJobRegistry(queue=queue).cleanup()
            finally:
                queue.release_maintenance_lock()

    def running(self) -> dict[str, str | None]:
        """Trial id -> name of the worker running it, for jobs a worker has started."""
        trial_ids = [
            job_id
            for queue in self._all_queues()
            for job_id, _ in StartedJobRegistry(queue=queue).get_job_and_execution_ids(cleanup=False)
        ]
        jobs = Job.fetch_many(trial_ids, connection=self._redis, serializer=JSONSerializer)
        return {job.id: job.worker_name for job in jobs if job is not None}

    def queue_depth(self) -> int:
        """Jobs waiting for a worker, on every engine's queue."""
        return sum(queue.count for queue in self._all_queues())

    def waiting(self) -> dict[str, str]:
        """Engine -> why its trials wait: no worker takes that engine's queue (checked on submit)."""
        return dict(self._waiting)

    # -- internals ---------------------------------------------------------------------------

    def _queue_of(self, engine: str) -> Queue:
        if engine not in self._queues:  # an engine this service does not know: its own queue
            self._queues[engine] = Queue(
                engine_queue_name(self._queue.name, engine), connection=self._redis, serializer=JSONSerializer
            )
        return self._queues[engine]

    def _all_queues(self) -> list[Queue]:
        unique = {queue.name: queue for queue in [self._queue, *self._queues.values()]}
        return list(unique.values())

    def _check_engines(self, engines: Iterable[str]) -> None:
        """Note engines whose queue no live worker takes: their trials wait, and say why. Every
        worker has the shared engines, so their queue is only as idle as the service's workers."""
        for engine in set(engines) - SHARED_ENGINES:
            queue = self._queue_of(engine)
            if Worker.count(queue=queue) > 0:
                self._waiting.pop(engine, None)
                continue
            message = (
                f"waiting for a worker with engine {engine!r}: no worker takes queue {queue.name!r} "
                f"(start `demcal worker` on a machine where {engine} is installed)"
            )
            if self._waiting.get(engine) != message:
                logger.warning("%s", message)
            self._waiting[engine] = message

    def _job_statuses(self, trial_ids: Sequence[str]) -> dict[str, str | None]:
        with self._redis.pipeline(transaction=False) as pipe:
            for trial in trial_ids:
                pipe.hget(Job.key_for(trial), "status")
            replies = pipe.execute()
        return {
            trial: (_text(status) if status else None)
            for trial, status in zip(trial_ids, replies, strict=True)
        }

    def _take_results(self, block: float = 0.0) -> list[TrialOutcome]:
        keys = [results_key(self._queue.name, study_id) for study_id in sorted(self._watched)]
        if block > 0:
            popped = self._redis.blpop(keys, timeout=block)
            envelopes = [popped[1]] if popped else []
            envelopes += self._pop_all(keys)
        else:
            envelopes = self._pop_all(keys)
        outcomes = []
        for raw in envelopes:
            envelope = json.loads(raw)
            outcomes.append(
                TrialOutcome(
                    trial_id=envelope["trial_id"],
                    result=SimulationResult.model_validate(envelope["result"]),
                    worker=envelope.get("worker"),
                    retries=max(int(envelope.get("attempt", 1)) - 1, 0),
                )
            )
        return outcomes

    def _pop_all(self, keys: Sequence[str]) -> list[bytes]:
        with self._redis.pipeline(transaction=False) as pipe:
            for key in keys:
                pipe.lpop(key, POP_BATCH)
            replies = pipe.execute()
        return [raw for reply in replies if reply for raw in reply]

    def _take_failed(self) -> list[TrialOutcome]:
        """Claim the watched studies' jobs that failed for good and turn them into error results."""
        outcomes = []
        for queue in self._all_queues():
            outcomes += self._take_failed_from(FailedJobRegistry(queue=queue))
        return outcomes

    def _take_failed_from(self, registry: FailedJobRegistry) -> list[TrialOutcome]:
        job_ids = [_text(job_id) for job_id in self._redis.zrange(registry.key, 0, -1)]
        if not job_ids:
            return []
        outcomes = []
        for job in Job.fetch_many(job_ids, connection=self._redis, serializer=JSONSerializer):
            if job is None or job.meta.get("study_id") not in self._watched:
                continue
            if not self._redis.zrem(registry.key, job.id):
                continue  # another service claimed it between our read and our ZREM
            outcomes.append(self._failure_outcome(job))
        return outcomes

    def _failure_outcome(self, job: Job) -> TrialOutcome:
        spec = job.args[0] if job.args else {}
        latest = job.latest_result()
        detail = latest.exc_string if latest is not None else None
        reason = (detail or "the job failed without a message").strip().splitlines()[-1]
        attempts = self._max_retries + 1 - (job.retries_left or 0)
        message = f"the worker failed {attempts} time(s); last error: {reason}"
        logger.warning("trial %s: %s", job.id, message)
        return TrialOutcome(
            trial_id=job.id,
            result=SimulationResult(
                status=SimulationStatus.ERROR,
                message=message,
                params=spec.get("params", {}),
                seed=spec.get("seed", 0),
            ),
            worker=job.worker_name,
            retries=attempts - 1,
        )
