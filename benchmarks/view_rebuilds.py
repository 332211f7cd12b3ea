"""The server's thread CPU per rebuild of the polled views, built on the server's thread ("in
place", ``DEMCAL_VIEW_PROCESSES=0``) and in view-building processes (the default), alternated on
one database: the seeded study of ``benchmarks.api_load`` (10,000 trials), a batch of 20 trials
run and saved before each round, as the load benchmark's writer does.

    python -m benchmarks.view_rebuilds [--rounds 20] [--database-url URL]

What a rebuild costs the server's process is what a request (or a progress refresh) holds the GIL
for: thread CPU (``time.thread_time``) of the build as the service calls it; in processes, the
wait is off the CPU and the process's own CPU is printed apart (wall time, both).
"""

from __future__ import annotations

import argparse
import random
import statistics
import tempfile
import time

from benchmarks.api_load import PARETO_SIZE, seed_database


def _batch(store, study_id: str, generation: int, first: int, rng: random.Random) -> None:
    from dem.result import SimulationResult, SimulationStatus
    from optimizer.protocols import TrialOutcome, TrialSpec, trial_id

    specs = [
        TrialSpec(trial_id(study_id, i, 0), study_id, i, generation, 0, i,
                  {"E": 10 ** rng.uniform(5, 9), "nu": 0.3, "e": 0.5, "mu": rng.uniform(0.05, 1)}, {})
        for i in range(first, first + 20)
    ]
    store.add_trials(specs)
    store.mark_queued([spec.trial_id for spec in specs])
    objectives = {}
    for spec in specs:
        store.mark_running(spec.trial_id, worker="bench")
        n_remaining, wall = rng.randint(0, 30), rng.uniform(20, 400)
        result = SimulationResult(status=SimulationStatus.OK, n_items=30, n_remaining=n_remaining,
                                  wall_time_s=wall, cost=wall * 1e6)
        store.record_result(TrialOutcome(spec.trial_id, result, worker="bench"))
        objectives[spec.trial_id] = (abs(n_remaining - 4.0), result.cost)
    pareto = [trial_id(study_id, i, 0) for i in range(PARETO_SIZE)]
    store.save_generation(study_id, generation + 1, b"", pareto, None, objectives)


def main() -> None:
    from api.db import create_db_engine
    from api.services.offload import ViewProcesses
    from api.services.progress import _progress
    from api.services.trials import _pareto_front, _recommendation_json
    from api.services.views import StudyViewCache
    from api.store import SqlStore

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--database-url", default=None, help="default: a SQLite file in a temp dir")
    args = parser.parse_args()
    url = args.database_url or f"sqlite:///{tempfile.mkdtemp(prefix='demcal-views-')}/bench.db"
    study_id, _ = seed_database(url)
    store = SqlStore(create_db_engine(url))
    processes = ViewProcesses(2)
    ways = {"in place": StudyViewCache(), "in processes": StudyViewCache(processes=processes)}
    views = {"recommendation": (_recommendation_json,), "pareto": (_pareto_front,), "progress": (_progress,)}
    cpu = {(way, view): [] for way in ways for view in views}
    wall = {(way, view): [] for way in ways for view in views}
    rng, first = random.Random(3), 20_000
    try:
        for cache in ways.values():  # first builds (progress reads the whole study): not counted
            for view, (fn,) in views.items():
                extra = (store.load_study(study_id).generation,) if view == "pareto" else ()
                cache.builder(view, fn, store, study_id, *extra)()
        for round_ in range(args.rounds):
            generation = store.load_study(study_id).generation
            _batch(store, study_id, generation, first, rng)
            first += 20
            order = list(ways.items()) if round_ % 2 == 0 else list(ways.items())[::-1]
            for way, cache in order:
                for view, (fn,) in views.items():
                    extra = (generation + 1,) if view == "pareto" else ()
                    build = cache.builder(view, fn, store, study_id, *extra)
                    t0, w0 = time.thread_time(), time.perf_counter()
                    build()
                    cpu[way, view].append(time.thread_time() - t0)
                    wall[way, view].append(time.perf_counter() - w0)
    finally:
        processes.close()
    print(f"{args.rounds} rounds, one batch of 20 trials saved before each ({url.split(':')[0]})")
    for view in views:
        for way in ways:
            print(f"  {view:15s} {way:13s} server thread CPU median "
                  f"{statistics.median(cpu[way, view]) * 1000:6.2f} ms  "
                  f"(max {max(cpu[way, view]) * 1000:6.2f}), wall median "
                  f"{statistics.median(wall[way, view]) * 1000:6.2f} ms")


if __name__ == "__main__":
    main()
