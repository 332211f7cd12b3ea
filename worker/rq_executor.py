"""The optimiser's Executor on an RQ queue: trials become jobs that ``demcal worker`` processes on
any machine run, and their results come back through Redis.

Decisions, and why:

* **One round trip per generation.** ``submit`` first reads the status of every job in one
  pipeline (a trial already queued or running is left alone, so re-submitting is a no-op), then
  enqueues all new jobs with ``Queue.enqueue_many`` on one pipeline.
* **Job id = trial id** (``optimizer.protocols.trial_id``: study, individual, replicate), so a
  re-submitted trial is the same job, and RQ's registries speak in trial ids.
* **Job timeout** (RQ's hard kill) comes from the spec's own deadline when it has one, otherwise
  from the scenario's simulated duration and an estimate of its time step (``job_timeout``).
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

Must not: touch the database or decide a trial's state; the driver and the store do that.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from typing import Any

from redis import Redis
from rq import Queue, Retry
from rq.job import Job, JobStatus
from rq.registry import FailedJobRegistry, StartedJobRegistry
from rq.serializers import JSONSerializer

from dem.result import SimulationResult, SimulationStatus
from optimizer.protocols import TrialOutcome, TrialSpec
from worker.jobs import longest_first
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


class RedisQueueError(RuntimeError):
    """Redis cannot be reached or refused the queue's commands; the message says which URL."""


def estimated_time_step(scenario: dict[str, Any], params: dict[str, float]) -> float:
    """A rough time step for a feeder-like scenario: a fraction of the contact period of a
    sphere of the smallest item's size, from E (``T_c = pi sqrt(m / K)``, ``K = E D / 2``).

    Only used to size the job timeout, so it errs on the small side (more steps, longer timeout).
    """
    run = scenario.get("run", {}) or {}
    if run.get("dt"):
        return float(run["dt"])
    fraction = float(run.get("dt_fraction", 0.05))
    young = float(params.get("E", (scenario.get("params") or {}).get("E", 1e7)))
    # A 10 mm steel-density sphere: smaller and denser than any item of the feeder's set, so the
    # estimated step is shorter than the engine's and the timeout longer.
    diameter, density = 0.01, 8000.0
    mass = density * math.pi * diameter**3 / 6
    stiffness = young * diameter / 2
    return fraction * math.pi * math.sqrt(mass / stiffness)


def job_timeout(spec: TrialSpec) -> int:
    """Seconds after which RQ kills the job: the spec's deadline with a margin, or an estimate
    from simulated duration x steps per second x items, bounded by a floor and a ceiling."""
    if spec.timeout_s:
        seconds = spec.timeout_s * DEADLINE_MARGIN + DEADLINE_GRACE_S
    else:
        stages = spec.scenario.get("stages", {}) or {}
        duration = float(stages.get("vibration_start", 5.0)) + float(stages.get("vibration_time", 60.0))
        counts = (spec.scenario.get("items", {}) or {}).get("counts") or {"items": 30}
        n_items = max(1, sum(int(count) for count in counts.values()))
        steps = duration / estimated_time_step(spec.scenario, spec.params)
        seconds = TIMEOUT_SAFETY * steps * n_items * STEP_COST_PER_ITEM_S
    return int(min(MAX_JOB_TIMEOUT_S, max(MIN_JOB_TIMEOUT_S, seconds)))


def spec_to_payload(spec: TrialSpec) -> dict[str, Any]:
    """The job's argument: the whole spec, JSON-able, so the worker needs nothing else."""
    return asdict(spec)


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
    ) -> None:
        self._redis = connection
        self._queue = Queue(queue_name, connection=connection, serializer=JSONSerializer)
        self._job_function = job_function
        self._max_retries = max_retries
        self._watched: set[str] = set()
        # Trials reported since they were last submitted: a late duplicate result is dropped.
        self._reported: set[str] = set()
        self._cancelled: set[str] = set()

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
            [spec for spec in specs if statuses.get(spec.trial_id) not in ACTIVE_STATES]
        )
        if not fresh:
            return
        failed = FailedJobRegistry(queue=self._queue)
        jobs = [
            Queue.prepare_data(
                self._job_function,
                args=(spec_to_payload(spec),),
                job_id=spec.trial_id,
                timeout=job_timeout(spec),
                result_ttl=RESULT_TTL_S,
                failure_ttl=FAILURE_TTL_S,
                description=f"demcal trial {spec.trial_id}",
                meta={"study_id": spec.study_id, "max_retries": self._max_retries},
                retry=Retry(max=self._max_retries) if self._max_retries else None,
            )
            for spec in fresh
        ]
        with self._redis.pipeline() as pipe:
            # A trial submitted again after it failed must not be reported failed again by poll.
            pipe.zrem(failed.key, *[spec.trial_id for spec in fresh])
            pipe.delete(*[cancel_key(spec.trial_id) for spec in fresh])
            self._queue.enqueue_many(jobs, pipeline=pipe)
            pipe.execute()
        for spec in fresh:
            self._reported.discard(spec.trial_id)
            self._cancelled.discard(spec.trial_id)
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

    def in_flight(self) -> set[str]:
        """Trial ids Redis still holds as work to do or a result to take (one atomic snapshot)."""
        queue = self._queue
        with self._redis.pipeline(transaction=True) as pipe:
            pipe.lrange(queue.key, 0, -1)
            pipe.lrange(queue.intermediate_queue_key, 0, -1)
            pipe.zrange(StartedJobRegistry(queue=queue).key, 0, -1)
            pipe.zrange(queue.scheduled_job_registry.key, 0, -1)
            pipe.zrange(FailedJobRegistry(queue=queue).key, 0, -1)
            for study_id in sorted(self._watched):
                pipe.lrange(results_key(queue.name, study_id), 0, -1)
            replies = pipe.execute()
        ids: set[str] = set()
        for reply in replies[:2]:
            ids.update(_text(job_id) for job_id in reply)
        # Started entries are "<job id>:<execution id>"; trial ids contain no colon.
        ids.update(_text(entry).split(":", 1)[0] for entry in replies[2])
        for reply in replies[3:5]:
            ids.update(_text(job_id) for job_id in reply)
        for reply in replies[5:]:
            ids.update(json.loads(envelope)["trial_id"] for envelope in reply)
        return ids

    def cancel(self, trial_ids: Sequence[str]) -> None:
        """Remove queued jobs and ask workers to stop running ones (between two chunks of the
        simulation); outcomes of cancelled trials are never reported."""
        if not trial_ids:
            return
        self._cancelled.update(trial_ids)
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
        or to the failed registry once retries are spent; ``poll`` then reports them."""
        StartedJobRegistry(queue=self._queue).cleanup()

    def running(self) -> dict[str, str | None]:
        """Trial id -> name of the worker running it, for jobs a worker has started."""
        registry = StartedJobRegistry(queue=self._queue)
        trial_ids = [job_id for job_id, _ in registry.get_job_and_execution_ids(cleanup=False)]
        jobs = Job.fetch_many(trial_ids, connection=self._redis, serializer=JSONSerializer)
        return {job.id: job.worker_name for job in jobs if job is not None}

    def queue_depth(self) -> int:
        """Jobs waiting for a worker."""
        return self._queue.count

    # -- internals ---------------------------------------------------------------------------

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
        registry = FailedJobRegistry(queue=self._queue)
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
        )
