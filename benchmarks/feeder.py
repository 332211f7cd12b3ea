"""The paper's full protocol (examples/feeder.toml: 30 items, 5 s deposition + 60 s vibration) at
E = 1e7 and 1e8 Pa on one core: wall and CPU time, steps, us/step, for each item representation.
Goals: <= 20 s CPU at E = 1e7 Pa with clumps (issue 15; CPU time is the figure on a shared
machine); rounded polyhedra at most 1.5x the clumps' time, and a run
that clogs (``--clogging``: e 0.2, mu 0.9, no early stop) in <= 30 s on one core (issue 12).

    NUMBA_NUM_THREADS=1 python benchmarks/feeder.py [--E 1e7 1e8] [--seed 1 2 3] [--vibration-time 60]
        [--representation polyhedron clump] [--clogging] [--core-tolerance 0.1 0]

Not a test: timings depend on the machine. ``--vibration-time`` shortens the vibration stage to
extrapolate when the full run is too slow (say so when you report it). ``--core-tolerance``
runs the polyhedra once per value (``items.core_tolerance``: the cores' simplification as a
fraction of the rounding r; 0 keeps every core vertex up to 48, as before session 15), in turn.

A run's CPU time follows the path its pile takes (on one seed the polyhedra took 34-61 s as
rounding changed the path, benchmarks/README session 19), so give several ``--seed``: the
representations run in turn for each seed (alternated, so the machine's load falls on both),
and the last lines give each one's mean and range over the seeds and the ratio of the means.
Each representation is first run once on the workers' tiny warm-up scene (``worker/warmup.py``),
so that no timed run includes the kernels' compile (with a cold cache and a busy machine one
seed took 155.7 s CPU where it takes 57 s warm, benchmarks/README session 21).

The summary prints both of issue 12's figures, with a verdict for the full protocol only: the
ratio of the means with its 90 % bootstrap interval over the seeds (the seeds resampled together
for both representations, since both ran the same seeds; one seed's jam moves a ten-seed mean by
a quarter, so a ratio without its interval says little), and the runs that clogged (status ok,
items in the tray at the end): how many, their mean and largest CPU time against the 30 s goal.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections import defaultdict
from typing import NamedTuple

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from dem.scenarios.feeder import run_feeder  # noqa: E402
from dem.scenarios.feeder_config import FeederConfig, load_feeder_config  # noqa: E402
from worker.warmup import WARMUP_PARAMS, WARMUP_SCENARIO  # noqa: E402

CLOGGING = {"e": 0.2, "mu": 0.9}  # --clogging: items stay on the tray (also benchmarks.profile_engine)
FULL_PROTOCOL = "examples/feeder.toml"  # the goals below are this run's, the whole 65 s
GOAL_RATIO = 1.5  # issue 12: the polyhedra's time at most this many times the clumps'
GOAL_CLOGGED_S = 30.0  # issue 12: a run that clogs, no early stop, one core
BOOTSTRAP_RESAMPLES = 10_000


class Timed(NamedTuple):
    """One timed run: its seed, CPU seconds, items left and whether it ended ``ok``."""

    seed: int
    cpu: float
    n_remaining: int
    ok: bool


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--E", type=float, nargs="+", default=[1e7, 1e8])
    parser.add_argument("--seed", type=int, nargs="+", default=[1])
    parser.add_argument("--vibration-time", type=float, default=None)
    parser.add_argument("--config", default=FULL_PROTOCOL)
    parser.add_argument("--representation", nargs="+", default=["polyhedron", "clump"])
    parser.add_argument("--clogging", action="store_true", help="e 0.2, mu 0.9: items stay")
    parser.add_argument("--core-tolerance", type=float, nargs="+", default=None)
    args = parser.parse_args()
    config = load_feeder_config(args.config)
    if args.vibration_time is not None:
        config.stages.vibration_time = args.vibration_time
    config.run.stop_when_empty = False  # the benchmark times the whole protocol
    params = dict(CLOGGING) if args.clogging else {}
    header = (
        f"{'shape':>10} {'E, Pa':>8} {'wall, s':>8} {'cpu, s':>7} {'sim, s':>7} {'steps':>9} {'dt, s':>9}"
    )
    print(f"{header} {'us/step':>8} {'N_t':>4} status")
    tolerances = args.core_tolerance or [None]  # None: the config's own
    runs = [
        (rep, tol) for rep in args.representation for tol in (tolerances if rep == "polyhedron" else [None])
    ]
    for representation in args.representation:
        _warm(representation)
    timed: dict[tuple[str, float | None, float], list[Timed]] = defaultdict(list)
    for seed in args.seed:
        for representation, tolerance in runs:
            config.items.representation = representation
            if tolerance is not None:
                config.items.core_tolerance = tolerance
            for E in args.E:
                started, cpu = time.perf_counter(), time.process_time()
                r = run_feeder(config, {"E": E, **params}, seed)
                wall, cpu = time.perf_counter() - started, time.process_time() - cpu
                timed[(representation, tolerance, E)].append(Timed(seed, cpu, r.n_remaining, r.ok))
                shape = _label(representation, tolerance)
                print(
                    f"{shape:>10} {E:8.0e} {wall:8.1f} {cpu:7.1f} {r.sim_time:7.2f} {r.steps:9d} "
                    f"{r.dt:9.3g} {1e6 * cpu / max(r.steps, 1):8.1f} {r.n_remaining:4d} {r.status.value} "
                    f"seed {seed} {r.message}",
                    flush=True,
                )
    if len(args.seed) > 1 or len(runs) > 1:
        # The goals are for the paper's protocol: a verdict on a shorter run would mislead.
        judge = args.config == FULL_PROTOCOL and args.vibration_time is None
        _print_means(timed, args.seed, judge)
        _print_clogged(timed, judge)


def _warm(representation: str) -> None:
    """The workers' warm-up scene with these items: the kernels compiled or loaded untimed."""
    scene = {**WARMUP_SCENARIO, "items": {**WARMUP_SCENARIO["items"], "representation": representation}}
    started = time.process_time()
    run_feeder(FeederConfig.model_validate(scene), dict(WARMUP_PARAMS), seed=0)
    seconds = time.process_time() - started
    print(f"# {representation}: kernels warm in {seconds:.1f} s CPU (untimed)", flush=True)


