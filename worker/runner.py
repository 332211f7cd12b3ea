"""The machinery of ``demcal worker``: an RQ worker configured for demcal's trials.

* RQ's ``SimpleWorker`` runs each trial in the worker process itself, not in a forked "work
  horse": the engine's numba kernels, compiled (or loaded from numba's on-disk cache) by the
  first trial, stay in memory for every later one, and a job costs no fork. A forking worker
  measured about 95 ms of queue overhead per job on our 2-core machine (``benchmarks/queue.py``),
  mostly the fork of a process holding numpy, numba and the engine, plus a reload of every
  compiled kernel per trial. What the fork would isolate (a crash inside a kernel) is covered
  anyway: the process dies, its heartbeats stop, the trial is retried on another worker and the
  supervisor (compose ``restart``) starts a new worker.
* Heartbeats: a thread refreshes the job's entry in RQ's started registry every
  ``heartbeat_s`` seconds while the trial runs (the kernels return to Python between chunks, so
  the thread gets its turn). The entry expires ``3 x heartbeat_s`` after the last refresh
  (``get_heartbeat_ttl``; RQ's own grace is 60 s), so the service notices a worker killed with
  SIGKILL, or a machine lost, within seconds and runs its trial again.
* Shutdown: the first SIGTERM or SIGINT is a *warm* shutdown: the worker takes no new job, lets
  the running trial finish and deliver its result, then exits 0. A trial can take minutes, so a
  supervisor must wait that long before it sends SIGKILL (compose: ``stop_grace_period``). A
  second signal is a cold shutdown: the running trial is killed and the service re-runs it.
* The job's argument carries the whole trial, so workers need only Redis: no database URL.

Must not: open the database or drive studies; that is ``demcal serve``'s job.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import uuid
from collections.abc import Sequence
from pathlib import Path

from redis import Redis
from rq import Queue, SimpleWorker
from rq.job import Job
from rq.serializers import JSONSerializer
from rq.worker import WorkerStatus

logger = logging.getLogger(__name__)

DEFAULT_HEARTBEAT_S = 10


class WorkerSetupError(RuntimeError):
    """The worker cannot start (no Redis URL, Redis unreachable); the message says what to fix."""


class DemcalWorker(SimpleWorker):
    """RQ's in-process worker, with heartbeats while a job runs and a short heartbeat grace."""

    def get_heartbeat_ttl(self, job: Job) -> int:
        return int(3 * self.job_monitoring_interval)

    def execute_job(self, job: Job, queue: Queue) -> None:
        self.prepare_execution(job)
        done = threading.Event()
        beating = threading.Thread(target=self._beat, args=(job, done), name="heartbeat", daemon=True)
        beating.start()
        try:
            self.perform_job(job, queue)
        finally:
            done.set()
            beating.join()
        self.set_state(WorkerStatus.IDLE)

    def _beat(self, job: Job, done: threading.Event) -> None:
        while not done.wait(self.job_monitoring_interval):
            try:
                self.maintain_heartbeats(job)
            except Exception as exc:  # Redis briefly away, or the job ended under our feet
                logger.warning("worker %s: heartbeat for %s failed: %s", self.name, job.id, exc)


def worker_name() -> str:
    """Unique per process and readable in logs and the dashboard: host, pid, a short random tag."""
    return f"{socket.gethostname()}.{os.getpid()}.{uuid.uuid4().hex[:6]}"


def connect(redis_url: str | None) -> Redis:
    """A Redis connection for the worker, or a WorkerSetupError saying what to set."""
    if not redis_url:
        raise WorkerSetupError(
            "DEMCAL_REDIS_URL is not set; a worker takes trials from a Redis queue "
            "(e.g. DEMCAL_REDIS_URL=redis://host:6379/0)"
        )
    connection = Redis.from_url(redis_url, socket_connect_timeout=5, health_check_interval=30)
    try:
        connection.ping()
    except Exception as exc:
        raise WorkerSetupError(f"cannot reach Redis at {redis_url} ({exc}); check DEMCAL_REDIS_URL") from exc
    return connection


def build_worker(
    connection: Redis,
    queue_names: Sequence[str],
    *,
    name: str | None = None,
    heartbeat_s: int = DEFAULT_HEARTBEAT_S,
) -> DemcalWorker:
    """A worker listening on ``queue_names`` in order of priority."""
    queues = [Queue(queue, connection=connection, serializer=JSONSerializer) for queue in queue_names]
    return DemcalWorker(
        queues,
        connection=connection,
        name=name or worker_name(),
        serializer=JSONSerializer,
        job_monitoring_interval=heartbeat_s,
    )


def preload() -> None:
    """Import the simulation stack before the first job, so that its start-up is not a trial's."""
    import dem.scenarios.feeder  # noqa: F401 - imported for its side effect: modules loaded
    import worker.jobs  # noqa: F401


def run_worker(
    redis_url: str | None,
    queue_names: Sequence[str],
    *,
    burst: bool = False,
    name: str | None = None,
    heartbeat_s: int = DEFAULT_HEARTBEAT_S,
    log_level: str = "INFO",
    snapshot_root: Path | None = None,
) -> bool:
    """Work until told to stop (or, with ``burst``, until the queues are empty).

    Returns True if at least one job was performed.
    """
    from worker import rq_job

    rq_job.SNAPSHOT_ROOT = snapshot_root
    connection = connect(redis_url)
    preload()
    worker = build_worker(connection, queue_names, name=name, heartbeat_s=heartbeat_s)
    logger.info(
        "worker %s: listening on %s at %s (heartbeat %d s%s)",
        worker.name,
        ", ".join(queue_names),
        connection.connection_pool.connection_kwargs.get("host", redis_url),
        heartbeat_s,
        ", burst" if burst else "",
    )
    worked = worker.work(burst=burst, logging_level=log_level, with_scheduler=False)
    logger.info("worker %s: stopped", worker.name)
    return worked
