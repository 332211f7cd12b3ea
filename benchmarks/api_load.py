"""Load benchmark of the REST API: 50 concurrent clients read the Pareto front and pages of the
trial list of a study with 10,000 trials, over loopback, from a uvicorn server in a subprocess.

    python benchmarks/api_load.py                      # SQLite in a temporary directory
    python benchmarks/api_load.py --database-url postgresql://postgres@127.0.0.1:5432/bench
    python benchmarks/api_load.py --think-ms 1000      # dashboard-like polling, one request/s/client
    python -m benchmarks.api_load --dashboard --think-ms 1000 --results-per-s 2

Besides latencies it prints what the server itself spent in the measured phase (CPU ms and SQL
statements per request, from the server process: ``accounted_app``), which a busy shared machine
does not inflate the way it inflates latencies.

Clients run closed-loop by default (each sends its next request as soon as the previous answer
arrives), which measures the server's capacity; with ``--think-ms`` each client waits between
requests, which is what 50 open dashboards do. Prints p50/p99 latency per endpoint and req/s.
Goal: p99 under 50 ms.

``--dashboard`` makes each client poll what the study page polls (``api/dashboard/static/
study.js``): the study, the trials changed since its last poll (``changed_since``), and, when
the study's version changed, the recommendation, progress and
identifiability (and meanwhile each one whose last answer was stale, ``X-Demcal-View``, once its
``Retry-After`` has passed),
revalidating what it has with the ETags it was sent as the browser does (304 when unchanged).
``--results-per-s`` stands for running workers: a writer process adds and finishes that many
trials a second through the store, so every poll sees changes and every per-study cache is
invalidated as in production.
``--dem-workers N`` runs real DEM meanwhile: N processes of the local pool (``worker/local.py``,
as ``demcal serve`` starts them, at the priority it gives them) simulating the quick feeder
(``examples/study-quick.toml``) one trial after another; the load starts once each has finished
its warm-up and a first trial. The writer still stands for their results (a quick trial takes
seconds, the writer's pace is what a larger pool would write).
Goal (issue 14): p99 under 100 ms with 50 clients polling every second while workers run.

Besides the clients' latencies it prints the server's own (from a request's arrival in the app
to its last byte sent), which leave out the time a request waits in the client's event loop or
for the server's accept.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

N_TRIALS = 10_000
PARETO_SIZE = 40


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def seed_database(url: str) -> tuple[str, str]:
    """A migrated database with one study of N_TRIALS finished trials; (study id, API key)."""
    import sqlalchemy as sa

    from api.auth import create_key
    from api.db import create_db_engine, upgrade_database
    from api.models import StudyRow, TrialRow, encode_value, utcnow
    from api.store import SqlStore
    from optimizer.protocols import trial_id
    from optimizer.study import StudyDefinition

    upgrade_database(url)
    engine = create_db_engine(url)
    store = SqlStore(engine)
    definition = StudyDefinition.model_validate(
        {"scenario": {}, "experiment": {"measured": [3, 4, 4, 2, 5]},
         "ga": {"population": 100, "offspring": 100, "generations": 999}}
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="bench")
    rng = random.Random(1)
    now = utcnow()
    rows = []
    for i in range(N_TRIALS):
        n_remaining = rng.randint(0, 30)
        wall = rng.uniform(20, 400)
        f1_value, f1_kind = encode_value(abs(n_remaining - 4.0))
        f2_value, f2_kind = encode_value(wall * 1e6)
        rows.append(
            {
                "id": trial_id(study_id, i, 0), "study_id": study_id, "individual": i, "generation": i // 100,
                "replicate": 0, "seed": i, "scenario": {},
                "params": {"E": 10 ** rng.uniform(5, 9), "nu": rng.uniform(0, 0.49),
                           "e": rng.uniform(0.05, 0.95), "mu": rng.uniform(0.05, 1)},
                "state": "done", "status": "ok", "n_remaining": n_remaining, "wall_time_s": wall,
                "cost": wall * 1e6, "dt": 1e-5, "message": "", "worker": "bench", "attempts": 1,
                "pareto": i < PARETO_SIZE, "f1_value": f1_value, "f1_kind": f1_kind,
                "f2_value": f2_value, "f2_kind": f2_kind, "created_at": now, "updated_at": now,
                "finished_at": now,
                "result": {"status": "ok", "n_items": 30, "n_remaining": n_remaining, "wall_time_s": wall,
                           "cost": wall * 1e6},
            }
        )
    with store.session() as session:
        session.execute(sa.insert(TrialRow), rows)
        # The N_TRIALS // 100 batches are complete, as the driver would have recorded them.
        session.execute(sa.update(StudyRow).where(StudyRow.id == study_id).values(generation=N_TRIALS // 100))
        _, token = create_key(session, "bench")
    engine.dispose()
    return study_id, token


def accounted_app():
    """The API app, counting what the server itself spends: SQL statements per request (by the
    kind of read) and process CPU time, read at ``GET /bench/stats``. Unlike latencies, these do
    not depend on how busy the shared machine is. A uvicorn factory
    (``benchmarks.api_load:accounted_app``)."""
    import contextvars
    import json
    import threading

    import sqlalchemy as sa

    from api.app import create_app
    from api.settings import load_settings

    app = create_app(load_settings())
    lock = threading.Lock()
    requests: dict[str, int] = {}
    queries: dict[str, int] = {}
    durations: dict[str, list[float]] = {}  # in the app, arrival to last byte, by kind
    lags: list[float] = []  # how late the server's event loop woke a 10 ms sleep
    watching: list = []
    current = contextvars.ContextVar("kind", default="background")  # copied into the thread pool

    def count_query(*args) -> None:
        with lock:
            kind = current.get()
            queries[kind] = queries.get(kind, 0) + 1

    sa.event.listen(sa.Engine, "before_cursor_execute", count_query)

    async def accounted(scope, receive, send):
        if scope["type"] != "http":
            await app(scope, receive, send)
            return
        if not watching:
            watching.append(asyncio.get_running_loop().create_task(_lag(lags, math.inf)))
        if scope["path"] == "/bench/stats":
            with lock:
                body = json.dumps({"requests": requests, "queries": queries, "cpu_s": time.process_time(),
                                   "child_cpu_s": _children_cpu_s(), "durations": durations, "lags": lags})
            await send({"type": "http.response.start", "status": 200,
                        "headers": [(b"content-type", b"application/json")]})
            await send({"type": "http.response.body", "body": body.encode()})
            return
        last = scope["path"].rstrip("/").rsplit("/", 1)[-1]
        kind = "study" if last.startswith("st-") else last
        current.set(kind)
        with lock:
            requests[kind] = requests.get(kind, 0) + 1
        arrived = time.perf_counter()

        async def timed_send(message):
            await send(message)
            if message["type"] == "http.response.body" and not message.get("more_body"):
                with lock:
                    durations.setdefault(kind, []).append(time.perf_counter() - arrived)

        await app(scope, receive, timed_send)

    return accounted


def _children_cpu_s(pid: int | str = "self") -> float:
    """CPU seconds of a process's live children (the server's view-building child, the DEM
    workers of the pool process), from /proc."""
    total = 0.0
    for children in Path(f"/proc/{pid}/task").glob("*/children"):
        for pid in children.read_text().split():
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def serve(url: str, port: int, workers: int) -> subprocess.Popen:
    env = dict(os.environ, DEMCAL_DATABASE_URL=url, DEMCAL_LOG_LEVEL="WARNING")
    return subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "benchmarks.api_load:accounted_app", "--factory",
         "--app-dir", str(Path(__file__).resolve().parents[1]), "--host", "127.0.0.1",
         "--port", str(port), "--workers", str(workers), "--log-level", "warning", "--no-access-log"],
        env=env,
    )


async def wait_ready(base: str, timeout: float = 60.0) -> None:
    import httpx

    deadline = time.monotonic() + timeout
    async with httpx.AsyncClient() as client:
        while time.monotonic() < deadline:
            try:
                if (await client.get(f"{base}/healthz")).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            await asyncio.sleep(0.2)
    raise SystemExit("the server did not become healthy in time")


def write_results(url: str, study_id: str, per_s: float, stop: float, batch: int = 20) -> None:
    """Stand-in for running workers and the driver, written as they write: a batch of trials queued
    at once, then run and finished, ``per_s`` a second, then the batch's objectives and the Pareto
    ranking saved (``save_generation``), so that every batch versions the study's views."""
    from api.db import create_db_engine
    from api.store import SqlStore
    from dem.result import SimulationResult, SimulationStatus
    from optimizer.protocols import TrialOutcome, TrialSpec, trial_id

    store = SqlStore(create_db_engine(url))
    rng = random.Random(2)
    pareto = [trial_id(study_id, i, 0) for i in range(PARETO_SIZE)]
    generation = store.load_study(study_id).generation
    individual = N_TRIALS
    while time.time() < stop:
        specs = [
            TrialSpec(trial_id(study_id, i, 0), study_id, i, generation, 0, i,
                      {"E": 10 ** rng.uniform(5, 9), "nu": 0.3, "e": 0.5, "mu": rng.uniform(0.05, 1)}, {})
            for i in range(individual, individual + batch)
        ]
        individual += batch
        store.add_trials(specs)
        store.mark_queued([spec.trial_id for spec in specs])
        objectives = {}
        for spec in specs:
            store.mark_running(spec.trial_id, worker="bench")
            time.sleep(1.0 / per_s)
            n_remaining = rng.randint(0, 30)
            wall = rng.uniform(20, 400)
            result = SimulationResult(status=SimulationStatus.OK, n_items=30, n_remaining=n_remaining,
                                      wall_time_s=wall, cost=wall * 1e6)
            store.record_result(TrialOutcome(spec.trial_id, result, worker="bench"))
            objectives[spec.trial_id] = (abs(n_remaining - 4.0), result.cost)
            if time.time() >= stop:
                return
        generation += 1
        store.save_generation(study_id, generation, b"", pareto, None, objectives)


