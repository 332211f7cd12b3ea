# ruff: noqa: E402 - the imports follow the sys.path fix below, on purpose
"""Benchmark of the distributed path (not a test): what the RQ queue costs per trial, and how
a generation of real trials speeds up with a second worker.

1. Overhead: 1,000 trivial trials (the job returns a fixed result at once, through the real
   delivery path) submitted as one generation and taken back with ``RqExecutor.poll``; workers
   are ``DemcalWorker`` processes forked from this script (the job function lives here, in
   ``__main__``). Per-job overhead = elapsed x workers / jobs: the worker-seconds the queue path
   (enqueue, dequeue, fork of the work horse, result push, pop) spends on a job that does nothing.
   Goal: under 20 ms.
2. Speedup: one generation of real quick-scenario trials (``examples/feeder-quick.toml``,
   parameters spread over the default bounds) run by 1 and then 2 real ``demcal worker``
   processes. Speedup = elapsed(1) / elapsed(2). Goal: at least 1.8 on 2 free cores. A warm-up
   trial first fills numba's on-disk cache so that neither run pays compilation.

Run: ``python benchmarks/queue.py [--jobs 1000] [--trials 12] [--skip-speedup]``
(needs Redis; ``--redis redis://127.0.0.1:6379/14`` by default, a database it flushes).
"""

from __future__ import annotations

import sys
from pathlib import Path

# This script shares its name with the standard library's ``queue``, which redis and
# multiprocessing import: keep its own folder off the import path before anything else loads.
sys.path[:] = [entry for entry in sys.path if Path(entry or ".").resolve() != Path(__file__).resolve().parent]

import argparse
import multiprocessing
import os
import signal
import statistics
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import redis
from rq import get_current_job

from dem.result import SimulationResult, SimulationStatus
from optimizer.protocols import TrialSpec, trial_id
from worker.rq_executor import RqExecutor
from worker.rq_job import deliver
from worker.runner import build_worker, preload

ROOT = Path(__file__).resolve().parent.parent


def trivial_trial(spec: dict) -> dict:
    """A 'simulation' that costs nothing: what remains of a job is the queue path itself."""
    result = SimulationResult(
        status=SimulationStatus.OK, n_items=1, n_remaining=0, params=spec["params"], seed=spec["seed"]
    ).model_dump(mode="json")
    deliver(get_current_job(), spec, result)
    return result


def _work(url: str, queue: str, name: str) -> None:
    connection = redis.Redis.from_url(url)
    build_worker(connection, [queue], name=name, heartbeat_s=10).work(logging_level="WARNING")


def specs(study: str, count: int, scenario: dict, params: list[dict]) -> list[TrialSpec]:
    return [
        TrialSpec(
            trial_id=trial_id(study, i, 0),
            study_id=study,
            individual=i,
            generation=0,
            replicate=0,
            seed=1000 + i,
            params=params[i % len(params)],
            scenario=scenario,
        )
        for i in range(count)
    ]


def collect(executor: RqExecutor, count: int, timeout: float) -> list:
    outcomes: list = []
    deadline = time.monotonic() + timeout
    while len(outcomes) < count:
        if time.monotonic() > deadline:
            raise RuntimeError(f"only {len(outcomes)} of {count} results after {timeout:.0f} s")
        outcomes += executor.poll(timeout=1.0)
    return outcomes


