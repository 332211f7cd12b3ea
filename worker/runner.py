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
* Redis restarts: RQ's own dequeue loop waits for Redis, but an error anywhere else (the
  suspension check, bookkeeping after a job) makes it quit. ``run_worker`` then waits for Redis
  with backoff and works again under a derived name; the running trial's cancellation check and
  result delivery ride the outage out (``worker/rq_job.py``).
* Shutdown: the first SIGTERM or SIGINT is a *warm* shutdown: the worker takes no new job, lets
  the running trial finish and deliver its result, then exits 0. A trial can take minutes, so a
  supervisor must wait that long before it sends SIGKILL (compose: ``stop_grace_period``). A
  second signal is a cold shutdown: the running trial is killed, the service re-runs it, and
  the worker exits ``COLD_STOP_EXIT_CODE`` (non-zero: a supervisor learns a trial was abandoned).
  RQ stops the trial by raising ``SystemExit`` from the signal handler, wherever the trial is;
  RQ's ``perform_job`` itself catches it (a bare ``except``: the job is failed, and retried) and
  then leaves its loop normally, so the worker remembers the cold stop (``cold_stopped``) to
  exit with the right code. A library that swallows the ``SystemExit`` (trimesh imports its
  optional parts under ``except BaseException``, and a trial's first clump imports them) would
  let the trial run on, so the process also ends itself, with the same code,
  ``COLD_STOP_GRACE_S`` after a cold shutdown that has not unwound by then.
* The job's argument carries the whole trial, so workers need only Redis: no database URL.

Must not: open the database or drive studies; that is ``demcal serve``'s job.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Sequence
from pathlib import Path

from redis import Redis
from rq import Queue, SimpleWorker
from rq.job import Job
from rq.serializers import JSONSerializer
from rq.worker import WorkerStatus

from worker.priority import DEFAULT_NICE, lower_priority
from worker.rq_job import REDIS_OUTAGE

logger = logging.getLogger(__name__)

DEFAULT_HEARTBEAT_S = 10
# A cold shutdown unwinds in milliseconds (RQ marks the job failed, then the worker exits); past
# this, the SystemExit was swallowed and the process ends without further ado.
COLD_STOP_GRACE_S = 2.0
COLD_STOP_EXIT_CODE = 1


class WorkerSetupError(RuntimeError):
    """The worker cannot start (no Redis URL, Redis unreachable); the message says what to fix."""


class ColdStop(RuntimeError):
    """A second SIGTERM/SIGINT stopped the worker mid-trial; the trial was abandoned (and re-queued)."""


class DemcalWorker(SimpleWorker):
    """RQ's in-process worker, with heartbeats while a job runs and a short heartbeat grace."""

    stop_asked = False  # a SIGTERM/SIGINT arrived: the end of the work is wanted, not an outage
    cold_stopped = False  # a second signal abandoned the running trial
    jobs_done = 0  # trials performed by this incarnation (RQ keeps its counts only in Redis)

    def request_stop(self, signum, frame) -> None:
        self.stop_asked = True
        super().request_stop(signum, frame)

    def get_heartbeat_ttl(self, job: Job) -> int:
        return int(3 * self.job_monitoring_interval)

    def request_force_stop(self, signum, frame) -> None:
        try:
            super().request_force_stop(signum, frame)  # raises SystemExit unless a duplicate signal
        except SystemExit:
            self.cold_stopped = True
            backstop = threading.Timer(COLD_STOP_GRACE_S, _exit_now, args=(self.name,))
            backstop.daemon = True
            backstop.start()
            raise

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
            self.jobs_done += 1
        self.set_state(WorkerStatus.IDLE)

    def _beat(self, job: Job, done: threading.Event) -> None:
        while not done.wait(self.job_monitoring_interval):
            try:
                self.maintain_heartbeats(job)
            except Exception as exc:  # Redis briefly away, or the job ended under our feet
                logger.warning("worker %s: heartbeat for %s failed: %s", self.name, job.id, exc)


def _exit_now(name: str) -> None:
    logger.warning("worker %s: cold shutdown not unwound after %g s; exiting now", name, COLD_STOP_GRACE_S)
    logging.shutdown()
    os._exit(COLD_STOP_EXIT_CODE)


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
    """Import the simulation stack (every built-in scenario) and warm its kernels before the first
    job, so that neither start-up nor the compile is part of a trial's T (``worker/warmup.py``)."""
    import worker.jobs  # noqa: F401 - imported for its side effect: modules loaded
    from dem.scenarios import registry
    from worker.warmup import warm_up

    registry.kinds()  # imports every built-in scenario module
    warm_up()


def run_worker(
    redis_url: str | None,
    queue_names: Sequence[str],
    *,
    burst: bool = False,
    max_jobs: int | None = None,
    name: str | None = None,
    heartbeat_s: int = DEFAULT_HEARTBEAT_S,
    log_level: str = "INFO",
    snapshot_root: Path | None = None,
    data_dir: Path | None = None,
    nice: int = DEFAULT_NICE,
) -> bool:
    """Work until told to stop (or, with ``burst``, until the queues are empty; with
    ``max_jobs``, after that many trials, counted across restarts after a Redis outage).

    Returns True if at least one job was performed; raises ``ColdStop`` after a cold shutdown.
    The process's priority is lowered by ``nice`` first (``worker/priority.py``).
    """
    from worker import rq_job

    lower_priority(nice)

    rq_job.SNAPSHOT_ROOT = snapshot_root
    rq_job.DATA_DIR = data_dir
    connection = connect(redis_url)
    preload()
    base_name = name or worker_name()
    worked, incarnation, done = False, 0, 0
    while True:
        # After an outage the worker comes back under a new name: RQ refuses to register a name
        # whose previous registration it may still hold.
        current = base_name if incarnation == 0 else f"{base_name}.{incarnation}"
        worker = build_worker(connection, queue_names, name=current, heartbeat_s=heartbeat_s)
        logger.info(
            "worker %s: listening on %s at %s (heartbeat %d s%s)",
            worker.name,
            ", ".join(queue_names),
            connection.connection_pool.connection_kwargs.get("host", redis_url),
            heartbeat_s,
            ", burst" if burst else "",
        )
        try:
            left = None if max_jobs is None else max_jobs - done
            worked = worker.work(
                burst=burst, max_jobs=left, logging_level=log_level, with_scheduler=False
            ) or worked
        except REDIS_OUTAGE as exc:  # raised from RQ's own start-up or tear-down
            logger.warning("worker %s: Redis unavailable (%s)", worker.name, exc)
        done += worker.jobs_done
        if worker.cold_stopped:
            raise ColdStop(f"worker {worker.name}: cold shutdown; its running trial was abandoned")
        if burst or worker.stop_asked or (max_jobs is not None and done >= max_jobs):
            logger.info("worker %s: stopped", worker.name)
            return worked
        # Not asked to stop: RQ quit on an error, in practice Redis going away outside its
        # dequeue loop (a restart). Wait for Redis with backoff and work again, so that a Redis
        # restart never needs an operator.
        logger.warning("worker %s: RQ stopped without being asked to; restarting it", worker.name)
        time.sleep(1.0)
        wait_for_redis(connection, worker.name)
        incarnation += 1


def redis_is_up(connection: Redis) -> bool:
    try:
        return bool(connection.ping())
    except REDIS_OUTAGE:
        return False


def wait_for_redis(connection: Redis, name: str, first_s: float = 0.5, longest_s: float = 30.0) -> None:
    """Block until Redis answers, retrying with exponential backoff (logged)."""
    wait = first_s
    while not redis_is_up(connection):
        logger.warning("worker %s: Redis unavailable; retrying in %.1f s", name, wait)
        time.sleep(wait)
        wait = min(2 * wait, longest_s)
    logger.info("worker %s: Redis is back; working again", name)
