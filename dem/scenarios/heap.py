"""Angle of repose: a heap formed by lifting a cylinder off a plate, its angle fitted from the
heap's surface. The most used calibration test of bulk friction.

Protocol (every number is a config key, see ``examples/repose.toml``):

1. A hollow cylinder (``cylinder.diameter``, open at both ends) stands on a square plate
   (``plate.size``). The particles start on a jittered lattice inside it (random per seed: jitter,
   which size class sits where, orientation of items) and settle under gravity until
   ``stages.lift_start``.
2. The cylinder rises at ``cylinder.lift_speed`` until it has cleared the column; the material
   flows out and forms a heap. Particles that run off the plate fall away and are not counted.
3. The run ends when the particles on the plate come to rest (translational RMS speed below
   ``stages.rest_speed``) or at ``stages.max_time``. The heap's angle and height are then fitted
   from the spheres' top points (``dem/scenarios/heap_fit.py``: sectors, radial bins, a line per
   sector between the apex and the toe).

Particles are either spheres (``particles.shape = "spheres"``: ``count`` spheres of
``diameter`` in ``size_classes`` sizes spread by ``size_spread``, density ``density``) or the
feeder's items (``"items"``: ``particles.items`` as in the feeder's ``[items]``). Plate and
cylinder are the walls: of the particles' material, or, when a trial names an item-wall parameter
(``dem/parameters.py``), both of the one wall material (``dem.materials.TrialMaterials``), as the
feeder's tray is. Why the cylinder too: in a real test it is a tube of acrylic or steel, not of
the grains, and its friction drags the column's rim while it rises, so a heap calibrated with the
cylinder in the grains' material would put the tube's friction into mu. A rig whose plate and
cylinder differ would need a second wall material, which the parameters do not offer (EDEM and
Rocky give each geometry its own).

Responses: ``angle_deg`` (the angle of repose, degrees) and ``height`` (the heap's height, m).
Engines: the built-in one (spheres and items) and LIGGGHTS (spheres; ``dem/engines/liggghts.py``
writes the same plate, cylinder and initial lattice, so both engines start from the same state).

This module followed the recipe of ``dem/scenarios/base.py``: the config model with ``kind`` and
``params`` in ``dem/scenarios/heap_config.py``, ``run_heap`` and ``SCENARIO`` here, both listed in
``dem/scenarios/registry.py``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from dem.parameters import PARAMETER_NAMES
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.base import Response, RunControl, Scenario, merged_params
from dem.scenarios.feeder import demcal_version
from dem.scenarios.heap_config import LATTICE_SPACING, HeapConfig, lattice_layer
from dem.scenarios.heap_fit import HeapFitError, fit_heap

logger = logging.getLogger(__name__)

GRAVITY = 9.81
# The random displacement of each lattice site, as a fraction of the free space around a sphere.
JITTER = 0.4


# -- geometry shared by every engine --------------------------------------------------------------


@dataclass(frozen=True)
class HeapGeometry:
    plate_vertices: np.ndarray
    plate_faces: np.ndarray
    cylinder_vertices: np.ndarray
    cylinder_faces: np.ndarray
    lift_distance: float  # m: the cylinder rises this far, clear of the column


def plate_mesh(config: HeapConfig) -> tuple[np.ndarray, np.ndarray]:
    """The plate, top at z = 0: square dimples of one mean diameter (inverted pyramids,
    ``plate.roughness`` diameters deep), or two triangles when smooth.

    Why rough: the contact law has no rolling resistance, so spheres on a smooth plate roll away
    and no heap stands; test rigs glue a layer of grains or sandpaper on the base for the same
    reason. The dimples hold the bottom layer as glued grains would, with a mesh every engine reads.
    """
    half = 0.5 * config.plate.size
    if config.plate.roughness == 0:
        vertices = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]])
        return vertices, np.array([[0, 1, 2], [0, 2, 3]])
    n = max(1, int(round(config.plate.size / config.particles.diameter)))
    grid = np.linspace(-half, half, n + 1)
    x, y = np.meshgrid(grid, grid, indexing="ij")
    corners = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    mid = 0.5 * (grid[:-1] + grid[1:])
    cx, cy = np.meshgrid(mid, mid, indexing="ij")
    depth = config.plate.roughness * config.particles.diameter
    centres = np.column_stack([cx.ravel(), cy.ravel(), np.full(cx.size, -depth)])
    faces = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = (
                i * (n + 1) + j,
                (i + 1) * (n + 1) + j,
                (i + 1) * (n + 1) + j + 1,
                i * (n + 1) + j + 1,
            )
            m = len(corners) + i * n + j
            faces += [[a, b, m], [b, c, m], [c, d, m], [d, a, m]]
    return np.vstack([corners, centres]), np.array(faces)


def heap_geometry(config: HeapConfig, column: float) -> HeapGeometry:
    """The plate (``plate_mesh``) and the open cylinder (a tube of ``segments`` quads from z = 0
    to ``cylinder.height``), in metres; the cylinder's axis is the z axis."""
    plate_v, plate_f = plate_mesh(config)
    n = config.cylinder.segments
    angles = 2 * math.pi * np.arange(n) / n
    radius = 0.5 * config.cylinder.diameter
    ring = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    cyl_v = np.vstack(
        [np.column_stack([ring, np.zeros(n)]), np.column_stack([ring, np.full(n, config.cylinder.height)])]
    )
    faces = []
    for k in range(n):
        a, b = k, (k + 1) % n
        faces += [[a, b, n + b], [a, n + b, n + a]]
    # Rise until the bottom rim clears the column's top by one diameter.
    lift = column + config.particles.diameters()[-1]
    return HeapGeometry(plate_v, plate_f, cyl_v, np.array(faces), lift)


