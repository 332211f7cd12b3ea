"""Benchmark: 1000 spheres poured into a box (issue 3). Prints wall time (JIT excluded) and
particle-steps per second; runs the same case in LIGGGHTS (``model hooke``) when ``liggghts`` is on
PATH, and prints the ratio.

    /work/venv/bin/python benchmarks/dem_spheres.py [--steps 100000]

Case: d 10 mm, 2500 kg/m3, E 1e7 Pa, nu 0.3, e 0.5, mu 0.5, box 0.1 x 0.1 m, dt 1e-5 s fixed.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from dem.clump import Clump
from dem.contact import ContactParams
from dem.simulation import Simulation
from dem.walls import WallMesh

N, D, RHO, DT = 1000, 0.010, 2500.0, 1e-5
PARAMS = ContactParams(E=1e7, nu=0.3, e=0.5, mu=0.5)
BOX = 0.1


def initial_positions(seed: int = 0) -> np.ndarray:
    """A jittered lattice above the box floor: 9 x 9 per layer, 11.1 mm apart."""
    rng = np.random.default_rng(seed)
    spacing = 0.0111
    per_side = 9
    k = np.arange(N)
    x = (k % per_side - (per_side - 1) / 2) * spacing
    y = (k // per_side % per_side - (per_side - 1) / 2) * spacing
    z = D / 2 + 0.001 + (k // per_side**2) * spacing
    return np.stack([x, y, z], axis=1) + rng.uniform(-5e-4, 5e-4, size=(N, 3))


def build() -> Simulation:
    ball = Clump.solid_sphere(D / 2, RHO)
    sim = Simulation(PARAMS, domain_min=(-0.06, -0.06, -0.01), domain_max=(0.06, 0.06, 0.3), dt=DT)
    sim.add_wall(WallMesh.box((-BOX / 2, -BOX / 2, 0), (BOX / 2, BOX / 2, 0.3)))
    for p in initial_positions():
        sim.add_body(ball, p)
    return sim


def run_ours(steps: int) -> float:
    warm = build()
    warm.run(10 * DT)  # JIT compile (or load from cache) outside the timing
    sim = build()
    start, cpu_start = time.perf_counter(), time.process_time()
    report = sim.run(steps * DT, chunk_time=0.01)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    assert report.ok, report.message
    # CPU time as well: on a shared machine the wall time includes other processes' turns.
    print(
        f"demcal:   {steps} steps, wall {wall:.2f} s ({N * steps / wall:.3g} particle-steps/s), "
        f"CPU {cpu:.2f} s ({N * steps / cpu:.3g} particle-steps/s), "
        f"{sim.n_builds} list builds, {sim.n_contacts} contacts at the end, "
        f"mean height {sim.bodies.pos[:, 2].mean() * 1000:.1f} mm"
    )
    return wall


LIGGGHTS_INPUT = """
atom_style granular
atom_modify map array
boundary f f f
newton off
communicate single vel yes
units si
read_data atoms.data
neighbor 0.002 bin
neigh_modify delay 0
fix m1 all property/global youngsModulus peratomtype 1e7
fix m2 all property/global poissonsRatio peratomtype 0.3
fix m3 all property/global coefficientRestitution peratomtypepair 1 0.5
fix m4 all property/global coefficientFriction peratomtypepair 1 0.5
fix m5 all property/global characteristicVelocity scalar 1.0
pair_style gran model hooke tangential history
pair_coeff * *
timestep 1e-5
fix gravi all gravity 9.81 vector 0.0 0.0 -1.0
fix floor all wall/gran model hooke tangential history primitive type 1 zplane 0.0
fix xlo all wall/gran model hooke tangential history primitive type 1 xplane -0.05
fix xhi all wall/gran model hooke tangential history primitive type 1 xplane 0.05
fix ylo all wall/gran model hooke tangential history primitive type 1 yplane -0.05
fix yhi all wall/gran model hooke tangential history primitive type 1 yplane 0.05
fix integr all nve/sphere
thermo 10000
run {steps}
"""


def run_liggghts(executable: str, steps: int) -> float | None:
    with tempfile.TemporaryDirectory() as tmp:
        positions = initial_positions()
        lines = [
            "LIGGGHTS data",
            "",
            f"{N} atoms",
            "1 atom types",
            "",
            "-0.06 0.06 xlo xhi",
            "-0.06 0.06 ylo yhi",
            "-0.01 0.3 zlo zhi",
            "",
            "Atoms",
            "",
        ]
        lines += [f"{i + 1} 1 {D} {RHO} {x} {y} {z}" for i, (x, y, z) in enumerate(positions)]
        Path(tmp, "atoms.data").write_text("\n".join(lines) + "\n")
        Path(tmp, "in.bench").write_text(LIGGGHTS_INPUT.format(steps=steps))
        start = time.perf_counter()
        cpu_start = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
        done = subprocess.run(
            [executable, "-in", "in.bench"], cwd=tmp, capture_output=True, text=True, errors="replace"
        )
        wall = time.perf_counter() - start
        cpu = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - cpu_start
        if done.returncode != 0:
            print("LIGGGHTS failed:", done.stdout[-2000:], done.stderr[-2000:])
            return None
        print(
            f"LIGGGHTS: {steps} steps, wall {wall:.2f} s ({N * steps / wall:.3g} particle-steps/s), "
            f"CPU {cpu:.2f} s ({N * steps / cpu:.3g} particle-steps/s), start-up included"
        )
        return wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=100_000)
    args = parser.parse_args()
    ours = run_ours(args.steps)
    executable = shutil.which("liggghts") or shutil.which("lmp_auto")
    if executable is None:
        print("LIGGGHTS: not on PATH (apt-get install liggghts); no comparison")
        return
    theirs = run_liggghts(executable, args.steps)
    if theirs is not None:
        print(f"ratio demcal / LIGGGHTS wall time: {ours / theirs:.2f}")


if __name__ == "__main__":
    main()
