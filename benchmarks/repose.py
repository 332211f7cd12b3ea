"""Angle of repose against friction, with the built-in engine and with LIGGGHTS on the same case
(the same plate, cylinder, initial spheres and step): mean and standard deviation over seeds.

    python benchmarks/repose.py                       # the quick heap, mu 0.1 / 0.5 / 1.0, 3 seeds
    python benchmarks/repose.py --count 1200 --cylinder 0.16 --plate 0.5 --seeds 2
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dem.engines.base import run_scenario  # noqa: E402
from dem.scenarios import registry  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mu", default="0.1,0.5,1.0")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--engines", default="numba,liggghts")
    parser.add_argument("--count", type=int, default=None, help="Spheres (default: the quick config's).")
    parser.add_argument("--cylinder", type=float, default=None, help="Cylinder diameter, m.")
    parser.add_argument("--plate", type=float, default=None, help="Plate size, m.")
    args = parser.parse_args()

    data = tomllib.loads((Path(__file__).resolve().parent.parent / "examples/repose-quick.toml").read_text())
    if args.count:
        data["particles"]["count"] = args.count
    if args.cylinder:
        data["cylinder"]["diameter"] = args.cylinder
        data["cylinder"]["height"] = max(data["cylinder"]["height"], 0.2)
    if args.plate:
        data["plate"]["size"] = args.plate
    scenario = registry.get("angle_of_repose")
    config = scenario.config(data)
    print(f"{config.particles.count} spheres, cylinder {config.cylinder.diameter} m, E {config.params.E:g}")
    print("| mu | engine | angle mean +- sd (deg) | height (mm) | wall s per run |")
    print("| --- | --- | --- | --- | --- |")
    for mu in (float(m) for m in args.mu.split(",")):
        for engine in args.engines.split(","):
            angles, heights, walls = [], [], []
            for seed in range(args.seeds):
                started = time.monotonic()
                result = run_scenario(scenario, config, {"mu": mu}, seed, engine=engine)
                walls.append(time.monotonic() - started)
                if not result.ok:
                    print(f"  {engine} mu={mu} seed={seed}: {result.status.value} {result.message}")
                    continue
                angles.append(result.responses["angle_deg"])
                heights.append(result.responses["height"])
            each = ", ".join(f"{a:.1f}" for a in angles)
            print(
                f"| {mu:g} | {engine} | {np.mean(angles):.1f} +- {np.std(angles, ddof=1):.1f} ({each}) "
                f"| {1e3 * np.mean(heights):.1f} | {np.mean(walls):.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
