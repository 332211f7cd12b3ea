"""The paper's full protocol (examples/feeder.toml: 30 items, 5 s deposition + 60 s vibration) at
E = 1e7 and 1e8 Pa on one core: wall time, steps, us/step. Goal: <= 60 s wall at E = 1e7 Pa.

    NUMBA_NUM_THREADS=1 python benchmarks/feeder.py [--E 1e7 1e8] [--seed 1] [--vibration-time 60]

Not a test: timings depend on the machine. ``--vibration-time`` shortens the vibration stage to
extrapolate when the full run is too slow (say so when you report it).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from dem.scenarios.feeder import load_feeder_config, run_feeder  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--E", type=float, nargs="+", default=[1e7, 1e8])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--vibration-time", type=float, default=None)
    parser.add_argument("--config", default="examples/feeder.toml")
    args = parser.parse_args()
    config = load_feeder_config(args.config)
    if args.vibration_time is not None:
        config.stages.vibration_time = args.vibration_time
    config.run.stop_when_empty = False  # the benchmark times the whole protocol
    header = f"{'E, Pa':>8} {'wall, s':>8} {'sim, s':>7} {'steps':>9} {'dt, s':>9} {'us/step':>8}"
    print(f"{header} {'N_t':>4} status")
    for E in args.E:
        started = time.perf_counter()
        r = run_feeder(config, {"E": E}, args.seed)
        wall = time.perf_counter() - started
        print(
            f"{E:8.0e} {wall:8.1f} {r.sim_time:7.2f} {r.steps:9d} {r.dt:9.3g} "
            f"{1e6 * wall / max(r.steps, 1):8.1f} {r.n_remaining:4d} {r.status.value} {r.message}",
            flush=True,
        )


if __name__ == "__main__":
    main()
