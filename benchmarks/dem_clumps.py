"""Benchmark: 30 phone-shaped clumps (146 x 71 x 8 mm, 170 g, default clump resolution) shaken
on a plate (issue 3). Prints microseconds per step and spheres per body; goal <= 50 us/step.

    /work/venv/bin/python benchmarks/dem_clumps.py [--time 0.5]

The plate (0.5 x 0.5 m, with 5 cm side walls) vibrates at 60 Hz, 1.5 mm along a line 25 degrees
from the horizontal, as the feeder of the paper; E 1e6 Pa, nu 0.3, e 0.3, mu 0.5.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import trimesh

from dem.clumping import make_clump
from dem.contact import ContactParams
from dem.motion import SinusoidalTranslation
from dem.quaternion import from_axis_angle
from dem.simulation import Simulation
from dem.walls import WallMesh

PARAMS = ContactParams(E=1e6, nu=0.3, e=0.3, mu=0.5)


def build() -> Simulation:
    phone = make_clump(
        trimesh.creation.box(extents=(0.146, 0.071, 0.008)), mass=0.170, name="phone", cache_dir=False
    )
    sim = Simulation(PARAMS, domain_min=(-0.4, -0.4, -0.1), domain_max=(0.4, 0.4, 0.6))
    angle = math.radians(25)
    motion = SinusoidalTranslation((math.cos(angle), 0, math.sin(angle)), 0.0015, 60.0, start_time=0.05)
    sim.add_wall(WallMesh.box((-0.25, -0.25, 0), (0.25, 0.25, 0.05), motion=motion))
    rng = np.random.default_rng(0)
    for k in range(30):
        x = (k % 3 - 1) * 0.16
        y = (k // 3 % 5 - 2) * 0.09
        z = 0.01 + (k // 15) * 0.03
        q = from_axis_angle(rng.normal(size=3), rng.uniform(0, 0.2))
        sim.add_body(phone, (x, y, z + 0.01), quaternion=q)
    return sim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--time", type=float, default=0.5, help="simulated seconds")
    args = parser.parse_args()
    warm = build()
    warm.run(20 * warm.dt)  # JIT compile (or cache load) outside the timing
    sim = build()
    start, cpu_start = time.perf_counter(), time.process_time()
    report = sim.run(args.time, chunk_time=0.01)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    print(
        f"status {report.status}, {report.steps} steps of dt {sim.dt:.3g} s, "
        f"{sim.spheres.n / sim.bodies.n:.0f} spheres per body, {sim.n_builds} list builds"
    )
    print(
        f"wall {1e6 * wall / report.steps:.1f} us/step, CPU {1e6 * cpu / report.steps:.1f} us/step, "
        f"{sim.n_contacts} sphere contacts at the end, cost {sim.cost:.3g}"
    )


if __name__ == "__main__":
    main()
