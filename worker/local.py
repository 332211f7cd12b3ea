"""The embedded default executor: trials run in a pool of local worker processes.

One process per core by default (``workers=0``); each runs one trial at a time through
``worker.jobs.run_trial`` and sends the result back on its own pipe. Own pipes rather than a
shared ``multiprocessing.Queue`` because a process killed while writing to a shared queue can
corrupt it, and this executor does kill processes:

- cancel: a running trial is stopped by terminating its process (a replacement starts when
  there is work); its outcome is never reported;
- deadlines: ``run_feeder`` ends a run with ``timeout`` once the spec's ``timeout_s`` has passed
  (checked between chunks); if a process is still busy ``grace_s`` after that, it is killed and
  the trial reported as ``timeout``;
- priority: a new process lowers its CPU priority by ``nice`` (``worker/priority.py``) first, so
  that the service it runs under stays responsive while trials compute;
- warm-up: a new process runs ``worker.warmup.warm_up`` before its first trial, so no trial's T
  includes the kernels' compile, and says when it is done: the first trial's hard deadline runs
  from then, not from when the trial was handed over. A cold compile on a loaded machine took
  over 270 s (two workers of the README's quick study, 23 Nov); a fixed allowance of 120 s
  killed both first trials, and every replacement process started the compile again. A warm-up
  still running after ``WARMUP_LIMIT_S`` is taken for a hung process;
- a process that dies (segfault in a kernel, out of memory) reports its trial as ``error`` with
  the exit code, and is replaced.

Processes are started with ``spawn``: the parent may hold threads (progress display, database
connections) that a fork would copy in an unknown state. Workers ignore SIGINT, so Ctrl-C reaches
only the parent, which then calls ``close()``: busy processes are terminated, idle ones told to
exit, and nothing is left behind.

Must not: touch the store or decide anything about a study; it only runs what it is handed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass
from multiprocessing import connection, get_context
from pathlib import Path
from typing import Any

from dem.result import SimulationResult, SimulationStatus
from optimizer.protocols import TrialOutcome, TrialSpec
from worker.jobs import longest_first
from worker.priority import DEFAULT_NICE, lower_priority
from worker.warmup import warm_up

logger = logging.getLogger(__name__)

# How long a worker may overrun its trial's deadline before it is killed: the feeder checks its
# deadline between chunks of simulated time, so a healthy run stops well within this.
DEFAULT_GRACE_S = 30.0
# Longest a new process may take to warm its kernels (``worker/warmup.py``) before it is taken
# for hung and its first trial ends as ``timeout``: a cold compile under load takes minutes.
WARMUP_LIMIT_S = 1800.0
# What a process sends when its warm-up is done (a result is ``(trial_id, result)``).
READY = None
# Longest single wait, so that hard deadlines are checked even when no result arrives.
MAX_WAIT_S = 0.5


def _serve(
    conn, log_level: int, snapshot_root: Path | None, data_dir: Path | None, nice: int, warm_up: Callable
) -> None:
    """A worker process: run the specs it receives until told to stop (None) or its pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    lower_priority(nice)
    # A spawned process starts with no logging set up; give the engine's records the parent's
    # level and a one-line format instead of Python's bare last-resort output.
    logging.basicConfig(
        level=log_level, format="%(asctime)s %(levelname)-7s %(name)s[%(process)d]: %(message)s"
    )
    from worker.jobs import run_trial

    conn.send((READY, warm_up()))  # before the first trial, so that no trial's T includes the compile
    while True:
        try:
            spec = conn.recv()
        except (EOFError, OSError):
            return
        if spec is None:
            return
        conn.send((spec["trial_id"], run_trial(spec, snapshot_root=snapshot_root, data_dir=data_dir)))


@dataclass
class _Slot:
    process: Any
    conn: Any
    spec: TrialSpec | None = None
    started: float = 0.0
    born: float = 0.0
    warm: bool = False  # its warm-up is done; until then its first trial waits in the pipe

    @property
    def name(self) -> str:
        return f"local-{self.process.pid}"

    def hard_deadline(self, grace_s: float) -> float | None:
        if self.spec is None:
            return None
        if not self.warm:
            return self.born + WARMUP_LIMIT_S
        if self.spec.timeout_s is None:
            return None
        return self.started + self.spec.timeout_s + grace_s


