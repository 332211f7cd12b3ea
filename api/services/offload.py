"""Views too expensive for the server's own process, built in one child process at a lower CPU
priority.

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

import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context

from api.db import create_db_engine
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
    if url.get_backend_name() == "sqlite" and url.database in (None, "", ":memory:"):
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
