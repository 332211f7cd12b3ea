"""The driver loop, the background thread of ``demcal serve``: it advances every running study
and runs every pending single simulation through the executor, and keeps the database and the
queue in step. (Not to be confused with ``api/services/``, the request services of the API.)

* **One driver per study, whatever the number of replicas or CLI runs.** A study is advanced
  only by the process holding its lease in the database (``api/store/leases.py``, the same lease
  ``demcal calibrate`` takes), renewed a few times per TTL and released when the study ends or
  the process stops; a process that dies loses its studies to a ``serve`` replica within
  ``DEMCAL_LEASE_TTL_S``.
* **Reconciliation**, on start and periodically (``reconcile_every_s``): the driver re-submits
  trials the database holds as queued or running but the executor does not know (a flushed or
  restarted Redis, a restarted process with a local pool); this loop also lets the executor move
  jobs of dead workers out of its started registry (they are retried, or reported as errors) and
  re-submits lost single simulations. The database is the truth; nothing is lost, and a result
  that arrives twice is recorded once (the store ignores the second).
* **Single simulations** share the executor with trials; their outcomes are told apart by their
  id (``api/store/simulations.is_simulation_id``, no query) and recorded with
  ``record_simulation_result``.

Must not: serve HTTP or know the GA; it only composes the driver, the store and an executor.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Collection, Sequence
from typing import Any

import redis
import sqlalchemy as sa

from api.errors import NotFoundError
from api.settings import Settings
from api.store import SqlStore
from api.store.leases import DatabaseLeases
from api.store.simulations import is_simulation_id
from optimizer.driver import Driver
from optimizer.protocols import (
    ACTIVE_STUDIES,
    STOPPING_STUDIES,
    Executor,
    StudyStatus,
    TrialOutcome,
    TrialSpec,
)

logger = logging.getLogger(__name__)

# Errors of the database or Redis themselves: they end the tick (retried later), never a study.
INFRASTRUCTURE_ERRORS = (
    sa.exc.OperationalError,
    sa.exc.InterfaceError,
    sa.exc.TimeoutError,
    redis.exceptions.ConnectionError,
    redis.exceptions.TimeoutError,
    ConnectionError,
    TimeoutError,
)


class RunningMarks:
    """Shows which trials and single simulations a worker has started (queued -> running, with
    its worker), for ``serve``'s loop and ``demcal calibrate`` alike. Each (trial, worker) is
    written once, not at every poll: a write takes the study row's lock, and a hundred workers
    would otherwise cost a hundred writes a second. A trial that a retry starts on another
    worker, or on the same one after it left the executor's view, is written again."""

    def __init__(self) -> None:
        self._marked: set[tuple[str, str | None]] = set()

    def update(self, store: SqlStore, executor: Any) -> None:
        running = getattr(executor, "running", None)
        if running is None:
            return
        now = set(running().items())
        for trial_id, worker in sorted(now - self._marked, key=lambda pair: pair[0]):
            if is_simulation_id(trial_id):
                store.mark_simulation_running(trial_id, worker)
            else:
                store.mark_running(trial_id, worker)
        self._marked = now


class _Routed:
    """The executor as the driver sees it: outcomes of single simulations are kept aside for
    the service, so that the driver (which records whatever it polls as trials) never sees them."""

    def __init__(self, executor: Executor) -> None:
        self.executor = executor
        self.simulation_outcomes: list[TrialOutcome] = []

    def submit(self, specs: Sequence[TrialSpec]) -> None:
        self.executor.submit(specs)

    def poll(self, timeout: float = 0.0) -> list[TrialOutcome]:
        trials = []
        for outcome in self.executor.poll(timeout):
            if is_simulation_id(outcome.trial_id):
                self.simulation_outcomes.append(outcome)
            else:
                trials.append(outcome)
        return trials

    def in_flight(self, expected: Collection[str] = ()) -> set[str]:
        return self.executor.in_flight(expected)

    def waiting(self) -> dict[str, str]:
        """Why trials of an engine wait (no worker has it), for the driver to store with them."""
        return getattr(self.executor, "waiting", dict)()

    def cancel(self, trial_ids: Sequence[str]) -> None:
        self.executor.cancel(trial_ids)

    def close(self) -> None:
        self.executor.close()


