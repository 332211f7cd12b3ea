r"""LIGGGHTS as an engine: write the input from the scenario and the parameters, run ``liggghts``,
read the responses and the run's time back.

The contact law mapped onto LIGGGHTS (``pair_style gran model hooke/stiffness tangential history
limitForce on``, the same model in ``fix wall/gran``), so that both engines integrate the same
forces (``dem/contact.py`` is the reference):

* every sphere size class is an atom type 1..n, the walls are type n + 1 (plate and cylinder are
  written as STL meshes, the same triangles the built-in engine uses);
* ``kn`` (type pair i, j) = ``normal_stiffness(E, D_i, E, D_j)`` = E D_i D_j / (D_i + D_j), and
  against a wall ``wall_stiffness(E, D_i, E)`` = E D_i / 2: Young's modulus enters through our
  linear law's K = E D / 2, not through LIGGGHTS' Hertz ``youngsModulus``;
* ``kt`` = ``tangential_stiffness_ratio(nu)`` x ``kn`` = 2 (1 - nu) / (2 - nu) x ``kn``: Poisson's
  ratio acts only through this ratio, as in ours;
* ``gamman`` = 2 zeta sqrt(kn / m*) and ``gammat`` = 2 zeta sqrt(kt / m*) with ``absolute_damping
  off`` (LIGGGHTS multiplies them by m*, giving our C = 2 zeta sqrt(K m*)), m* the pair's reduced
  mass (the sphere's own mass against a wall), zeta = ``damping_ratio(e)``, the restitution
  corrected for the no-attraction clamp, which ``limitForce on`` reproduces;
* ``coefficientFriction`` = mu for every pair; Coulomb's cap acts on the tangential spring as in
  ours (``tangential history``); no rolling friction in either engine.

The walls are of the items' material: a study or run naming an item-wall parameter is refused
(``parameters``): plate and cylinder are one atom type here, and giving that type its own
material with a pair per sphere type is not written yet (the built-in engine gives plate and
cylinder the wall material).

Scenarios reach LIGGGHTS through an adapter (``ADAPTERS``, keyed by scenario kind) that writes
the case's files and reads its responses back. To add one: a class with ``refuses(config)``,
``write(folder, config, params, seed) -> LiggghtsCase`` and ``read(folder, config, case) ->
responses``, registered in ``ADAPTERS``, and the scenario lists ``"liggghts"`` in its engines.
The binary is ``liggghts`` on the PATH, or ``options["binary"]`` / ``DEMCAL_LIGGGHTS``.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dem.contact import damping_ratio, normal_stiffness, tangential_stiffness_ratio, wall_stiffness
from dem.engines.base import parameters_refusal
from dem.engines.process import run_process
from dem.parameters import PARAMETER_NAMES
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.base import RunControl, Scenario, merged_params


@dataclass(frozen=True)
class LiggghtsCase:
    """What an adapter wrote: the input file's name, the time step and how many steps at most."""

    input_name: str
    dt: float
    n_atoms: int


def binary(options: dict[str, Any] | None = None) -> str | None:
    name = (options or {}).get("binary") or os.environ.get("DEMCAL_LIGGGHTS") or "liggghts"
    return shutil.which(name)


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray, name: str) -> None:
    """An ASCII STL of a triangle mesh (LIGGGHTS' ``fix mesh/surface`` reads it)."""
    lines = [f"solid {name}"]
    for tri in np.asarray(vertices)[np.asarray(faces)]:
        normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        length = np.linalg.norm(normal)
        normal = normal / length if length > 0 else normal
        lines.append(f"  facet normal {normal[0]:.9e} {normal[1]:.9e} {normal[2]:.9e}")
        lines.append("    outer loop")
        lines += [f"      vertex {x:.9e} {y:.9e} {z:.9e}" for x, y, z in tri]
        lines += ["    endloop", "  endfacet"]
    lines.append(f"endsolid {name}")
    path.write_text("\n".join(lines) + "\n")


def input_header(skin: float) -> str:
    """The start of every LIGGGHTS input demcal writes (the engine's and the benchmarks'):
    granular atoms from ``atoms.data``, one process, SI units, a binned neighbour list."""
    return f"""atom_style granular
atom_modify map array
boundary f f f
newton off
communicate single vel yes
units si
read_data atoms.data
neighbor {skin:.9g} bin
neigh_modify delay 0"""