@dataclass(frozen=True)
class SpherePacking:
    positions: np.ndarray  # (n, 3) m
    size_class: np.ndarray  # (n,) index into ParticlesConfig.diameters()
    column: float  # m, height of the lattice


def sphere_packing(config: HeapConfig, seed: int) -> SpherePacking:
    """The initial column: lattice sites filled bottom-up, jittered, size classes shuffled."""
    rng = np.random.default_rng(seed)
    p = config.particles
    diameters = p.diameters()
    spacing = LATTICE_SPACING * diameters[-1]
    layer = lattice_layer(config)
    layers = math.ceil(p.count / len(layer))
    sites = np.vstack(
        [
            np.column_stack([layer, np.full(len(layer), (k + 0.5) * spacing + 0.05 * spacing)])
            for k in range(layers)
        ]
    )[: p.count]
    free = 0.5 * (spacing - diameters[-1])
    positions = sites + rng.uniform(-JITTER * free, JITTER * free, size=sites.shape)
    size_class = rng.permutation(np.arange(p.count) % len(diameters))
    return SpherePacking(positions, size_class, layers * spacing)


# -- the built-in engine's run ---------------------------------------------------------------------


def run_heap(
    config: HeapConfig, params: dict[str, float], seed: int, control: RunControl
) -> SimulationResult:
    """One angle-of-repose test with the built-in engine; never raises."""
    started = time.monotonic()
    checked, problem = merged_params(config.params, params)
    base = {"seed": int(seed), "version": demcal_version(), "params": checked}
    if problem:
        return SimulationResult(status=SimulationStatus.ERROR, message=problem, **base)
    try:
        return _HeapRun(config, checked, int(seed), control).execute(started)
    except Exception as exc:  # the contract: a result, never a traceback
        logger.exception("heap run failed (seed %s, params %s)", seed, checked)
        return SimulationResult(
            status=SimulationStatus.ERROR,
            message=f"{type(exc).__name__}: {exc}",
            wall_time_s=time.monotonic() - started,
            **base,
        )


