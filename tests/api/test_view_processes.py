"""The polled views built in view-building processes (``offload.ViewProcesses``): the same bytes
as built on the server's thread, on SQLite and PostgreSQL, and the server's event loop keeps
answering while a build that holds the GIL for seconds runs."""

from __future__ import annotations

import asyncio
import os
import threading
import time

import httpx
import pytest

from api.app import create_app
from api.auth import Principal
from api.services import progress, trials
from api.services.offload import ViewProcesses
from api.services.views import StudyViewCache
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_with_failures
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


@pytest.fixture
def processes():
    processes = ViewProcesses(2)
    yield processes
    processes.close()


def _where_built(store, views, study_id: str) -> bytes:
    return str(os.getpid()).encode()


def test_views_built_in_processes_are_the_bytes_built_in_place(store, processes):
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 8, "offspring": 4, "generations": 4}, seed=7)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    driver = Driver(store, SyntheticExecutor(synthetic_with_failures))
    alice = Principal(key_id=1, owner="alice", admin=False)
    in_place, off = StudyViewCache(), StudyViewCache(processes=processes)
    views = {"recommendation": trials.recommendation_json, "pareto": trials.pareto_front_json,
             "progress": progress.progress_json}
    compared = 0
    active = True
    while active:
        active = driver.step(study_id, timeout=0).active
        for name, view in views.items():
            # A new cache each time for the server's side: progress is served stale while it builds.
            here = view(store, StudyViewCache(), study_id, alice)
            there = view(store, off, study_id, alice)
            kept_here = view(store, in_place, study_id, alice)
            while not (there.current and kept_here.current):  # progress: its next version builds
                time.sleep(0.01)
                there, kept_here = view(store, off, study_id, alice), view(store, in_place, study_id, alice)
            assert there.body == here.body == kept_here.body, name
            assert there.etag == here.etag
            compared += 1

    assert compared >= 12
    assert b'"points":[{' in here.body
    # built there, not here: a lane per kind (progress keeps its trackers in lane 0)
    assert processes.build("progress", _where_built, _url(store), study_id) != str(os.getpid()).encode()
    assert len(set(processes.pids())) == 2 and os.getpid() not in processes.pids()


def _url(store) -> str:
    return store.engine.url.render_as_string(hide_password=False)


def test_a_dead_view_process_is_replaced_and_its_build_done(store, processes):
    import signal

    first = processes.build("pareto", _where_built, _url(store), "s1")
    os.kill(int(first), signal.SIGKILL)
    deadline = time.monotonic() + 30
    while True:  # the pool notices the death: the next build starts another process
        second = processes.build("pareto", _where_built, _url(store), "s1")
        if second != first:
            break
        assert time.monotonic() < deadline
        time.sleep(0.1)

    assert int(second) != os.getpid()


def _hold_the_gil(store, views, study_id: str, seconds: float) -> bytes:
    """A build that holds the GIL in long stretches (C loops that never let another thread run),
    as the views' decoding and serialisation of hundreds of rows do in shorter ones; it says how long
    its longest stretch was."""
    longest, stop = 0.0, time.perf_counter() + seconds
    while time.perf_counter() < stop:
        started = time.perf_counter()
        sum(range(60_000_000))  # about 0.25 s here: 20M took 0.09 s on a faster machine
        longest = max(longest, time.perf_counter() - started)
    return repr(longest).encode()


@pytest.mark.parametrize("view_processes", [1])
def test_the_event_loop_answers_while_a_build_holds_the_gil(settings, engine, store, view_processes):
    app = create_app(settings.model_copy(update={"view_processes": view_processes}), engine=engine)
    views = app.state.study_views
    build = views.builder("slow", _hold_the_gil, store, "s1", 3.0)
    views.builder("slow", _where_built, store, "s1")()  # the process is started before the clock runs

    async def run() -> tuple[list[float], bytes]:
        built: list[bytes] = []
        thread = threading.Thread(target=lambda: built.append(views.get_or_build("slow", "s1", 1, build)))
        latencies = []
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app), base_url="http://test") as client:
            await client.get("/healthz")  # its first answer opens connections: not the clock's
            thread.start()
            while thread.is_alive():
                asked = time.perf_counter()
                assert (await client.get("/healthz")).status_code == 200
                latencies.append(time.perf_counter() - asked)
                await asyncio.sleep(0.02)
        thread.join()
        return latencies, built[0]

    try:
        latencies, built = asyncio.run(run())
    finally:
        views.close()
    longest = float(built)
    assert longest > 0.1  # the build held the GIL in stretches this long...
    # ...not here: answered every 20 ms or so (built in place, once or twice between stretches),
    # the slowest tenth (the shared machine's hiccups) in under half a stretch
    slow = sorted(latencies)[len(latencies) * 9 // 10]
    assert len(latencies) > 30 and slow < longest / 2, (len(latencies), slow, longest)


def test_a_database_in_this_process_only_is_built_here(processes):
    from api.db import create_db_engine
    from api.models import Base
    from api.store import SqlStore

    engine = create_db_engine("sqlite://")
    Base.metadata.create_all(engine)  # in this connection's memory: no other process sees it
    views = StudyViewCache(processes=processes)

    assert views.builder("pareto", _where_built, SqlStore(engine), "s1")() == str(os.getpid()).encode()
    assert processes.pids() == []