def material_fixes(params: dict[str, float], diameters: np.ndarray, masses: np.ndarray) -> str:
    """The ``fix property/global`` lines of the hooke/stiffness model for sphere types 1..n and
    the wall type n + 1 (see the module docstring for the mapping)."""
    n = len(diameters)
    E, zeta = params["E"], damping_ratio(params["e"])
    ratio = tangential_stiffness_ratio(params["nu"])
    kn = np.zeros((n + 1, n + 1))
    meff = np.zeros((n + 1, n + 1))
    for i in range(n + 1):
        for j in range(n + 1):
            if i < n and j < n:
                kn[i, j] = normal_stiffness(E, diameters[i], E, diameters[j])
                meff[i, j] = masses[i] * masses[j] / (masses[i] + masses[j])
            elif i < n or j < n:
                k = i if i < n else j
                kn[i, j] = wall_stiffness(E, diameters[k], E)
                meff[i, j] = masses[k]
            else:  # wall against wall never happens; LIGGGHTS still wants a value
                kn[i, j], meff[i, j] = kn[0, 0], meff[0, 0]
    kt = ratio * kn
    gamman = 2 * zeta * np.sqrt(kn / meff)
    gammat = 2 * zeta * np.sqrt(kt / meff)
    friction = np.full((n + 1, n + 1), params["mu"])

    def fix(name: str, keyword: str, values: np.ndarray) -> str:
        flat = " ".join(f"{v:.12g}" for v in values.ravel())
        return f"fix {name} all property/global {keyword} peratomtypepair {n + 1} {flat}"

    return "\n".join(
        [
            fix("m_kn", "kn", kn),
            fix("m_kt", "kt", kt),
            fix("m_gn", "gamman", gamman),
            fix("m_gt", "gammat", gammat),
            fix("m_mu", "coefficientFriction", friction),
        ]
    )


# LIGGGHTS is an MPI program; run alone it is an Open MPI "singleton", which forks an orted daemon
# unless isolated. Isolated, several runs side by side (a worker pool) cannot disturb each other.
MPI_ENV = {"OMPI_MCA_ess_singleton_isolated": "1"}

CONTACT_MODEL = "model hooke/stiffness tangential history"
MODEL_SETTINGS = "limitForce on"


def read_dump(path: Path) -> dict[str, np.ndarray]:
    """A ``dump custom`` file's last frame as columns by name."""
    lines = path.read_text(errors="replace").splitlines()
    start = max(i for i, line in enumerate(lines) if line.startswith("ITEM: ATOMS"))
    names = lines[start].split()[2:]
    rows = [line.split() for line in lines[start + 1 :] if line.strip()]
    data = np.array(rows, dtype=float).reshape(-1, len(names))
    return {name: data[:, k] for k, name in enumerate(names)}


def loop_steps(log: str) -> int:
    """Steps run: the sum of N over LIGGGHTS' 'Loop time of X on P procs for N steps' lines."""
    steps = 0
    for line in log.splitlines():
        if line.startswith("Loop time of"):
            words = line.split()
            steps += int(words[words.index("for") + 1])
    return steps


class LiggghtsEngine:
    name = "liggghts"
    # Its walls are one atom type of the items' material: no item-wall parameters yet.
    parameters = PARAMETER_NAMES

    def unavailable(self, options=None) -> str:
        if binary(options) is None:
            return (
                "LIGGGHTS is not installed here (no 'liggghts' on the PATH; Debian: apt-get install liggghts)"
            )
        return ""

    def refuses(self, scenario: Scenario, config, options=None) -> str:
        adapter = ADAPTERS.get(scenario.kind)
        if adapter is None:
            return f"no LIGGGHTS adapter for scenario {scenario.kind!r}"
        return adapter().refuses(config)

    def run(self, scenario: Scenario, config, params, seed: int, control: RunControl, options=None):
        started = time.monotonic()
        checked, problem = merged_params(config.params, params)
        base = {"seed": seed, "params": checked, "engine": self.name}
        problem = problem or parameters_refusal(self.name, checked)
        if problem:
            return SimulationResult(status=SimulationStatus.ERROR, message=problem, **base)
        adapter = ADAPTERS[scenario.kind]()
        keep = (options or {}).get("keep_dir")
        with tempfile.TemporaryDirectory(prefix="demcal-liggghts-") as tmp:
            folder = Path(keep) if keep else Path(tmp)
            folder.mkdir(parents=True, exist_ok=True)
            case = adapter.write(folder, config, checked, seed)
            command = [
                binary(options) or "liggghts",
                "-in",
                case.input_name,
                "-log",
                "log.liggghts",
                "-echo",
                "none",
                "-nocite",
            ]
            status, message = run_process(command, folder, control, env=MPI_ENV)
            log = (
                (folder / "log.liggghts").read_text(errors="replace")
                if (folder / "log.liggghts").exists()
                else ""
            )
            steps = loop_steps(log)
            responses = {r.name: None for r in scenario.responses}
            if status is SimulationStatus.OK:
                try:
                    responses = adapter.read(folder, config, case)
                except Exception as exc:
                    status, message = SimulationStatus.ERROR, f"could not read LIGGGHTS' output: {exc}"
            elif not message:
                message = "LIGGGHTS failed: " + " | ".join(log.strip().splitlines()[-3:])
        return SimulationResult(
            status=status,
            message=message,
            n_items=case.n_atoms,
            responses=responses,
            sim_time=steps * case.dt,
            wall_time_s=time.monotonic() - started,
            steps=steps,
            dt=case.dt,
            cost=float(steps * case.n_atoms),
            **base,
        )


