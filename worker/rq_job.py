"""What an RQ worker runs for one trial, and the Redis list through which the result travels back.

The job's only argument is the whole ``TrialSpec`` as a JSON-able dict (scenario, parameters,
seed), so a worker needs Redis and nothing else: no database, no shared disk. The simulation
itself is ``worker.jobs.run_trial``; this module wraps it for RQ:

* a simulation that ends ``unstable``, ``timeout`` or ``error`` is a *result* like ``ok``: it is
  delivered and the job succeeds, so RQ never retries physics;
* only an exception escaping ``run_trial`` (a lost connection, memory exhausted, a bug) fails the
  job, and RQ retries it the bounded number of times the executor asked for;
* Redis going away mid-trial (a restart) is infrastructure, never a result: the cancellation
  check carries on, and delivery waits for Redis with backoff (``DELIVERY_PATIENCE_S``);
* a cancelled trial (``RqExecutor.cancel`` sets its cancel key) stops between two chunks of the
  simulation and delivers a ``cancelled`` result, which the executor never reports;
* the result is pushed onto the study's result list (``results_key``); the service's
  ``RqExecutor`` pops it, and a pop is atomic, so each pushed result is taken exactly once. A
  trial that ran twice (a worker presumed dead that was only slow) pushes twice; the store keeps
  the first and ignores the second.

Must not: open the database, import ``api``, or decide anything about a study.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import redis
from rq import get_current_job
from rq.job import Job

from dem.scenarios import registry

logger = logging.getLogger(__name__)

# A result list nobody pops (its study was deleted while trials ran) must not stay in Redis for
# ever; a week is far longer than any service outage we expect to ride out.
RESULT_LIST_TTL_S = 7 * 24 * 3600
# How long a finished trial waits for Redis to come back before its job fails (and is retried).
DELIVERY_PATIENCE_S = 600.0
# Redis away (restarting, network cut): infrastructure, never a trial's result.
REDIS_OUTAGE = (redis.exceptions.ConnectionError, redis.exceptions.TimeoutError)


def results_key(queue_name: str, study_id: str) -> str:
    """The Redis list holding finished results of one study's trials on one queue."""
    return f"demcal:results:{queue_name}:{study_id}"


def cancel_key(trial_id: str) -> str:
    """Set by the executor to ask the worker running this trial to stop it."""
    return f"demcal:cancel:{trial_id}"


class CancellationCheck:
    """``should_stop`` for the simulation: True once the trial's cancel key exists. Redis is
    asked at most every ``every_s`` seconds, the simulation calls it between every two chunks."""

    def __init__(self, job: Job, trial_id: str, every_s: float = 1.0) -> None:
        self._redis = job.connection
        self._key = cancel_key(trial_id)
        self._every_s = every_s
        self._next = 0.0
        self._stopped = False

    def __call__(self) -> bool:
        now = time.monotonic()
        if not self._stopped and now >= self._next:
            self._next = now + self._every_s
            try:
                self._stopped = bool(self._redis.exists(self._key))
            except REDIS_OUTAGE as exc:  # Redis restarting: go on, ask again at the next check
                logger.warning("cancellation check: Redis unavailable (%s); the trial goes on", exc)
        return self._stopped


class ProgressLog:
    """``progress`` for the simulation: one log line per ``every_s`` seconds of wall time, so an
    operator following a worker's log sees a long trial advance without a line per chunk."""

    def __init__(self, trial_id: str, end_s: float | None, every_s: float = 10.0) -> None:
        self._trial_id = trial_id
        self._end = f" of {end_s:g} s" if end_s else ""
        self._every_s = every_s
        self._next = time.monotonic() + every_s

    def __call__(self, sim_time: float, items_left: int) -> None:
        now = time.monotonic()
        if now >= self._next:
            self._next = now + self._every_s
            logger.info(
                "trial %s: t = %.2f s%s simulated, %d items left",
                self._trial_id,
                sim_time,
                self._end,
                items_left,
            )


def deliver(
    job: Job, spec: dict[str, Any], result: dict[str, Any], patience_s: float = DELIVERY_PATIENCE_S
) -> None:
    """Push one finished trial's result where the executor will take it; while Redis is away
    (restarting), retry with exponential backoff for up to ``patience_s`` rather than lose a
    finished trial (after that the error escapes, the job fails and is retried)."""
    envelope = json.dumps(
        {
            "trial_id": spec["trial_id"],
            "study_id": spec["study_id"],
            "worker": job.worker_name,
            "attempt": attempt(job),
            "result": result,
        }
    )
    # An engine's own queue delivers to the base queue's list, which the service reads.
    key = results_key(job.meta.get("results_queue") or job.origin, spec["study_id"])
    wait, give_up = 0.5, time.monotonic() + patience_s
    while True:
        try:
            with job.connection.pipeline() as pipe:
                pipe.rpush(key, envelope)
                pipe.expire(key, RESULT_LIST_TTL_S)
                pipe.execute()
            return
        except REDIS_OUTAGE as exc:
            if time.monotonic() + wait > give_up:
                raise
            logger.warning(
                "trial %s: cannot deliver the result (%s); retrying in %.1f s", spec["trial_id"], exc, wait
            )
            time.sleep(wait)
            wait = min(2 * wait, 30.0)


def attempt(job: Job) -> int:
    """1 for the first run of a job, 2 for its first retry, and so on."""
    retries = int(job.meta.get("max_retries", 0))
    left = job.retries_left if job.retries_left is not None else retries
    return retries - left + 1


# Where this worker process keeps snapshots of trials that ask for them, and where it finds the
# meshes a scenario names (set by ``run_worker`` from the worker's data dir; None: none kept, and
# relative mesh paths are taken from the working directory).
SNAPSHOT_ROOT: Path | None = None
DATA_DIR: Path | None = None


def perform_trial(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one trial on this worker and deliver its result; returns the SimulationResult JSON."""
    from worker.jobs import run_trial

    job = get_current_job()
    if job is None:
        raise RuntimeError("perform_trial runs inside an RQ job; call worker.jobs.run_trial directly")
    params = ", ".join(f"{name}={value:.4g}" for name, value in spec["params"].items())
    logger.info(
        "trial %s: started (generation %s, %s, seed %s, attempt %d)",
        spec["trial_id"],
        spec.get("generation"),
        params,
        spec["seed"],
        attempt(job),
    )
    started = time.perf_counter()
    try:
        scenario = registry.for_config(spec["scenario"])
        end = scenario.duration(spec["scenario"])
    except Exception:  # an invalid config fails inside run_trial with a message
        scenario, end = None, None
    result = run_trial(
        spec,
        should_stop=CancellationCheck(job, spec["trial_id"]),
        progress=ProgressLog(spec["trial_id"], end),
        snapshot_root=SNAPSHOT_ROOT,
        data_dir=DATA_DIR,
    )
    deliver(job, spec, result)
    logger.info(
        "trial %s: %s, %s, %.1f s wall%s",
        spec["trial_id"],
        result.get("status"),
        scenario.describe(result.get("responses") or {}, spec["scenario"]) if scenario else "-",
        time.perf_counter() - started,
        f" ({result['message']})" if result.get("message") else "",
    )
    return result