def run_dem_workers(workers: int, ready, stop) -> None:
    """``workers`` local-pool processes simulating the quick feeder, trial after trial, until
    ``stop`` is set; ``ready`` is set once every process has finished a trial (warm-up done)."""
    import tomllib

    from optimizer.protocols import TrialSpec
    from optimizer.study import StudyDefinition
    from worker.local import LocalPoolExecutor

    root = Path(__file__).resolve().parents[1]
    with open(root / "examples" / "study-quick.toml", "rb") as handle:
        scenario = StudyDefinition.model_validate(tomllib.load(handle)).model_dump(mode="json")["scenario"]
    executor = LocalPoolExecutor(workers)  # the priority demcal serve gives its pool, by default
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}
    submitted, finished_by = 0, set()
    try:
        while not stop.is_set():
            while len(executor.in_flight()) < 2 * workers:
                executor.submit([TrialSpec(f"dem-{submitted}", "bench", submitted, 0, 0, submitted, params,
                                           scenario)])
                submitted += 1
            for outcome in executor.poll(timeout=0.5):
                finished_by.add(outcome.worker)
            if len(finished_by) >= workers:
                ready.set()
    finally:
        executor.close()


async def load(
    base: str, study_id: str, token: str, clients: range, seconds: float, think: float, dashboard: bool,
    start_at: float,
) -> dict:
    """Clients numbered ``clients``, warming up until ``start_at`` (``time.time()``), then measured
    for ``seconds``: their latencies, errors, 304s, CPU and event-loop lags."""
    import httpx

    headers = {"Authorization": f"Bearer {token}"}
    kinds = ["study", "trials", "recommendation", "progress", "identifiability"] if dashboard else [
        "pareto", "trials"]
    latencies: dict[str, list[float]] = {kind: [] for kind in kinds}
    errors = 0
    not_modified = dict.fromkeys(kinds, 0)
    # A dashboard is a browser of its own, with up to 6 connections to the host (Chromium's limit);
    # with one a client, its 3 view reads at a version change queued in the clients' shared pool.
    connections = (6 if dashboard else 1) * len(clients)
    limits = httpx.Limits(max_connections=connections, max_keepalive_connections=connections)

    async def timed(client: httpx.AsyncClient, kind: str, path: str, params=None, cache=None) -> dict | None:
        """One timed GET; its JSON, or None (counted as an error) for a failed request: a keep-alive
        connection the server closed while the client was thinking is retried once by httpx only.
        With ``cache`` (a page's), it revalidates what it has as a browser does: If-None-Match with
        the ETag it was sent, and a 304 means the cached body."""
        nonlocal errors
        start = time.perf_counter()
        sent = dict(headers)
        if cache is not None and path in cache:
            sent["If-None-Match"] = cache[path][0]
        try:
            response = await client.get(path, params=params, headers=sent)
        except httpx.TransportError:
            errors += 1
            return None
        latencies[kind].append(time.perf_counter() - start)
        if cache is not None:  # as study.js reads them, a 304 carries them too
            cache[("stale", path)] = stale = response.headers.get("x-demcal-view") == "stale"
            retry = float(response.headers.get("retry-after", 0)) if stale else 0.0
            cache[("retry", path)] = time.monotonic() + retry if retry > 0 else 0.0
        if response.status_code == 304 and cache is not None and path in cache:
            not_modified[kind] += 1
            # A browser's cache keeps the 304's ETag (a view whose version moved, not its bytes).
            cache[path] = (response.headers.get("etag", cache[path][0]), cache[path][1])
            return cache[path][1]
        if response.status_code != 200:
            errors += 1
            return None
        body = response.json()
        if cache is not None and "etag" in response.headers:
            cache[path] = (response.headers["etag"], body)
        return body

    async def dashboard_loop(index: int, client: httpx.AsyncClient, stop: float) -> None:
        rng = random.Random(index)
        cache: dict = {}  # the browser's HTTP cache of this page (and the views' X-Demcal-View)
        study = f"/api/v1/studies/{study_id}"
        views = [f"{study}/{name}" for name in ("recommendation", "progress", "identifiability")]
        # A page already open: its first full load is done, it polls for changes from now on.
        cursor = views_read = None
        await asyncio.sleep(think * rng.uniform(0, 1))
        while time.monotonic() < stop:
            body = await timed(client, "study", study, cache=cache)
            query = {"limit": 1} if cursor is None else {"limit": 5000, "offset": 0, "changed_since": cursor}
            page = await timed(client, "trials", f"{study}/trials", query)
            if page is None or body is None:
                continue
            cursor = page["changes"]
            version = body["version"]
            due = [path for path in views if (version != views_read or cache.get(("stale", path)))
                   and time.monotonic() >= cache.get(("retry", path), 0.0)]
            await asyncio.gather(*(timed(client, path.rsplit("/", 1)[1], path, cache=cache) for path in due))
            views_read = version
            await asyncio.sleep(think * rng.uniform(0.5, 1.5))

    async def client_loop(index: int, client: httpx.AsyncClient, stop: float) -> None:
        nonlocal errors
        if dashboard:
            await dashboard_loop(index, client, stop)
            return
        rng = random.Random(index)
        if think:
            # Dashboards do not poll in lock step: spread the clients' first requests over one
            # think time instead of sending 50 at the same instant at the start of each phase.
            await asyncio.sleep(think * rng.uniform(0, 1))
        while time.monotonic() < stop:
            if rng.random() < 0.5:
                kind, path, params = "pareto", f"/api/v1/studies/{study_id}/pareto", None
            else:
                offset = rng.randrange(0, N_TRIALS - 100)
                kind, path, params = "trials", f"/api/v1/studies/{study_id}/trials", {
                    "limit": 100, "offset": offset}
            await timed(client, kind, path, params)
            if think:
                await asyncio.sleep(think * rng.uniform(0.5, 1.5))

    async with httpx.AsyncClient(base_url=base, limits=limits, timeout=30) as client:
        warm_stop = time.monotonic() + max(start_at - time.time(), 0.0)
        await asyncio.gather(*(client_loop(i, client, warm_stop) for i in clients))
        for values in latencies.values():
            values.clear()
        errors = 0
        not_modified = dict.fromkeys(kinds, 0)
        client_cpu = time.process_time()
        started = time.monotonic()
        stop = started + seconds
        lags: list[float] = []
        await asyncio.gather(*(client_loop(i, client, stop) for i in clients), _lag(lags, stop))
        elapsed = time.monotonic() - started
        client_cpu = time.process_time() - client_cpu
    return {"latencies": latencies, "elapsed": elapsed, "errors": errors, "not_modified": not_modified,
            "client_cpu_s": client_cpu, "lags": lags}