# -- adapters ----------------------------------------------------------------------------------------


class HeapAdapter:
    """The angle of repose (``dem/scenarios/heap.py``) with spheres: same plate, cylinder, initial
    lattice and step as the built-in engine; the heap is fitted by the same ``fit_heap``."""

    def refuses(self, config) -> str:
        if config.particles.shape != "spheres":
            return "LIGGGHTS runs the angle of repose with spheres only (particles.shape = 'spheres')"
        return ""

    def write(self, folder: Path, config, params: dict[str, float], seed: int) -> LiggghtsCase:
        from dem.scenarios import heap

        packing = heap.sphere_packing(config, seed)
        geometry = heap.heap_geometry(config, packing.column)
        diameters = config.particles.diameters()
        masses = config.particles.density * math.pi * diameters**3 / 6
        dt = heap.time_step(config, params)
        write_stl(folder / "plate.stl", geometry.plate_vertices, geometry.plate_faces, "plate")
        write_stl(folder / "cylinder.stl", geometry.cylinder_vertices, geometry.cylinder_faces, "cylinder")
        half = 0.5 * config.plate.size + 0.1
        depth = config.plate.roughness * config.particles.diameter
        top = config.cylinder.height + geometry.lift_distance + 0.1
        wall = len(diameters) + 1
        atoms = [
            f"{k + 1} {c + 1} {diameters[c]:.12g} {config.particles.density:.12g} {x:.12g} {y:.12g} {z:.12g}"
            for k, ((x, y, z), c) in enumerate(zip(packing.positions, packing.size_class, strict=True))
        ]
        (folder / "atoms.data").write_text(
            "\n".join(
                [
                    "demcal angle of repose",
                    "",
                    f"{len(atoms)} atoms",
                    f"{wall} atom types",
                    "",
                    f"{-half:.9g} {half:.9g} xlo xhi",
                    f"{-half:.9g} {half:.9g} ylo yhi",
                    f"{-0.05 - depth:.9g} {top:.9g} zlo zhi",
                    "",
                    "Atoms",
                    "",
                    *atoms,
                    "",
                ]
            )
        )
        chunk = max(1, int(round(config.run.chunk_time / dt)))
        settle = int(math.ceil(config.stages.lift_start / dt))
        lift = int(math.ceil(geometry.lift_distance / config.cylinder.lift_speed / dt))
        remaining = max(0, int(math.ceil(config.stages.max_time / dt)) - settle - lift)
        skin = 0.5 * diameters[-1]
        script = f"""# demcal: angle of repose (dem/scenarios/heap.py) for LIGGGHTS, seed {seed}
# E={params["E"]:.6g} nu={params["nu"]:.6g} e={params["e"]:.6g} mu={params["mu"]:.6g}
{input_header(skin)}
{material_fixes(params, diameters, masses)}
pair_style gran {CONTACT_MODEL} {MODEL_SETTINGS}
pair_coeff * *
timestep {dt:.12g}
fix gravity all gravity {heap.GRAVITY} vector 0.0 0.0 -1.0
fix plate all mesh/surface file plate.stl type {wall}
fix cylinder all mesh/surface file cylinder.stl type {wall}
fix walls all wall/gran {CONTACT_MODEL} mesh n_meshes 2 meshes plate cylinder {MODEL_SETTINGS}
fix integrate all nve/sphere
compute ke all ke
variable vrms equal sqrt(2*c_ke/mass(all))
thermo_style custom step atoms c_ke v_vrms
thermo {chunk}
thermo_modify lost ignore norm no
run {settle}
fix lift all move/mesh mesh cylinder linear 0.0 0.0 {config.cylinder.lift_speed:.9g}
run {lift}
unfix lift
variable chunk loop {max(1, math.ceil(remaining / chunk))}
label rest
run {chunk}
if "${{vrms}} < {config.stages.rest_speed:.9g}" then "jump SELF done"
next chunk
jump SELF rest
label done
dump final all custom 1 final.dump id type radius x y z
run 0
undump final
"""
        (folder / "in.heap").write_text(script)
        return LiggghtsCase("in.heap", dt, len(atoms))

    def read(self, folder: Path, config, case: LiggghtsCase) -> dict[str, float]:
        from dem.scenarios.heap_fit import fit_heap

        atoms = read_dump(folder / "final.dump")
        points = np.column_stack([atoms["x"], atoms["y"], atoms["z"]])
        fit = fit_heap(points, atoms["radius"], config=config.fit, diameter=config.particles.diameter)
        return {"angle_deg": fit.angle_deg, "height": fit.height}


ADAPTERS: dict[str, type] = {"angle_of_repose": HeapAdapter}