class LocalPoolExecutor:
    """An Executor on local processes; see the module docstring for what it guarantees."""

    def __init__(
        self, workers: int = 0, *, grace_s: float = DEFAULT_GRACE_S, snapshot_root: Path | None = None,
        data_dir: Path | None = None, nice: int = DEFAULT_NICE, warm_up: Callable = warm_up,
    ):
        self.size = workers or os.cpu_count() or 1
        self.nice = nice
        self.snapshot_root = snapshot_root
        self.data_dir = data_dir
        self.grace_s = grace_s
        self.warm_up = warm_up  # a module-level function: ``spawn`` pickles it by name
        self._context = get_context("spawn")
        self._slots: list[_Slot] = []
        self._waiting: deque[TrialSpec] = deque()

    # -- the Executor protocol ------------------------------------------------------------------

    def submit(self, specs: Sequence[TrialSpec]) -> None:
        known = self.in_flight()
        for spec in longest_first(specs, self.data_dir):
            if spec.trial_id not in known:
                self._waiting.append(spec)
                known.add(spec.trial_id)
        self._dispatch()

    def poll(self, timeout: float = 0.0) -> list[TrialOutcome]:
        end = time.monotonic() + timeout
        outcomes: list[TrialOutcome] = []
        while True:
            self._dispatch()
            busy = [slot for slot in self._slots if slot.spec is not None]
            if not busy:
                return outcomes
            now = time.monotonic()
            deadlines = [d for d in (slot.hard_deadline(self.grace_s) for slot in busy) if d is not None]
            wait = min([end - now, MAX_WAIT_S, *(d - now for d in deadlines)])
            ready = set(connection.wait([slot.conn for slot in busy], timeout=max(wait, 0.0)))
            for slot in busy:
                outcome = self._collect(slot, slot.conn in ready)
                if outcome is not None:
                    outcomes.append(outcome)
            if outcomes or time.monotonic() >= end:
                return outcomes

    def in_flight(self, expected: Collection[str] = ()) -> set[str]:
        """Every trial is in this process's own lists, so ``expected`` adds nothing."""
        running = {slot.spec.trial_id for slot in self._slots if slot.spec is not None}
        return running | {spec.trial_id for spec in self._waiting}

    def cancel(self, trial_ids: Sequence[str]) -> None:
        doomed = set(trial_ids)
        self._waiting = deque(spec for spec in self._waiting if spec.trial_id not in doomed)
        for slot in list(self._slots):
            if slot.spec is not None and slot.spec.trial_id in doomed:
                logger.info("trial %s: cancelled, stopping %s", slot.spec.trial_id, slot.name)
                self._retire(slot)

    def close(self) -> None:
        """Stop every process: idle ones are asked to exit, busy ones terminated."""
        self._waiting.clear()
        for slot in list(self._slots):
            if slot.spec is None:
                with contextlib.suppress(OSError):  # already gone; join below reaps it
                    slot.conn.send(None)
            else:
                slot.process.terminate()
        for slot in self._slots:
            slot.process.join(timeout=5)
            if slot.process.is_alive():
                slot.process.kill()
                slot.process.join()
            slot.conn.close()
        self._slots.clear()

    # -- beyond the protocol: what a progress display wants -------------------------------------

    def running(self) -> dict[str, str]:
        """Trial id -> worker name for the trials being simulated right now."""
        return {slot.spec.trial_id: slot.name for slot in self._slots if slot.spec is not None}

    # -- internals ------------------------------------------------------------------------------

    def _dispatch(self) -> None:
        while self._waiting:
            slot = next((slot for slot in self._slots if slot.spec is None), None)
            if slot is None:
                if len(self._slots) >= self.size:
                    return
                slot = self._start()
            spec = self._waiting.popleft()
            slot.spec, slot.started = spec, time.monotonic()
            slot.conn.send(asdict(spec))

    def _start(self) -> _Slot:
        parent, child = self._context.Pipe()
        process = self._context.Process(
            target=_serve,
            args=(
                child,
                logging.getLogger().getEffectiveLevel(),
                self.snapshot_root,
                self.data_dir,
                self.nice,
                self.warm_up,
            ),
            daemon=True,
            name="demcal-local-worker",
        )
        process.start()
        child.close()
        slot = _Slot(process, parent, born=time.monotonic())
        self._slots.append(slot)
        return slot

    def _retire(self, slot: _Slot) -> None:
        slot.process.terminate()
        slot.process.join(timeout=5)
        if slot.process.is_alive():
            slot.process.kill()
            slot.process.join()
        slot.conn.close()
        self._slots.remove(slot)

    def _collect(self, slot: _Slot, readable: bool) -> TrialOutcome | None:
        """The outcome of a busy slot, if it has one: a result, a death, or an overrun."""
        spec = slot.spec
        if readable:
            try:
                trial, result = slot.conn.recv()
            except (EOFError, OSError):
                slot.process.join(timeout=5)
                return self._failed(
                    slot, SimulationStatus.ERROR, f"worker process died (exit code {slot.process.exitcode})"
                )
            if trial is READY:
                logger.info("%s: kernels warm after %.1f s", slot.name, result)
                slot.warm, slot.started = True, time.monotonic()
                return None
            slot.spec = None
            return TrialOutcome(trial, SimulationResult.model_validate(result), worker=slot.name)
        if not slot.process.is_alive():
            return self._failed(
                slot, SimulationStatus.ERROR, f"worker process died (exit code {slot.process.exitcode})"
            )
        deadline = slot.hard_deadline(self.grace_s)
        if deadline is not None and time.monotonic() > deadline:
            if not slot.warm:
                message = f"killed: its worker was still warming its kernels after {WARMUP_LIMIT_S:g} s"
            else:
                message = f"killed: still running {self.grace_s:g} s after its {spec.timeout_s:g} s limit"
            return self._failed(slot, SimulationStatus.TIMEOUT, message)
        return None

    def _failed(self, slot: _Slot, status: SimulationStatus, message: str) -> TrialOutcome:
        spec, name = slot.spec, slot.name
        logger.warning("trial %s: %s (%s)", spec.trial_id, message, name)
        self._retire(slot)
        result = SimulationResult(
            status=status,
            message=message,
            params=dict(spec.params),
            seed=spec.seed,
            wall_time_s=time.monotonic() - slot.started,
        )
        return TrialOutcome(spec.trial_id, result, worker=name)
