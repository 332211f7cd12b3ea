"""The machinery of ``demcal worker``: an RQ worker configured for demcal's trials.

* RQ's forking ``Worker``: each trial runs in a child process (a "work horse"), so a crash in a
  numba kernel or a memory blow-up fails that one job, which RQ then retries; the worker lives
  on. The heavy modules (numpy, numba, the engine) are imported once in the parent before the
  first fork, so a horse starts with them loaded; numba's on-disk cache (``cache=True``) spares it
  the compilation.
* Heartbeats: while a horse runs, the parent refreshes the job's entry in RQ's started registry
  every ``heartbeat_s`` seconds. The entry expires ``heartbeat_s + grace`` seconds after the last
  refresh (``get_heartbeat_ttl``); RQ's default grace is 60 s, ours is ``2 x heartbeat_s`` so
  that the service notices a worker killed with SIGKILL (or a machine lost) within about half
  a minute and re-runs its trial.
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
import uuid
from collections.abc import Sequence

from redis import Redis
from rq import Queue, Worker
from rq.job import Job
from rq.serializers import JSONSerializer

logger = logging.getLogger(__name__)

DEFAULT_HEARTBEAT_S = 10


class WorkerSetupError(RuntimeError):
    """The worker cannot start (no Redis URL, Redis unreachable); the message says what to fix."""


class DemcalWorker(Worker):
    """RQ's forking worker, whose jobs count as abandoned soon after its heartbeats stop."""

    def get_heartbeat_ttl(self, job: Job) -> int:
        interval = self.job_monitoring_interval
        if job.timeout and job.timeout > 0:
            interval = min(interval, max(1, job.timeout - self.current_job_working_time))
        return int(interval + 2 * self.job_monitoring_interval)


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
    """Import the simulation stack once in the parent, so that every forked horse has it."""
    import worker.jobs  # noqa: F401 - imported for its side effect: modules loaded before fork
    import worker.rq_job  # noqa: F401


def run_worker(
    redis_url: str | None,
    queue_names: Sequence[str],
    *,
    burst: bool = False,
    name: str | None = None,
    heartbeat_s: int = DEFAULT_HEARTBEAT_S,
    log_level: str = "INFO",
) -> bool:
    """Work until told to stop (or, with ``burst``, until the queues are empty).

    Returns True if at least one job was performed.
    """
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
