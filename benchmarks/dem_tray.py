"""Benchmark (issue 15): 300 spheres on a shaken open tray of mesh walls (the feeder in
miniature), demcal against LIGGGHTS 3.8 with the same contact constants, runs alternated in one
invocation. Prints each engine's particle-steps per second (wall and CPU; particle-steps counted
with the spheres still in the domain at each step), the ratio demcal / LIGGGHTS (above 1: demcal
is faster), and the physical result of both: the spheres still on the tray every 0.1 s.

    NUMBA_NUM_THREADS=1 python benchmarks/dem_tray.py [--time 2.0] [--repeats 1]

Case: a 0.3 x 0.1 m floor with side walls and a back wall 0.1 m high (8 triangles), open at
x = 0.3 m, moving as A sin(2 pi 60 t) along (cos 25 deg, 0, sin 25 deg) with A = 1.5 mm; 300
spheres d = 10 mm, 2,500 kg/m3, the first 300 sites (layer by layer) of a 12 x 8 x 4 lattice of
pitch 12 mm in x < 0.15 m, jitter U(+-0.9 mm) from numpy default_rng(1000); g = 9.81; dt 1e-5 s;
spheres are deleted below z = -0.05 m (the domain's floor in both engines). Contact constants as
in ``benchmarks/dem_spheres.py`` (``benchmarks/liggghts.py``: E 1e7, nu 0.3, e 0.5, mu 0.5 in
LIGGGHTS ``model hooke``, and the demcal materials with the same kn, kt, gamma_n, gamma_t).
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import liggghts  # noqa: E402
import numpy as np  # noqa: E402

from dem.clump import Clump  # noqa: E402
from dem.engines.liggghts import write_stl  # noqa: E402
from dem.motion import SinusoidalTranslation  # noqa: E402
from dem.simulation import Simulation  # noqa: E402
from dem.walls import WallMesh  # noqa: E402

D, RHO, DT, PITCH, JITTER, N = 0.010, 2500.0, 1e-5, 0.012, 0.0009, 300
E, NU, E_REST, MU = 1e7, 0.3, 0.5, 0.5
LENGTH, WIDTH, HEIGHT = 0.3, 0.1, 0.1
AMPLITUDE, FREQUENCY, ANGLE = 1.5e-3, 60.0, math.radians(25.0)
DOMAIN_LO, DOMAIN_HI = (-0.02, -0.02, -0.05), (0.5, 0.12, 0.2)
REPORT_EVERY = 0.1  # s
SKIN = 0.002  # the Verlet skin of both engines (as in benchmarks/dem_spheres.py)
MAP = liggghts.mapping(E, NU, E_REST, MU, D, RHO)


def tray() -> tuple[np.ndarray, np.ndarray]:
    """The tray's 8 triangles: floor, two sides, back wall; open at x = LENGTH and on top."""
    L, W, H = LENGTH, WIDTH, HEIGHT
    vertices = np.array(
        [[0, 0, 0], [L, 0, 0], [L, W, 0], [0, W, 0], [0, 0, H], [L, 0, H], [L, W, H], [0, W, H]], dtype=float
    )
    faces = np.array(
        [[0, 1, 2], [0, 2, 3], [0, 1, 5], [0, 5, 4], [3, 2, 6], [3, 6, 7], [0, 3, 7], [0, 7, 4]],
        dtype=np.int64,
    )
    return vertices, faces


def lattice() -> np.ndarray:
    rng = np.random.default_rng(1000)
    k, j, i = np.meshgrid(np.arange(4), np.arange(8), np.arange(12), indexing="ij")
    x = 0.008 + i.ravel() * PITCH
    y = WIDTH / 2 + (j.ravel() - 3.5) * PITCH
    z = D / 2 + 0.001 + k.ravel() * PITCH
    points = np.stack([x, y, z], axis=1) + rng.uniform(-JITTER, JITTER, size=(len(x), 3))
    return points[:N]


def direction() -> tuple[float, float, float]:
    return (math.cos(ANGLE), 0.0, math.sin(ANGLE))


def run_demcal(duration: float) -> tuple[float, float, float, list[int]]:
    def build() -> Simulation:
        sim = Simulation(MAP.particles, domain_min=DOMAIN_LO, domain_max=DOMAIN_HI, dt=DT, skin=SKIN)
        motion = SinusoidalTranslation(direction(), AMPLITUDE, FREQUENCY)
        vertices, faces = tray()
        sim.add_wall(WallMesh(vertices, faces, material=MAP.wall, motion=motion, name="tray"))
        ball = Clump.solid_sphere(D / 2, RHO)
        for p in lattice():
            sim.add_body(ball, p)
        return sim

    warm = build()
    warm.run(10 * DT)  # JIT compile (or load from the cache) outside the timing
    sim = build()
    on_tray = [N]
    particle_steps = 0.0
    start, cpu_start = time.perf_counter(), time.process_time()
    for k in range(1, round(duration / REPORT_EVERY) + 1):
        before = sim.steps
        n_before = int(sim.bodies.active.sum())
        report = sim.run(k * REPORT_EVERY, chunk_time=0.01)
        assert report.ok, report.message
        n_after = int(sim.bodies.active.sum())
        particle_steps += 0.5 * (n_before + n_after) * (sim.steps - before)
        on_tray.append(n_after)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    return wall, cpu, particle_steps, on_tray