def overhead(url: str, jobs: int, workers: int) -> dict:
    connection = redis.Redis.from_url(url)
    connection.flushdb()
    queue = f"bench-overhead-{workers}"
    executor = RqExecutor(connection, queue, job_function=f"{__name__}.trivial_trial")
    context = multiprocessing.get_context("fork")
    processes = [
        context.Process(target=_work, args=(url, queue, f"bench-{workers}-{i}")) for i in range(workers)
    ]
    for process in processes:
        process.start()
    time.sleep(2.0)  # let the workers register and block on the queue
    batch = specs(f"overhead{workers}", jobs, {}, [{"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}])
    started = time.perf_counter()
    executor.submit(batch)
    submitted = time.perf_counter()
    outcomes = collect(executor, jobs, timeout=600)
    elapsed = time.perf_counter() - started
    for process in processes:
        os.kill(process.pid, signal.SIGTERM)
    for process in processes:
        process.join(30)
    connection.flushdb()
    return {
        "workers": workers,
        "jobs": len(outcomes),
        "submit_ms": (submitted - started) * 1e3,
        "elapsed_s": elapsed,
        "per_job_ms": elapsed * workers / jobs * 1e3,
    }


def quick_scenario() -> dict:
    """The quick example as it ships: the time step derived from each trial's E."""
    with (ROOT / "examples" / "feeder-quick.toml").open("rb") as handle:
        return tomllib.load(handle)


def generation_params(count: int) -> list[dict]:
    """Parameter sets spread over the default bounds, as a GA's initial population would be."""
    sets = []
    for i in range(count):
        u = (i + 0.5) / count
        sets.append({"E": 10 ** (6 + u), "nu": 0.1 + 0.3 * u, "e": 0.2 + 0.6 * (1 - u), "mu": 0.3 + 0.4 * u})
    # E within 1e6-1e7 Pa: the quick study's bounds.
    return sets


def run_generation(url: str, workers: int, trials: int, tag: str) -> dict:
    connection = redis.Redis.from_url(url)
    connection.flushdb()
    queue = f"bench-speedup-{tag}"
    env = {**os.environ, "DEMCAL_REDIS_URL": url, "DEMCAL_QUEUE_NAME": queue, "DEMCAL_LOG_LEVEL": "WARNING"}
    demcal = str(Path(sys.executable).with_name("demcal"))
    processes = [
        subprocess.Popen([demcal, "worker", "--name", f"{tag}-{i}"], env=env, cwd=ROOT)
        for i in range(workers)
    ]
    executor = RqExecutor(connection, queue)
    time.sleep(5.0)  # workers import the engine before they take a job
    batch = specs(f"speedup{tag}", trials, quick_scenario(), generation_params(trials))
    started = time.perf_counter()
    executor.submit(batch)
    outcomes = collect(executor, trials, timeout=3600)
    elapsed = time.perf_counter() - started
    for process in processes:
        process.send_signal(signal.SIGTERM)
    for process in processes:
        process.wait(120)
    walls = [outcome.result.wall_time_s for outcome in outcomes]
    statuses = sorted({outcome.result.status.value for outcome in outcomes})
    return {"workers": workers, "elapsed_s": elapsed, "trial_wall_s": walls, "statuses": statuses}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--redis", default="redis://127.0.0.1:6379/14", help="a Redis database this may flush"
    )
    parser.add_argument("--jobs", type=int, default=1000)
    parser.add_argument("--trials", type=int, default=12)
    parser.add_argument("--skip-speedup", action="store_true")
    args = parser.parse_args()
    preload()  # forked workers start with the simulation stack loaded, as `demcal worker` does

    print(f"queue path overhead, {args.jobs} trivial jobs")
    for workers in (1, 2):
        figures = overhead(args.redis, args.jobs, workers)
        print(
            f"  {workers} worker(s): submit {figures['submit_ms']:.0f} ms (one round trip), "
            f"all results in {figures['elapsed_s']:.1f} s -> {figures['per_job_ms']:.1f} ms per job"
        )
    if args.skip_speedup:
        return

    print(f"one generation of {args.trials} quick-scenario trials (examples/feeder-quick.toml)")
    warm = run_generation(args.redis, 1, 1, "warmup")
    print(f"  warm-up trial (fills the numba cache): {warm['elapsed_s']:.1f} s")
    one = run_generation(args.redis, 1, args.trials, "one")
    two = run_generation(args.redis, 2, args.trials, "two")
    for run in (one, two):
        print(
            f"  {run['workers']} worker(s): {run['elapsed_s']:.1f} s; trial wall time median "
            f"{statistics.median(run['trial_wall_s']):.1f} s, sum {sum(run['trial_wall_s']):.1f} s; "
            f"statuses {run['statuses']}"
        )
    print(f"  speedup 1 -> 2 workers: {one['elapsed_s'] / two['elapsed_s']:.2f} (goal >= 1.8)")
    # Busy workers on average: what the queue lets run at once. On free cores it bounds the
    # speedup; when the cores are shared with other processes, trials run slower instead.
    occupancy = sum(two["trial_wall_s"]) / two["elapsed_s"]
    print(f"  trials running at once with 2 workers (sum of trial wall / elapsed): {occupancy:.2f}")
    queue_share = (one["elapsed_s"] - sum(one["trial_wall_s"])) / args.trials
    print(f"  queue and start-up time per real trial (1 worker): {queue_share:.2f} s")


if __name__ == "__main__":
    main()