def _client_process(*args) -> dict:
    return asyncio.run(load(*args))


def measure(base: str, study_id: str, token: str, args, probe) -> dict:
    """The load of ``args.clients`` clients in ``args.client_processes`` processes (50 dashboards
    are 50 browsers: one Python process running them all adds its own queueing to their
    latencies), and what the server and the DEM workers (``probe``) spent meanwhile."""
    import httpx

    headers = {"Authorization": f"Bearer {token}"}
    if args.dashboard:  # the pages are open already: their first load built the study's views
        for view in ("", "/recommendation", "/progress", "/identifiability"):
            url = f"{base}/api/v1/studies/{study_id}{view}"
            httpx.get(url, headers=headers, timeout=300).raise_for_status()
    start_at = time.time() + 8.0  # the processes start, then their clients warm up until then
    share = [range(k, args.clients, args.client_processes) for k in range(args.client_processes)]
    with ProcessPoolExecutor(args.client_processes, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(_client_process, base, study_id, token, clients, args.seconds,
                               args.think_ms / 1000.0, args.dashboard, start_at) for clients in share]
        time.sleep(max(start_at - time.time(), 0.0))
        before = httpx.get(f"{base}/bench/stats").json()
        probed = probe()
        parts = [future.result() for future in futures]
        after = httpx.get(f"{base}/bench/stats").json()
        probed = probe() - probed
    kinds = parts[0]["latencies"]
    return {
        "latencies": {kind: [v for part in parts for v in part["latencies"][kind]] for kind in kinds},
        "elapsed": max(part["elapsed"] for part in parts), "server": _spent(before, after),
        "dem_cpu_s": probed, "lags": [lag for part in parts for lag in part["lags"]],
        "not_modified": {kind: sum(part["not_modified"][kind] for part in parts) for kind in kinds},
        **{name: sum(part[name] for part in parts) for name in ("errors", "client_cpu_s")},
    }


