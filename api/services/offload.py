"""Views built outside the server's process: identifiability in one child at a lower CPU priority
(``in_child``), the views every page polls in view-building processes at the server's own
priority (``ViewProcesses``, below).

Identifiability reads and evaluates every trial of a study and fits a Gaussian process: about 7 s
of CPU for 10,000 trials, once per batch. Built on a thread of the server, it held the GIL and the
server's share of the cores for that long, and every poll of every dashboard queued behind it
(``benchmarks/README.md``). In a child process niced by ``NICE``, the scheduler serves the
polls first and the build takes what is left.

The child is started on first use (spawn: no state inherited from the server), ends when the
server is gone, and reads the database itself; a build's function and arguments must pickle. A
database the child cannot open (SQLite in memory) is built on the calling thread. A child that
died is replaced at the next build. What it must not do: decide what a view contains (the
caller's function does).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context

from api.db import create_db_engine
from api.services.views import StudyViewCache
from api.store import SqlStore

log = logging.getLogger(__name__)

NICE = 10

_pool: ProcessPoolExecutor | None = None
_lock = threading.Lock()


def in_child(build: Callable[[SqlStore, str], bytes], store: SqlStore, study_id: str) -> bytes:
    """``build(store, study_id)`` in the low-priority child, on a store of the same database; on
    this thread for a database only this process can see."""
    global _pool
    url = store.engine.url
    if not shared_database(url):
        return build(store, study_id)
    with _lock:
        if _pool is None:
            _pool = ProcessPoolExecutor(
                1, mp_context=get_context("spawn"), initializer=_start_child, initargs=(os.getpid(),)
            )
        pool = _pool
    try:
        return pool.submit(_run, build, url.render_as_string(hide_password=False), study_id).result()
    except BrokenProcessPool:
        log.warning("the view-building child process died; starting another at the next build")
        with _lock:
            if _pool is pool:
                _pool = None
        raise


def _start_child(server_pid: int) -> None:
    """Lower the child's priority, and end it when the server is gone: a worker of a process pool
    holds both ends of its task pipe, so it never sees the server die (SIGKILL, or a SIGTERM that
    outlived its grace period) and would wait for tasks forever."""
    os.nice(NICE)
    _watch_server(server_pid)


def _watch_server(server_pid: int) -> None:
    def watch() -> None:
        while os.getppid() == server_pid:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, name="server-watch", daemon=True).start()


_stores: dict[str, SqlStore] = {}  # in the child: one store per database


def _run(build: Callable[[SqlStore, str], bytes], url: str, study_id: str) -> bytes:
    if url not in _stores:
        _stores[url] = SqlStore(create_db_engine(url))
    return build(_stores[url], study_id)


class ViewProcesses:
    """Child processes that build views polled by every open page (the recommendation, progress,
    the Pareto front) from the database themselves, so that no build holds the server's GIL while
    requests wait: built on the server's threads, their bursts after each batch (a fold over the
    study's records, hundreds of rows decoded and serialised) stalled its event loop 222-245 ms on
    a quiet machine, the bulk of the polls' p99 (``benchmarks/README.md``, API session 8, part 2).

    ``processes`` single-process lanes (spawn, started at a lane's first build, at the server's own
    priority: requests wait for these builds): progress, whose trackers a lane keeps between builds
    (as ``StudyViewCache.kept`` in the server did, ``max_kept_studies`` studies), always builds in
    lane 0, every other view in the last lane, so that a long fold does not delay them. A lane whose
    process died is replaced and the build tried once more; ``close`` ends them with the app. A
    build's function (``fn(store, views, study_id, *args)``, ``views`` the lane's own cache for
    ``kept``) and arguments must pickle; its bytes are the caller's."""

    KEPT_VIEWS = frozenset({"progress"})

    def __init__(self, processes: int = 2, max_kept_studies: int = 64) -> None:
        if processes < 1:
            raise ValueError("processes must be at least 1")
        self._lanes = [_Lane(max_kept_studies) for _ in range(processes)]

    def lane(self, view: str) -> int:
        return 0 if view in self.KEPT_VIEWS else len(self._lanes) - 1

    def build(self, view: str, fn: Callable[..., bytes], url: str, study_id: str, *args) -> bytes:
        """``fn(store, views, study_id, *args)`` in the view's lane, on a store of ``url``; the
        calling thread waits (without the GIL)."""
        return self._lanes[self.lane(view)].call(view, fn, url, study_id, args)

    def pids(self) -> list[int]:
        """The live lanes' process ids (for tests and measurements)."""
        return [lane.process.pid for lane in self._lanes
                if lane.process is not None and lane.process.is_alive()]

    def close(self) -> None:
        """End the lanes' processes (a build after this starts them again)."""
        for lane in self._lanes:
            lane.close()