class _HeapRun:
    def __init__(self, config: HeapConfig, params: dict[str, float], seed: int, control: RunControl):
        from dem.clump import Clump
        from dem.materials import TrialMaterials
        from dem.motion import LinearLift
        from dem.simulation import Simulation
        from dem.walls import WallMesh

        self.config, self.params, self.seed, self.control = config, params, seed, control
        rng = np.random.default_rng(seed)
        bodies = []  # (clump, position, quaternion)
        if config.particles.shape == "spheres":
            packing = sphere_packing(config, seed)
            clumps = [
                Clump.solid_sphere(0.5 * d, config.particles.density, name=f"sphere-{k}")
                for k, d in enumerate(config.particles.diameters())
            ]
            bodies = [
                (clumps[c], pos, (1.0, 0.0, 0.0, 0.0))
                for pos, c in zip(packing.positions, packing.size_class, strict=True)
            ]
            column, self.unit = packing.column, config.particles.diameter
        else:
            bodies, column = _item_column(config, rng)
            # The fit's length unit: the items' mean equal-volume diameter.
            self.unit = float(np.mean([b[0].equivalent_diameter for b in bodies]))
        self.geometry = heap_geometry(config, column)
        g = self.geometry
        half = 0.5 * config.plate.size
        materials = TrialMaterials.of(params)
        self.sim = Simulation(
            materials.items,
            interactions=materials.interactions,
            gravity=(0.0, 0.0, -GRAVITY),
            domain_min=(-half - 0.1, -half - 0.1, -0.05 - config.plate.roughness * config.particles.diameter),
            domain_max=(half + 0.1, half + 0.1, config.cylinder.height + g.lift_distance + 0.1),
            dt=config.run.dt,
            dt_fraction=config.run.dt_fraction,
            seed=seed,
        )
        self.sim.add_wall(WallMesh(g.plate_vertices, g.plate_faces, material=materials.walls, name="plate"))
        lift = LinearLift(
            (0.0, 0.0, 1.0), g.lift_distance, config.cylinder.lift_speed, config.stages.lift_start
        )
        cylinder = g.cylinder_vertices, g.cylinder_faces
        self.sim.add_wall(WallMesh(*cylinder, material=materials.walls, motion=lift, name="cylinder"))
        for clump, position, quat in bodies:
            self.sim.add_body(clump, position, quat)
        self.lift_end = lift.end_time
        self.frames = 0
        self.next_frame = 0.0

    def _rms_speed(self) -> float:
        b = self.sim.bodies
        a = np.asarray(b.active)
        mass = np.asarray(b.mass)[a]
        if mass.sum() == 0:
            return 0.0
        return float(math.sqrt(np.sum(mass * np.sum(np.asarray(b.vel)[a] ** 2, axis=1)) / mass.sum()))

    def _observe(self, sim) -> None:
        vtk_dir = self.control.vtk_dir
        if vtk_dir is not None and sim.t >= self.next_frame - 1e-12:
            from dem import vtk

            vtk.write_frame(sim, vtk_dir, self.frames)
            self.frames += 1
            self.next_frame = sim.t + self.config.run.snapshot_interval
        if self.control.progress is not None:
            self.control.progress(sim.t, int(np.sum(sim.bodies.active)))

    def _at_rest(self) -> bool:
        return self.sim.t > self.lift_end and self._rms_speed() < self.config.stages.rest_speed

    def execute(self, started: float) -> SimulationResult:
        control, stages = self.control, self.config.stages
        status, message = SimulationStatus.OK, ""

        def stop() -> bool:
            return self._at_rest() or bool(control.should_stop and control.should_stop())

        report = self.sim.run(
            until=stages.max_time,
            chunk_time=self.config.run.chunk_time,
            deadline=control.deadline,
            should_stop=stop,
            on_chunk=self._observe,
        )
        report_status = SimulationStatus(str(getattr(report.status, "value", report.status)))
        if report_status is SimulationStatus.CANCELLED and self._at_rest():
            report_status = SimulationStatus.OK
        if report_status is not SimulationStatus.OK:
            status, message = report_status, report.message or f"the engine stopped: {report_status}"
        responses: dict[str, float | None] = {"angle_deg": None, "height": None}
        if status is SimulationStatus.OK:
            if not self._at_rest():
                message = f"not at rest at stages.max_time (RMS speed {self._rms_speed():.3g} m/s)"
            points, radii = self.sphere_state()
            try:
                fit = fit_heap(points, radii, config=self.config.fit, diameter=self.unit)
                responses = {"angle_deg": fit.angle_deg, "height": fit.height}
            except HeapFitError as exc:
                status, message = SimulationStatus.ERROR, f"no heap to fit: {exc}"
        self._observe(self.sim)
        return SimulationResult(
            status=status,
            message=message,
            n_items=int(self.sim.bodies.n),
            responses=responses,
            sim_time=float(self.sim.t),
            wall_time_s=time.monotonic() - started,
            steps=int(self.sim.steps),
            dt=float(self.sim.dt),
            cost=float(self.sim.cost),
            params=self.params,
            seed=self.seed,
            version=demcal_version(),
        )

    def sphere_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres and radii of the spheres of every body still in the domain."""
        keep = np.asarray(self.sim.bodies.active)[self.sim.spheres.body]
        return self.sim.sphere_positions()[keep], np.asarray(self.sim.spheres.radius)[keep]


def _item_column(config: HeapConfig, rng: np.random.Generator):
    """Items stacked in the cylinder on a grid of their largest extent, randomly oriented."""
    from dem.scenarios.feeder import body_frame_hull, make_items, random_rotation

    items = make_items(config.particles.items, rng)
    reach = max(float(np.linalg.norm(body_frame_hull(item), axis=1).max()) for item in items)
    spacing = 2.05 * reach
    inner = 0.5 * config.cylinder.diameter * math.cos(math.pi / config.cylinder.segments) - reach
    if inner < 0:
        raise ValueError(
            f"cylinder.diameter {config.cylinder.diameter} m is narrower than the items "
            f"({2 * reach:.3f} m across); widen it"
        )
    n = int(inner // spacing)
    grid = np.arange(-n, n + 1) * spacing
    x, y = np.meshgrid(grid, grid, indexing="ij")
    keep = np.hypot(x, y) <= inner
    layer = np.column_stack([x[keep], y[keep]])
    layers = math.ceil(len(items) / len(layer))
    column = layers * spacing
    if column > config.cylinder.height:
        raise ValueError(
            f"{len(items)} items need a column {column * 1e3:.0f} mm high in this cylinder; raise "
            "cylinder.height or cylinder.diameter, or use fewer items"
        )
    bodies = []
    for i, item in enumerate(items):
        xy = layer[i % len(layer)]
        z = (i // len(layer) + 0.5) * spacing + 0.002
        quat, _ = random_rotation(rng)
        bodies.append((item.shape, np.array([xy[0], xy[1], z]), quat))
    return bodies, column


# -- declarations -------------------------------------------------------------------------------------


def time_step(config: HeapConfig, params: dict[str, float]) -> float:
    """The built-in engine's automatic step for the spheres (exact); for items a cheap estimate
    from a 10 mm steel sphere, which errs short like the feeder's."""
    if config.run.dt:
        return float(config.run.dt)
    from dem.clump import Clump
    from dem.contact import ContactParams
    from dem.timestep import automatic_time_step

    merged = {**config.params.model_dump(), **params}
    contact = ContactParams(**{k: float(merged[k]) for k in PARAMETER_NAMES})
    if config.particles.shape == "spheres":
        clumps = [Clump.solid_sphere(0.5 * d, config.particles.density) for d in config.particles.diameters()]
    else:
        clumps = [Clump.solid_sphere(0.005, 8000.0)]
    return automatic_time_step(clumps, contact, [contact], config.run.dt_fraction)


def estimated_cost(config: HeapConfig, params: dict[str, float]) -> float:
    """Body-steps up to stages.max_time (a run at rest ends earlier)."""
    bodies = (
        config.particles.count
        if config.particles.shape == "spheres"
        else sum(config.particles.items.counts.values())
    )
    return bodies * config.stages.max_time / time_step(config, params)


SCENARIO = Scenario(
    kind="angle_of_repose",
    title="angle of repose (heap formed by lifting a cylinder off a plate)",
    config_model=HeapConfig,
    responses=(
        Response(
            "angle_deg",
            unit="deg",
            integer=False,
            failed_value=90.0,
            description="Angle of repose fitted from the heap's surface.",
            label="angle of repose",
        ),
        Response(
            "height", unit="m", integer=False, failed_value=0.0, description="Height of the heap.",
            label="heap height",
        ),
    ),
    run_function=run_heap,
    cost_function=estimated_cost,
    time_step_function=time_step,
    engines=("numba", "liggghts", "command"),
    duration_function=lambda config: config.stages.max_time,
    progress_label="bodies",
)