class DriverLoop:
    """Advances studies and single simulations in a background thread; see the module docstring."""

    def __init__(
        self,
        store: SqlStore,
        executor: Executor,
        leases: DatabaseLeases,
        *,
        poll_s: float = 0.5,
        scan_every_s: float = 5.0,
        reconcile_every_s: float = 30.0,
    ) -> None:
        self.store = store
        self.executor = executor
        self.leases = leases
        self.poll_s = poll_s
        self.scan_every_s = scan_every_s
        self.reconcile_every_s = reconcile_every_s
        self._routed = _Routed(executor)
        self.driver = Driver(store, self._routed, reconcile_every_s=reconcile_every_s)
        self.held: set[str] = set()
        self._last_scan = -float("inf")
        self._last_reconcile = -float("inf")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # The heartbeat renews leases on its own thread, so that a long step (a surrogate fit, a
        # validation batch, a CPU-starved machine) never lets a lease lapse while we drive the
        # study. The lock keeps ``held`` and the leases in step between the two threads.
        self._lease_lock = threading.Lock()
        self._running_marks = RunningMarks()
        self._lost: set[str] = set()
        self._heartbeat: threading.Thread | None = None

    # -- life cycle ---------------------------------------------------------------------------

    def start(self) -> None:
        self._thread = threading.Thread(target=self.run, name="demcal-driver-loop", daemon=True)
        self._thread.start()
        self._heartbeat = threading.Thread(target=self._beat, name="demcal-lease-heartbeat", daemon=True)
        self._heartbeat.start()

    def stop(self, timeout: float = 30.0) -> None:
        """Finish the current tick, release the leases and close the executor."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._heartbeat is not None:
            self._heartbeat.join(timeout)
        for study_id in list(self.held):
            self._drop(study_id)
        self.executor.close()

    def run(self) -> None:
        logger.info("service %s: driving studies", self.leases.owner)
        while not self._stop.is_set():
            try:
                self.tick()
            except Exception:  # a database or Redis outage must not end the loop; retry later
                logger.exception("service: tick failed; retrying in %.0f s", self.scan_every_s)
                self._stop.wait(self.scan_every_s)

    # -- one pass -----------------------------------------------------------------------------

    def tick(self) -> None:
        """Bounded work: lease bookkeeping, one step per held study, single simulations."""
        now = time.monotonic()
        if now - self._last_scan >= self.scan_every_s:
            self._last_scan = now
            self._scan()
        self._forget_lost()
        if now - self._last_reconcile >= self.reconcile_every_s:
            self._last_reconcile = now
            self._reconcile_simulations()
        self._submit_simulations()
        self._mark_running()
        if self.held:
            share = self.poll_s / len(self.held)
            for study_id in sorted(self.held):
                self._step(study_id, share)
        else:
            self._routed.simulation_outcomes.extend(self._routed.poll(self.poll_s))
        self._record_simulations()

    def _step(self, study_id: str, timeout: float) -> None:
        """One step of one study, isolated: whatever goes wrong with this study (a definition it
        cannot compute with, a bug) fails this study with its message and withdraws its work;
        the other studies go on. Only an outage of the database or Redis ends the tick."""
        try:
            progress = self.driver.step(study_id, timeout=timeout)
        except NotFoundError:
            logger.info("study %s: deleted; withdrawing its work", study_id)
            self.driver.withdraw(study_id)
            self._drop(study_id)
            return
        except INFRASTRUCTURE_ERRORS:
            raise
        except Exception as exc:
            logger.exception("study %s: the driver failed on it; failing this study only", study_id)
            message = f"the driver failed on this study: {type(exc).__name__}: {exc}"
            self.store.set_status(study_id, StudyStatus.FAILED, message[:2000])
            self.driver.withdraw(study_id)
            self._drop(study_id)
            return
        if not progress.active:
            logger.info("study %s: %s; releasing it", study_id, progress.status)
            if progress.status is not StudyStatus.DONE:
                self.driver.withdraw(study_id)
            self._drop(study_id)

    def _scan(self) -> None:
        """Take leases of active studies nobody drives; let go of studies that stopped."""
        maintain = getattr(self.executor, "maintain", None)
        if maintain is not None:
            maintain()
        active = set(self.store.studies_in(ACTIVE_STUDIES))
        stopping = set(self.store.studies_in(STOPPING_STUDIES))
        for study_id in sorted(active - self.held):
            with self._lease_lock:
                taken = self.leases.acquire(study_id)
                if taken:
                    self.held.add(study_id)
            if taken:
                logger.info("study %s: now driven by %s", study_id, self.leases.owner)
                self._watch(study_id)
        for study_id in sorted(stopping & self.held):
            self._step(study_id, 0)  # withdraws its queued and running trials
        for study_id in sorted(self.held - active - stopping):
            self._step(study_id, 0)  # deleted, or finished by another process

    def _mark_running(self) -> None:
        self._running_marks.update(self.store, self.executor)

    def _beat(self) -> None:
        """The heartbeat thread: renew every held lease a few times per TTL."""
        while not self._stop.wait(self.leases.renew_every_s):
            try:
                self.renew_leases()
            except Exception:  # an outage: the next beat retries, the loop reports it too
                logger.exception("service: renewing leases failed; retrying")

    def renew_leases(self) -> None:
        """Extend our leases; a lease another process holds now is lost, and the loop thread
        stops driving that study at its next tick."""
        with self._lease_lock:
            for study_id in sorted(self.held):
                if not self.leases.renew(study_id):
                    logger.warning("study %s: lease lost to another service; no longer driving it", study_id)
                    self.held.discard(study_id)
                    self._lost.add(study_id)

    def _forget_lost(self) -> None:
        with self._lease_lock:
            lost, self._lost = self._lost, set()
        for study_id in sorted(lost):
            self._unwatch(study_id)

    def _drop(self, study_id: str) -> None:
        with self._lease_lock:
            self.held.discard(study_id)
            self.leases.release(study_id)
        self._unwatch(study_id)

    def _watch(self, study_id: str) -> None:
        watch = getattr(self.executor, "watch", None)
        if watch is not None:
            watch([study_id])

    def _unwatch(self, study_id: str) -> None:
        unwatch = getattr(self.executor, "unwatch", None)
        if unwatch is not None:
            unwatch(study_id)

    # -- single simulations -------------------------------------------------------------------

    def _submit_simulations(self) -> None:
        specs = [
            spec
            for spec in self.store.pending_simulations()
            if self.store.mark_simulation_queued(spec.trial_id)
        ]
        if specs:
            self._watch("")  # single simulations are the study-less specs
            self.executor.submit(specs)
            logger.info("queued %d single simulations", len(specs))

    def _record_simulations(self) -> None:
        outcomes, self._routed.simulation_outcomes = self._routed.simulation_outcomes, []
        for outcome in outcomes:
            self.store.record_simulation_result(outcome.trial_id, outcome.result, outcome.worker)

    def _reconcile_simulations(self) -> None:
        """Simulations the database has in flight but the executor lost go back to pending."""
        in_db = self.store.in_flight_simulations()
        if not in_db:
            return
        self._watch("")
        lost = sorted(set(in_db) - self.executor.in_flight(in_db))
        if lost:
            logger.info("re-submitting %d single simulations the executor does not know", len(lost))
            self.store.requeue_simulations(lost)


def build_executor(settings: Settings) -> Any:
    """The RQ executor when ``DEMCAL_REDIS_URL`` is set, else the local process pool."""
    if settings.redis_url:
        from worker.rq_executor import RqExecutor

        return RqExecutor.from_url(settings.redis_url, settings.queue_name, data_dir=settings.data_dir)
    from worker.local import LocalPoolExecutor

    return LocalPoolExecutor(
        workers=settings.workers, snapshot_root=settings.snapshot_root, data_dir=settings.data_dir,
        nice=settings.worker_nice,
    )


def build_driver_loop(settings: Settings, store: SqlStore, **options: Any) -> DriverLoop:
    """The service for ``demcal serve``: executor and leases chosen from the settings."""
    executor = build_executor(settings)
    leases = DatabaseLeases(store, ttl_s=settings.lease_ttl_s)
    options.setdefault("reconcile_every_s", settings.reconcile_interval_s)
    # A replica scans for studies whose lease expired a few times per lease period.
    options.setdefault("scan_every_s", min(5.0, settings.lease_ttl_s / 3))
    return DriverLoop(store, executor, leases, **options)