def _label(representation: str, tolerance: float | None) -> str:
    return representation if tolerance is None else f"{representation} {tolerance:g}r"


def _print_means(
    timed: dict[tuple[str, float | None, float], list[Timed]], seeds: list[int], judge: bool = True
) -> None:
    """Each run's CPU time over the seeds, and each representation's against the clumps' (ratio of
    the means over the seeds where both ended ok: a seed's pile path moves both, so a per-seed
    ratio is noisier), with its interval and, when ``judge`` (the full protocol), the verdict
    against ``GOAL_RATIO``."""
    print(f"over seeds {' '.join(map(str, seeds))}: CPU s mean (least-most); against clumps [90 % interval]")
    for (representation, tolerance, E), runs in timed.items():
        cpus = [run.cpu for run in runs]
        clumps = {run.seed: run for run in timed.get(("clump", None, E), [])}
        against = "-"
        if clumps and representation != "clump":
            # A run that stopped (invalid, unstable) did less of the protocol: its seed is left out.
            both = [(run.cpu, clumps[run.seed].cpu) for run in runs if run.ok and clumps[run.seed].ok]
            if both:
                ours, theirs = [pair[0] for pair in both], [pair[1] for pair in both]
                ratio = statistics.mean(ours) / statistics.mean(theirs)
                low, high = ratio_interval(ours, theirs)
                figures = f"{ratio:.2f}x [{low:.2f}-{high:.2f}]"
                used = f"{len(both)} of {len(runs)} seeds, both ok"
                if judge:
                    verdict = _verdict(high <= GOAL_RATIO, low > GOAL_RATIO)
                    used = f"goal <= {GOAL_RATIO}x; {used}"
                    figures = f"{figures} {verdict}"
                against = f"{figures} ({used})"
        elif clumps:
            against = "1.00x"
        shape, mean = _label(representation, tolerance), statistics.mean(cpus)
        print(f"{shape:>10} {E:8.0e} {mean:7.1f} ({min(cpus):.1f}-{max(cpus):.1f}) {against}", flush=True)


def _print_clogged(timed: dict[tuple[str, float | None, float], list[Timed]], judge: bool = True) -> None:
    """The runs that clogged (ended ok with items in the tray) against ``GOAL_CLOGGED_S`` (met when
    the slowest is within it), and how many runs did not end ok (never counted as either)."""
    goal = f"goal: every one <= {GOAL_CLOGGED_S:g} s" if judge else f"no verdict: not {FULL_PROTOCOL} whole"
    print(f"runs that clogged (ok, N_t > 0 at the end): count, CPU s mean and largest ({goal})")
    for (representation, tolerance, E), runs in timed.items():
        clogged = [run.cpu for run in runs if run.ok and run.n_remaining > 0]
        failed = sum(not run.ok for run in runs)
        shape = _label(representation, tolerance)
        tail = f"; {failed} not ok" if failed else ""
        if not clogged:
            print(f"{shape:>10} {E:8.0e} none of {len(runs)}{tail}", flush=True)
            continue
        worst = max(clogged)
        verdict = _verdict(worst <= GOAL_CLOGGED_S, worst > GOAL_CLOGGED_S) if judge else ""
        print(
            f"{shape:>10} {E:8.0e} {len(clogged)} of {len(runs)}: {statistics.mean(clogged):.1f} s, "
            f"largest {worst:.1f} s{' ' + verdict if verdict else ''}{tail}",
            flush=True,
        )


def ratio_interval(cpus: list[float], clumps: list[float], level: float = 0.9) -> tuple[float, float]:
    """The bootstrap interval of mean(cpus) / mean(clumps) over seeds, each resample drawing the
    same seeds for both (the lists are in seed order); a fixed generator, so a rerun prints the
    same interval."""
    a, b = np.asarray(cpus), np.asarray(clumps)
    if len(a) < 2:
        ratio = float(a.mean() / b.mean())
        return ratio, ratio
    draws = np.random.default_rng(0).integers(0, len(a), size=(BOOTSTRAP_RESAMPLES, len(a)))
    ratios = a[draws].mean(axis=1) / b[draws].mean(axis=1)
    tail = 50.0 * (1.0 - level)
    low, high = np.percentile(ratios, [tail, 100.0 - tail])
    return float(low), float(high)


def _verdict(met: bool, missed: bool) -> str:
    return "met" if met else ("NOT met" if missed else "undecided")


if __name__ == "__main__":
    main()