class _Lane:
    """One view-building process, spoken to over a pipe by the thread that waits for the build
    (one build at a time): no helper thread of the server's process has to win the GIL to pass a
    build on or hand its result back, as a process pool's two do."""

    def __init__(self, max_kept_studies: int) -> None:
        self.max_kept_studies = max_kept_studies
        self.lock = threading.Lock()
        self.process = None
        self.conn = None

    def call(self, view: str, fn: Callable[..., bytes], url: str, study_id: str, args: tuple) -> bytes:
        with self.lock:
            ok, value = self._ask(view, (fn, url, study_id, args))
            if ok is None:  # the process died: once more, on a new one
                ok, value = self._ask(view, (fn, url, study_id, args))
            if ok is None:
                raise RuntimeError(f"the view-building process died building {view}")
            if ok:
                return value
            raise value

    def _ask(self, view: str, asked: tuple) -> tuple[bool | None, object]:
        """One round trip; (None, None) if the process died, after stopping what is left of it."""
        if self.process is None or not self.process.is_alive():
            self._start()
        try:
            self.conn.send(asked)
            return self.conn.recv()
        except (EOFError, OSError):
            log.warning("a view-building process died (%s of study %s); starting another",
                        view, asked[2])
            self._stop()
            return None, None

    def _start(self) -> None:
        context = get_context("spawn")
        mine, theirs = context.Pipe()
        self.process = context.Process(
            target=_lane_main, args=(theirs, os.getpid(), self.max_kept_studies), name="demcal-views",
            daemon=True,
        )
        self.process.start()
        theirs.close()
        self.conn = mine

    def _stop(self) -> None:
        if self.conn is not None:
            self.conn.close()
        if self.process is not None:
            self.process.join(1)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(5)
        self.process = self.conn = None

    def close(self) -> None:
        with self.lock:
            if self.conn is not None:
                with contextlib.suppress(OSError):
                    self.conn.send(None)  # ends its loop
            self._stop()


def shared_database(url) -> bool:
    """Whether another process can open the database at ``url`` (not SQLite in memory)."""
    return not (url.get_backend_name() == "sqlite" and url.database in (None, "", ":memory:"))


class _LaneBuilder:
    """What a lane's process keeps between builds: one store and one view cache (for ``kept``)
    per database."""

    def __init__(self, max_kept_studies: int) -> None:
        self.max_kept_studies = max_kept_studies
        self.stores: dict[str, SqlStore] = {}
        self.caches: dict[str, StudyViewCache] = {}

    def build(self, fn: Callable[..., bytes], url: str, study_id: str, args: tuple) -> bytes:
        if url not in self.stores:
            self.stores[url] = SqlStore(create_db_engine(url))
            self.caches[url] = StudyViewCache(max_kept_studies=self.max_kept_studies)
        return fn(self.stores[url], self.caches[url], study_id, *args)


def _lane_main(conn, server_pid: int, max_kept_studies: int) -> None:
    """A lane's process: builds asked over ``conn`` until it reads None or the server is gone."""
    builder = _LaneBuilder(max_kept_studies)
    _watch_server(server_pid)
    while True:
        try:
            asked = conn.recv()
        except EOFError:
            return
        if asked is None:
            return
        try:
            answer = (True, builder.build(*asked))
        except Exception as exc:  # the caller raises it
            answer = (False, exc)
        try:
            conn.send(answer)
        except Exception as exc:  # an error that does not pickle
            conn.send((False, RuntimeError(f"{type(exc).__name__}: {exc}")))
