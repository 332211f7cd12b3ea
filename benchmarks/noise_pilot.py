"""Noise pilot: N_t over seeds at one parameter set on the quick feeder config, so that the
optimiser can choose its replicates (the seed changes item shapes, positions and orientations).

    NUMBA_NUM_THREADS=1 python benchmarks/noise_pilot.py [--seeds 10] [--E 1e7 --mu 0.5 --e 0.5]
"""

from __future__ import annotations

import argparse
import statistics
import time

from dem.scenarios.feeder import run_feeder
from dem.scenarios.feeder_config import load_feeder_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="examples/feeder-quick.toml")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--E", type=float, default=1e7)
    parser.add_argument("--nu", type=float, default=0.3)
    parser.add_argument("--e", type=float, default=0.5)
    parser.add_argument("--mu", type=float, default=0.5)
    args = parser.parse_args()
    config = load_feeder_config(args.config)
    params = {"E": args.E, "nu": args.nu, "e": args.e, "mu": args.mu}
    values = []
    for seed in range(args.seeds):
        started = time.perf_counter()
        r = run_feeder(config, params, seed)
        values.append(r.n_remaining)
        last = max((t for t in r.discharge_times if t is not None), default=float("nan"))
        print(
            f"seed {seed:2d}: N_t = {r.n_remaining}/{r.n_items}, last discharge {last:.2f} s, "
            f"{r.status.value}, {time.perf_counter() - started:.1f} s wall",
            flush=True,
        )
    print(f"params {params}, {args.config}")
    print(
        f"N_t mean {statistics.mean(values):.2f}, sd {statistics.stdev(values):.2f}, "
        f"min {min(values)}, max {max(values)}, values {values}"
    )


if __name__ == "__main__":
    main()