async def _lag(lags: list[float], stop: float, every: float = 0.01) -> None:
    """How late the clients' own event loop wakes a 10 ms sleep: time a response waited there
    (parsing other responses, httpx's work) is in the clients' latencies, not the server's."""
    while time.monotonic() < stop:
        asked = time.perf_counter()
        await asyncio.sleep(every)
        lags.append(time.perf_counter() - asked - every)


def _spent(before: dict, after: dict) -> dict:
    """What the server spent during the measured phase: requests and SQL statements by kind of
    read (statements of views built in background threads count as "background"), CPU seconds."""
    def delta(name: str) -> dict[str, int]:
        return {kind: n - before[name].get(kind, 0) for kind, n in after[name].items()
                if n - before[name].get(kind, 0)}

    return {"requests": delta("requests"), "queries": delta("queries"),
            "durations": {kind: values[len(before["durations"].get(kind, [])):]
                          for kind, values in after["durations"].items()},
            "lags": after["lags"][len(before["lags"]):],
            "cpu_s": after["cpu_s"] - before["cpu_s"],
            "child_cpu_s": after["child_cpu_s"] - before["child_cpu_s"]}


def _percentile(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100, method="inclusive")[q - 1] if len(values) > 1 else values[0]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--database-url", default=None, help="default: a SQLite file in a temp dir")
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--think-ms", type=float, default=0.0, help="pause between a client's requests")
    parser.add_argument("--server-workers", type=int, default=1, help="uvicorn worker processes")
    parser.add_argument("--dashboard", action="store_true", help="poll what the study page polls")
    parser.add_argument("--results-per-s", type=float, default=0.0,
                        help="trials finished per second meanwhile (running workers)")
    parser.add_argument("--client-processes", type=int, default=1,
                        help="processes the clients are spread over (each with its own event loop)")
    parser.add_argument("--dem-workers", type=int, default=0,
                        help="local-pool processes simulating DEM meanwhile (real workers)")
    args = parser.parse_args()

    workdir = tempfile.mkdtemp(prefix="demcal-bench-")
    url = args.database_url or f"sqlite:///{workdir}/bench.db"
    if args.database_url and args.database_url.startswith("postgresql"):
        import sqlalchemy as sa

        from api.db import create_db_engine

        engine = create_db_engine(args.database_url)
        with engine.begin() as connection:
            connection.execute(sa.text("DROP SCHEMA public CASCADE; CREATE SCHEMA public"))
        engine.dispose()
    t0 = time.perf_counter()
    study_id, token = seed_database(url)
    print(f"seeded {N_TRIALS} trials in {time.perf_counter() - t0:.1f} s ({url.split(':')[0]})")

    port = _free_port()
    server = serve(url, port, args.server_workers)
    base = f"http://127.0.0.1:{port}"
    writer = dem = None
    context = None
    try:
        asyncio.run(wait_ready(base))
        context = get_context("spawn")
        probe = lambda: 0.0  # noqa: E731
        if args.dem_workers:
            ready, stop_dem = context.Event(), context.Event()
            dem = context.Process(target=run_dem_workers, args=(args.dem_workers, ready, stop_dem))
            dem.start()
            if not ready.wait(900):
                raise SystemExit("the DEM workers did not finish a first trial in 15 min")
            probe = lambda: _children_cpu_s(dem.pid)  # noqa: E731
            print(f"{args.dem_workers} DEM workers warm")
        if args.results_per_s:
            until = time.time() + 3600  # ended with the load, however long warming the views takes
            writer = context.Process(
                target=write_results, args=(url, study_id, args.results_per_s, until)
            )
            writer.start()
        result = measure(base, study_id, token, args, probe)
    finally:
        if dem is not None:
            stop_dem.set()
            dem.join(30)
            if dem.is_alive():
                dem.kill()
        if writer is not None:
            writer.terminate()
            writer.join(10)
        server.terminate()  # graceful: it waits for requests in flight, a view still building
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()

    everything = [v for values in result["latencies"].values() for v in values]
    mode = ("dashboard polls, " if args.dashboard else "") + (
        "closed loop" if not args.think_ms else f"think time {args.think_ms:g} ms")
    if args.results_per_s:
        mode += f", {args.results_per_s:g} results/s written meanwhile"
    print(f"{args.clients} clients in {args.client_processes} process(es), {mode}, "
          f"{args.server_workers} server worker(s), {result['elapsed']:.1f} s")
    inside = result["server"]["durations"]
    inside_all = [v for values in inside.values() for v in values]
    for kind, values in [*result["latencies"].items(), ("all", everything)]:
        if not values:
            print(f"  {kind:7s} n=     0")
            continue
        own = inside_all if kind == "all" else inside.get(kind, [])
        print(
            f"  {kind:7s} n={len(values):6d}  p50={_percentile(values, 50) * 1000:7.1f} ms  "
            f"p99={_percentile(values, 99) * 1000:7.1f} ms"
            + (f"  304s {result['not_modified'][kind]:5d}" if args.dashboard and kind != "all" else "")
            + (f"  (in the server: p50 {_percentile(own, 50) * 1000:.1f} ms, p99 "
               f"{_percentile(own, 99) * 1000:.1f} ms)" if own else "")
        )
    print(f"  throughput {len(everything) / result['elapsed']:.0f} req/s, errors {result['errors']}, "
          f"304 not modified {sum(result['not_modified'].values())} "
          f"({sum(result['not_modified'].values()) / max(len(everything), 1):.0%})")
    server = result["server"]
    requests = sum(server["requests"].values())
    per_kind = ", ".join(
        f"{kind} {server['queries'].get(kind, 0) / n:.1f}" for kind, n in sorted(server["requests"].items()))
    print(f"  server: {server['cpu_s'] * 1000 / max(requests, 1):.1f} CPU ms per request "
          f"({server['cpu_s']:.1f} s for {requests}); SQL statements per request: {per_kind}; "
          f"in background view builds: {server['queries'].get('background', 0)}; "
          f"its view-building child: {server['child_cpu_s']:.1f} CPU s")
    def late(lags: list[float]) -> str:
        stalled = sum(lag for lag in lags if lag > 0.05)
        return (f"p50 {_percentile(lags, 50) * 1000:.1f} ms, p99 {_percentile(lags, 99) * 1000:.1f} ms, "
                f"max {max(lags) * 1000:.0f} ms ({stalled:.1f} s late by over 50 ms)")

    print(f"  clients: {result['client_cpu_s']:.1f} CPU s; a 10 ms sleep woke late in their event loop by "
          f"{late(result['lags'])}, in the server's by {late(server['lags'])}")
    if args.dem_workers:
        print(f"  DEM workers: {result['dem_cpu_s']:.1f} CPU s in the measured phase "
              f"({result['dem_cpu_s'] / result['elapsed']:.2f} cores)")
    print(f"  load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
