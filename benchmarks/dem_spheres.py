"""Benchmark (issue 15): spheres settling in a box, demcal against LIGGGHTS 3.8 with the same
contact constants, runs alternated in one invocation. Prints each engine's particle-steps per
second (wall and CPU) and the ratio demcal / LIGGGHTS (above 1: demcal is faster), and the
physical result of both (bed height: mean and 95th percentile of the sphere centres' z).

    NUMBA_NUM_THREADS=1 python benchmarks/dem_spheres.py [--n 1000 10000] [--steps 100000] [--repeats 1]

Case: spheres d = 10 mm, 2,500 kg/m3 on a jittered cubic lattice of pitch 12 mm (jitter
U(+-0.9 mm), numpy default_rng(1000)), 8 x 8 x 16 = 1,024 spheres in a 0.1 x 0.1 m box, or
26 x 26 x 15 = 10,140 in 0.3162 x 0.3162 m (floor and four side walls, no lid); g = 9.81; dt 1e-5 s.
LIGGGHTS: ``model hooke tangential history limitForce on``, E 1e7, nu 0.3, e 0.5, mu 0.5,
characteristicVelocity 1 m/s, ``neighbor 0.002 bin``, walls as planes; demcal gets the materials
that give the same kn, kt, gamma_n, gamma_t (``benchmarks/liggghts.py`` says how; the mapping is
printed with its largest relative difference). LIGGGHTS' time includes its start-up (< 0.1 s).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import liggghts  # noqa: E402
import numpy as np  # noqa: E402

from dem.clump import Clump  # noqa: E402
from dem.simulation import Simulation  # noqa: E402
from dem.walls import WallMesh  # noqa: E402

D, RHO, DT, PITCH, JITTER = 0.010, 2500.0, 1e-5, 0.012, 0.0009
E, NU, E_REST, MU = 1e7, 0.3, 0.5, 0.5
CASES = {1000: (8, 16, 0.1), 10000: (26, 15, 0.3162)}  # spheres per side, layers, box side
SKIN = 0.002  # the Verlet skin of both engines (LIGGGHTS' ``neighbor 0.002 bin``)
MAP = liggghts.mapping(E, NU, E_REST, MU, D, RHO)


def lattice(n_side: int, layers: int) -> np.ndarray:
    rng = np.random.default_rng(1000)
    i, j, k = np.meshgrid(np.arange(n_side), np.arange(n_side), np.arange(layers), indexing="ij")
    x = (i.ravel(order="F") - (n_side - 1) / 2) * PITCH
    y = (j.ravel(order="F") - (n_side - 1) / 2) * PITCH
    z = D / 2 + 0.001 + k.ravel(order="F") * PITCH
    return np.stack([x, y, z], axis=1) + rng.uniform(-JITTER, JITTER, size=(len(x), 3))


def bed(z: np.ndarray) -> str:
    return f"bed height mean {1000 * z.mean():.2f} mm, 95th percentile {1000 * np.percentile(z, 95):.2f} mm"


def build(n: int, skin: float | None = SKIN) -> Simulation:
    n_side, layers, box = CASES[n]
    half = box / 2
    sim = Simulation(
        MAP.particles,
        domain_min=(-half - 0.01, -half - 0.01, -0.01),
        domain_max=(half + 0.01, half + 0.01, 0.4),
        dt=DT,
        skin=skin,
    )
    sim.add_wall(WallMesh.box((-half, -half, 0), (half, half, 0.4), material=MAP.wall))
    ball = Clump.solid_sphere(D / 2, RHO)
    for p in lattice(n_side, layers):
        sim.add_body(ball, p)
    return sim


def run_demcal(n: int, steps: int) -> tuple[float, float, str]:
    warm = build(n)
    warm.run(10 * DT)  # JIT compile (or load from the cache) outside the timing
    sim = build(n)
    start, cpu_start = time.perf_counter(), time.process_time()
    report = sim.run(steps * DT, chunk_time=0.01)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    assert report.ok, report.message
    return wall, cpu, f"{bed(sim.bodies.pos[:, 2])}; {sim.n_builds} list builds"


LIGGGHTS_INPUT = """{header}{materials}
timestep {dt}
fix gravi all gravity 9.81 vector 0.0 0.0 -1.0
fix floor all wall/gran model hooke tangential history primitive type 1 zplane 0.0 limitForce on
fix xlo all wall/gran model hooke tangential history primitive type 1 xplane {lo} limitForce on
fix xhi all wall/gran model hooke tangential history primitive type 1 xplane {hi} limitForce on
fix ylo all wall/gran model hooke tangential history primitive type 1 yplane {lo} limitForce on
fix yhi all wall/gran model hooke tangential history primitive type 1 yplane {hi} limitForce on
fix integr all nve/sphere
thermo 10000
dump final all custom {steps} final.dump id x y z
run {steps}
"""


def run_liggghts(executable: str, n: int, steps: int) -> tuple[float, float, str]:
    n_side, layers, box = CASES[n]
    half = box / 2
    with tempfile.TemporaryDirectory() as tmp:
        positions = lattice(n_side, layers)
        lines = ["LIGGGHTS data", "", f"{len(positions)} atoms", "1 atom types", ""]
        lines += [
            f"{-half - 0.01} {half + 0.01} xlo xhi",
            f"{-half - 0.01} {half + 0.01} ylo yhi",
            "-0.01 0.4 zlo zhi",
        ]
        lines += ["", "Atoms", ""]
        lines += [f"{i + 1} 1 {D} {RHO} {x:.17g} {y:.17g} {z:.17g}" for i, (x, y, z) in enumerate(positions)]
        Path(tmp, "atoms.data").write_text("\n".join(lines) + "\n")
        materials = liggghts.MATERIAL_COMMANDS.format(E=E, nu=NU, e=E_REST, mu=MU, v_char=1.0)
        text = LIGGGHTS_INPUT.format(
            header=liggghts.header(SKIN),
            materials=materials,
            dt=DT,
            lo=-half,
            hi=half,
            steps=steps,
        )
        Path(tmp, "in.bench").write_text(text)
        timed = liggghts.run(executable, Path(tmp), "in.bench")
        z = np.array([row[3] for row in liggghts.read_last_dump(Path(tmp, "final.dump"))])
    return timed.wall, timed.cpu, bed(z)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, nargs="+", default=[1000, 10000], choices=sorted(CASES))
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=1, help="pairs of alternated runs per case")
    args = parser.parse_args()
    print(MAP.describe())
    executable = liggghts.executable()
    if executable is None:
        print("LIGGGHTS: not on PATH (apt-get install liggghts); demcal only")
    for n in args.n:
        n_side, layers, _ = CASES[n]
        count = n_side * n_side * layers
        work = count * args.steps
        ours, theirs = [], []
        for _ in range(args.repeats):
            for engine, runner, times in (("demcal", run_demcal, ours), ("LIGGGHTS", run_liggghts, theirs)):
                if engine == "LIGGGHTS" and executable is None:
                    continue
                wall, cpu, physics = (
                    runner(n, args.steps) if engine == "demcal" else runner(executable, n, args.steps)
                )
                times.append((wall, cpu))
                print(
                    f"{count:6d} spheres {engine:8s}: {args.steps} steps, wall {wall:7.1f} s "
                    f"({work / wall:.3g} particle-steps/s), CPU {cpu:7.1f} s ({work / cpu:.3g}); {physics}",
                    flush=True,
                )
        if theirs:
            wall_ratio = sum(t[0] for t in theirs) / sum(t[0] for t in ours)
            cpu_ratio = sum(t[1] for t in theirs) / sum(t[1] for t in ours)
            print(
                f"{count:6d} spheres ratio demcal / LIGGGHTS throughput: "
                f"wall {wall_ratio:.2f}, CPU {cpu_ratio:.2f}"
            )


if __name__ == "__main__":
    main()