LIGGGHTS_INPUT = """{header}{materials}
timestep {dt}
fix gravi all gravity 9.81 vector 0.0 0.0 -1.0
fix tray all mesh/surface file tray.stl type 1
fix walls all wall/gran model hooke tangential history mesh n_meshes 1 meshes tray limitForce on
fix shake all move/mesh mesh tray wiggle amplitude {ax!r} 0.0 {az!r} period {period!r}
fix integr all nve/sphere
thermo_style custom step atoms
thermo {report}
thermo_modify lost ignore norm no
run {steps}
"""


def run_liggghts(executable: str, duration: float) -> tuple[float, float, float, list[int]]:
    steps = round(duration / DT)
    report = round(REPORT_EVERY / DT)
    with tempfile.TemporaryDirectory() as tmp:
        lines = ["LIGGGHTS data", "", f"{N} atoms", "1 atom types", ""]
        lines += [
            f"{lo:.17g} {hi:.17g} {a}lo {a}hi" for lo, hi, a in zip(DOMAIN_LO, DOMAIN_HI, "xyz", strict=True)
        ]
        lines += ["", "Atoms", ""]
        lines += [f"{i + 1} 1 {D} {RHO} {x:.17g} {y:.17g} {z:.17g}" for i, (x, y, z) in enumerate(lattice())]
        Path(tmp, "atoms.data").write_text("\n".join(lines) + "\n")
        write_stl(Path(tmp, "tray.stl"), *tray(), "tray")
        materials = liggghts.MATERIAL_COMMANDS.format(E=E, nu=NU, e=E_REST, mu=MU, v_char=1.0)
        ux, _, uz = direction()
        text = LIGGGHTS_INPUT.format(
            header=liggghts.header(SKIN),
            materials=materials,
            dt=DT,
            ax=AMPLITUDE * ux,
            az=AMPLITUDE * uz,
            period=1.0 / FREQUENCY,
            report=report,
            steps=steps,
        )
        Path(tmp, "in.tray").write_text(text)
        timed = liggghts.run(executable, Path(tmp), "in.tray")
    on_tray = []
    for line in timed.stdout.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0].isdigit() and parts[1].isdigit() and int(parts[0]) % report == 0:
            on_tray.append(int(parts[1]))
    # Atoms are counted at the reports; between them the count is taken as linear.
    particle_steps = sum(0.5 * (a + b) * report for a, b in zip(on_tray, on_tray[1:], strict=False))
    return timed.wall, timed.cpu, particle_steps, on_tray


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time", type=float, default=2.0, help="simulated seconds")
    parser.add_argument("--repeats", type=int, default=1, help="pairs of alternated runs")
    args = parser.parse_args()
    print(MAP.describe())
    executable = liggghts.executable()
    if executable is None:
        print("LIGGGHTS: not on PATH (apt-get install liggghts); demcal only")
    results: dict[str, list[tuple[float, float, float]]] = {"demcal": [], "LIGGGHTS": []}
    for _ in range(args.repeats):
        for engine in ("demcal", "LIGGGHTS"):
            if engine == "LIGGGHTS" and executable is None:
                continue
            if engine == "demcal":
                wall, cpu, work, on_tray = run_demcal(args.time)
            else:
                wall, cpu, work, on_tray = run_liggghts(executable, args.time)
            results[engine].append((wall, cpu, work))
            print(
                f"{engine:8s}: {args.time:g} s, wall {wall:6.1f} s ({work / wall:.3g} particle-steps/s), "
                f"CPU {cpu:6.1f} s ({work / cpu:.3g}); spheres on the tray every {REPORT_EVERY:g} s: "
                f"{' '.join(map(str, on_tray))}",
                flush=True,
            )
    if results["LIGGGHTS"]:
        ours, theirs = results["demcal"], results["LIGGGHTS"]
        wall = (sum(r[2] for r in ours) / sum(r[0] for r in ours)) / (
            sum(r[2] for r in theirs) / sum(r[0] for r in theirs)
        )
        cpu = (sum(r[2] for r in ours) / sum(r[1] for r in ours)) / (
            sum(r[2] for r in theirs) / sum(r[1] for r in theirs)
        )
        print(f"ratio demcal / LIGGGHTS throughput: wall {wall:.2f}, CPU {cpu:.2f}")


if __name__ == "__main__":
    main()
