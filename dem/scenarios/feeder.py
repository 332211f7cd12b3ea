"""The vibration feeder of Kawaguchi et al. (Mater. Trans. 62(4), 2021, chapters 2-3) as a
configurable simulation: the scenario every calibration runs, and its response N_t.

Protocol (defaults from the paper; every number is a config key, see ``examples/feeder.toml``):

1. Insertion, 0 to ``stages.insertion_time`` (1 s): items are created one after another at
   random positions and orientations above the inlet region, never overlapping a wall or another
   item (their oriented bounding boxes are checked), lowest free place first, then fall.
2. Deposition until ``stages.vibration_start`` (t = 5 s): gravity only.
3. Vibration for ``stages.vibration_time`` (60 s): the tray translates sinusoidally at
   ``vibration.frequency`` (60 Hz) with ``vibration.amplitude`` (1.5 mm), along a line inclined
   ``vibration.angle_deg`` (25 deg) from the horizontal, towards the outlet. The amplitude is a
   peak amplitude by default (``amplitude_kind = "peak"``: displacement A sin(w t)), which is
   how the paper's "amplitude of 1.5 mm" reads; ``"peak_to_peak"`` halves it.

An item is discharged when its centre passes the tray's open outlet end (tray-frame
x > outlet_x, see ``dem/scenarios/tray.py``); its time is recorded and the body removed. N_t is
the number of items never discharged. With ``run.stop_when_empty`` the run ends when the last
item left, as the experiment did. The outlet (100 mm) is narrower than a smartphone (146 mm), so
single-item clogging and bridging are possible, which is the physics the calibration is about.

``run_feeder`` never raises for physics or parameters: a blow-up, a deadline, a cancellation or a
bad parameter value ends it with the matching status and a message. The config model is
``dem/scenarios/feeder_config.py``'s ``FeederConfig``: a bad config is a pydantic ``ValidationError``
at load time, naming the key.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from dem import quaternion
from dem.frames import norm, transform
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.base import Response, RunControl, Scenario, merged_params
from dem.scenarios.feeder_config import FeederConfig, ItemsConfig, load_feeder_config
from dem.scenarios.tray import TrayGeometry, build_tray

logger = logging.getLogger(__name__)

GRAVITY = 9.81


def demcal_version() -> str:
    try:
        return version("demcal")
    except PackageNotFoundError:
        return "0+unknown"


Progress = Callable[[float, int], None]


def run_feeder(
    config: FeederConfig,
    params: dict[str, float],
    seed: int,
    *,
    deadline: float | None = None,
    should_stop: Callable[[], bool] | None = None,
    progress: Progress | None = None,
    snapshot_dir: Path | None = None,
    vtk_dir: Path | None = None,
) -> SimulationResult:
    """Run one feeder experiment with these contact parameters; never raises.

    ``params`` holds any of E, nu, e, mu and the optional item-wall ones (``dem/parameters.py``),
    the tray's material and its pair with the items (missing ones come from ``config.params``); ``deadline``
    is a ``time.monotonic()`` value; ``should_stop()`` is polled between chunks; ``progress`` is
    called with (simulated time, items not yet discharged); ``snapshot_dir`` receives the files
    ``demcal render`` reads (see ``dem/scenarios/render.py``); ``vtk_dir`` receives ParaView files
    (``dem.vtk.write_frame``) every ``run.snapshot_interval``.
    """
    started = time.monotonic()
    checked, problem = merged_params(config.params, params)
    base = {"seed": int(seed), "version": demcal_version()}
    if problem:
        return SimulationResult(status=SimulationStatus.ERROR, message=problem, params=checked, **base)
    try:
        feeder = _FeederRun(config, checked, int(seed), snapshot_dir, vtk_dir)
        return feeder.execute(started, deadline, should_stop, progress)
    except Exception as exc:  # the contract: a worker gets a result, never a traceback
        logger.exception("feeder run failed (seed %s, params %s)", seed, checked)
        return SimulationResult(
            status=SimulationStatus.ERROR,
            message=f"{type(exc).__name__}: {exc}",
            params=checked,
            wall_time_s=time.monotonic() - started,
            **base,
        )


def random_rotation(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A uniformly random orientation: unit quaternion (scalar first) and its rotation matrix."""
    q = rng.normal(size=4)
    q /= norm(q)
    return q, quaternion.matrices(q[None, :])[0]


class _FeederRun:
    """One run's state: the engine, which body is which item, and what has left the tray."""

    # Gap kept between a new item's bounding box and walls or other items, m.
    INSERT_GAP = 0.003
    # The insertion zone reaches this far above the wall top, m.
    INSERT_ZONE_HEIGHT = 0.25
    PLACEMENT_TRIES = 64
    RETRY_INTERVAL = 0.02

    def __init__(
        self,
        config: FeederConfig,
        params: dict[str, float],
        seed: int,
        snapshot_dir: Path | None,
        vtk_dir: Path | None = None,
    ):
        from dem.materials import TrialMaterials
        from dem.motion import SinusoidalTranslation
        from dem.simulation import Simulation
        from dem.walls import WallMesh

        self.config = config
        self.params = params
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.tray: TrayGeometry = build_tray(config.tray)
        self.items = make_items(config.items, self.rng)
        self.hulls = [body_frame_hull(item) for item in self.items]
        n = len(self.items)
        self.body_of = np.full(n, -1, dtype=np.int64)
        self.state = np.zeros(n, dtype=np.int8)  # render.NOT_CREATED / IN_TRAY / GONE
        self.discharge_times: list[float | None] = [None] * n
        self.inserted_at: list[float | None] = [None] * n
        self.escaped: list[int] = []
        self.emptied_at: float | None = None
        self.pending = list(range(n))

        lo = self.tray.vertices.min(axis=0)
        hi = self.tray.vertices.max(axis=0)
        materials = TrialMaterials.of(params, wall="tray")
        self.sim = Simulation(
            materials.items,
            interactions=materials.interactions,
            gravity=(0.0, 0.0, -GRAVITY),
            domain_min=tuple(lo - np.array([0.3, 0.3, 0.5])),
            domain_max=tuple(hi + np.array([0.5, 0.3, self.INSERT_ZONE_HEIGHT + 0.5])),
            dt=config.run.dt,
            dt_fraction=config.run.dt_fraction,
            seed=seed,
        )
        vib = config.vibration
        motion = SinusoidalTranslation(
            direction=vib.direction,
            amplitude=vib.peak_amplitude,
            frequency=vib.frequency,
            start_time=config.stages.vibration_start,
            ramp_time=vib.ramp_time,
        )
        tray, walls = self.tray, materials.walls
        self.sim.add_wall(WallMesh(tray.vertices, tray.faces, material=walls, motion=motion, name="tray"))

        self.writer = None
        if snapshot_dir is not None:
            from dem.scenarios.render import SnapshotWriter

            self.writer = SnapshotWriter(
                snapshot_dir,
                self.tray.vertices,
                self.tray.faces,
                [item.name for item in self.items],
                [item.kind for item in self.items],
                self.hulls,
                tilt_deg=config.tray.tilt_deg,
                vibration=(*vib.direction, vib.peak_amplitude, vib.frequency, config.stages.vibration_start),
            )
        self.vtk_dir = Path(vtk_dir) if vtk_dir is not None else None
        self.vtk_frames = 0
        self.next_snapshot = 0.0

    # -- insertion ---------------------------------------------------------------------------

    def _occupied_boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Tray-frame bounding boxes of the items in the tray, at their current pose."""
        boxes = []
        bodies = self.sim.bodies
        for i in np.flatnonzero(self.state == 1):
            b = self.body_of[i]
            rotation = quaternion.matrices(np.asarray(bodies.quat[b])[None, :])[0]
            points = self.tray.to_tray_frame(np.asarray(bodies.pos[b]) + transform(self.hulls[i], rotation.T))
            boxes.append((points.min(axis=0), points.max(axis=0)))
        return boxes

    def _try_insert(self, i: int) -> bool:
        """Create item i at the lowest free random place above the inlet region, if there is one."""
        gap = self.INSERT_GAP
        (x0, x1), (y0, y1) = self.tray.inlet_x, self.tray.inlet_y
        z_top = self.tray.wall_height + self.INSERT_ZONE_HEIGHT
        occupied = self._occupied_boxes()
        best = None
        for _ in range(self.PLACEMENT_TRIES):
            quat, rotation = random_rotation(self.rng)
            local = self.tray.to_tray_frame(transform(self.hulls[i], rotation.T))
            low, high = local.min(axis=0), local.max(axis=0)
            span_x = (x0 + gap - low[0], x1 - gap - high[0])
            span_y = (y0 + gap - low[1], y1 - gap - high[1])
            span_z = (gap - low[2], z_top - high[2])
            if span_x[0] > span_x[1] or span_y[0] > span_y[1] or span_z[0] > span_z[1]:
                continue  # this orientation does not fit the inlet footprint at all
            centre = np.array(
                [self.rng.uniform(*span_x), self.rng.uniform(*span_y), self.rng.uniform(*span_z)]
            )
            box_lo, box_hi = centre + low - gap, centre + high + gap
            if any(np.all(box_lo < o_hi) and np.all(o_lo < box_hi) for o_lo, o_hi in occupied):
                continue
            if best is None or centre[2] < best[0][2]:
                best = (centre, quat)
        if best is None:
            return False
        centre, quat = best
        position = self.tray.to_world(centre[None, :])[0]
        self.body_of[i] = self.sim.add_body(self.items[i].shape, position, quat, np.zeros(3), np.zeros(3))
        self.state[i] = 1
        self.inserted_at[i] = float(self.sim.t)
        return True

    def _insert_due(self) -> None:
        """Create every pending item whose insertion time has come, in order, while they fit."""
        n = len(self.items)
        interval = self.config.stages.insertion_time / n
        while self.pending and self.pending[0] * interval <= self.sim.t + 1e-12:
            if not self._try_insert(self.pending[0]):
                return
            self.pending.pop(0)

    def _next_stop(self) -> float:
        end = self.config.stages.end
        if not self.pending:
            return end
        due = self.pending[0] * self.config.stages.insertion_time / len(self.items)
        if due > self.sim.t + 1e-12:
            return min(due, end)
        return min(self.sim.t + self.RETRY_INTERVAL, end)  # it did not fit: wait for room

    # -- observation ---------------------------------------------------------------------------

    def _observe(self, sim) -> None:
        """After each chunk: remove discharged items, record times, write snapshots, report."""
        t = float(sim.t)
        active = np.asarray(sim.bodies.active)
        on_tray = np.flatnonzero(self.state == 1)
        # All items' x in one call (row by row the same sums): this runs after every chunk, and a
        # call per item was 0.15 ms of Python a chunk, 1 s of a 65 s feeder run.
        tray_x = self.tray.to_tray_frame(np.asarray(sim.bodies.pos)[self.body_of[on_tray]])[:, 0]
        for i, x in zip(on_tray, tray_x, strict=True):
            b = self.body_of[i]
            if not active[b]:
                # The engine removed it for leaving the domain other than through the outlet.
                self.state[i] = 2
                self.discharge_times[i] = t
                self.escaped.append(int(i))
                continue
            if x > self.tray.outlet_x:
                self.state[i] = 2
                self.discharge_times[i] = t
                sim.remove_body(int(b))
        if self.emptied_at is None and not self.pending and not np.any(self.state == 1):
            self.emptied_at = t
        if (self.writer is not None or self.vtk_dir is not None) and t >= self.next_snapshot - 1e-12:
            self._snapshot()
            self.next_snapshot = t + self.config.run.snapshot_interval
        if self.progress is not None:
            self.progress(t, self.n_left)

    def _snapshot(self) -> None:
        if self.vtk_dir is not None:
            from dem import vtk

            vtk.write_frame(self.sim, self.vtk_dir, self.vtk_frames)
            self.vtk_frames += 1
        if self.writer is None:
            return
        n = len(self.items)
        pos = np.zeros((n, 3))
        quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        for i in np.flatnonzero(self.state == 1):
            pos[i] = self.sim.bodies.pos[self.body_of[i]]
            quat[i] = self.sim.bodies.quat[self.body_of[i]]
        self.writer.frame(self.sim.t, pos, quat, self.state, self.sim.wall_displacement(0))

    @property
    def n_left(self) -> int:
        return int(np.sum(self.state != 2))

    # -- the run -----------------------------------------------------------------------------------

    def execute(self, started, deadline, should_stop, progress) -> SimulationResult:
        self.progress = progress
        cfg = self.config

        def stop() -> bool:
            if cfg.run.stop_when_empty and self.emptied_at is not None:
                return True
            return bool(should_stop and should_stop())

        status, message = SimulationStatus.OK, ""
        end = cfg.stages.end
        self._observe(self.sim)
        while self.sim.t < end - 1e-9 and not (cfg.run.stop_when_empty and self.emptied_at is not None):
            self._insert_due()
            if self.pending and self.sim.t >= cfg.stages.vibration_start - 1e-9:
                status = SimulationStatus.ERROR
                message = (
                    f"{len(self.pending)} of {len(self.items)} items could not be created without overlap "
                    f"in the inlet region before vibration_start; reduce items.counts, lengthen "
                    f"stages.insertion_time or enlarge the tray's inlet"
                )
                break
            report = self.sim.run(
                until=self._next_stop(),
                chunk_time=cfg.run.chunk_time,
                deadline=deadline,
                should_stop=stop,
                on_chunk=self._observe,
            )
            report_status = SimulationStatus(str(getattr(report.status, "value", report.status)))
            if report_status is SimulationStatus.CANCELLED and cfg.run.stop_when_empty and self.emptied_at:
                break
            if report_status is not SimulationStatus.OK:
                status, message = report_status, report.message or f"the engine stopped: {report_status}"
                break
        if status is SimulationStatus.OK and self.escaped:
            # The domain reaches 0.3-0.5 m beyond the tray. With a step too long for the contacts
            # an item gets there because it was thrown by a blow-up: N_t is not a response. With a
            # step that resolves them, it bounced over a wall (a stiff, elastic set dropped from
            # the inlet): physics, and the item is out of the tray like a discharged one.
            first = min(self.discharge_times[i] for i in self.escaped)
            if self.sim.resolves_contacts():
                message = (
                    f"{len(self.escaped)} item(s) bounced out of the tray over a wall (first at "
                    f"t={first:.4g} s); they count as not remaining"
                )
            else:
                status = SimulationStatus.UNSTABLE
                message = (
                    f"{len(self.escaped)} item(s) were thrown out of the domain (first at "
                    f"t={first:.4g} s) with a forced run.dt above the automatic step "
                    f"({self.sim.dt:.3g} s); remove run.dt or make it smaller"
                )
        if self.writer is not None or self.vtk_dir is not None:
            self._snapshot()
        result = SimulationResult(
            status=status,
            message=message,
            n_items=len(self.items),
            n_remaining=self.n_left,
            responses={"n_remaining": self.n_left},
            discharge_times=self.discharge_times,
            emptied_at=self.emptied_at,
            sim_time=float(self.sim.t),
            wall_time_s=time.monotonic() - started,
            steps=int(self.sim.steps),
            dt=float(self.sim.dt),
            cost=float(self.sim.cost),
            full_load_factor=(
                full_load_factor(self.inserted_at, self.discharge_times, float(self.sim.t), cfg.stages.end)
                if status is SimulationStatus.OK
                else 1.0
            ),
            max_overlap=float(self.sim.max_overlap),
            params=self.params,
            seed=self.seed,
            version=demcal_version(),
        )
        if self.writer is not None:
            self.writer.summary(result.model_dump(mode="json"))
        return result



def full_load_factor(
    inserted_at: list[float | None], discharge_times: list[float | None], stopped_at: float, end: float
) -> float:
    """The protocol's item-seconds (each item from its insertion to ``end``) over the run's (to
    its discharge, or to ``stopped_at``). In four paper studies the work per item-second was the
    same within 1.4 % whatever N_t (``benchmarks/cost_coupling.py``), so this factor times the
    run's cost is the cost of the full 65 s protocol, which the paper's T measured."""
    run = protocol = 0.0
    for inserted, left in zip(inserted_at, discharge_times, strict=True):
        if inserted is not None:
            run += (stopped_at if left is None else left) - inserted
            protocol += end - inserted
    return max(1.0, protocol / run) if run > 0 else 1.0


def softest_valid_E(config: FeederConfig, e: float) -> float:
    """The E below which insertion makes runs ``invalid`` (``dem/validity.py``), estimated.

    The hardest impact of a run is an item's drop at insertion: created at most the wall height
    plus the insertion zone above the floor, it lands at ``v = sqrt(2 g h)``, with the mass that
    ``dem.validity.impact_mass`` says carries it (a clump lands on a corner, where it is lighter
    than its mass because it turns; a rounded polyhedron can land on a face level, with its whole
    mass) against its ``overlap_scale`` (a clump's smallest sphere, a polyhedron's rounding).
    The estimate is the largest over one nominal item per kind (``items.spread`` moves it by
    about 2 x spread). It is an estimate: a drop from lower moves the real threshold down (clumps
    on the quick feeder at e = 0.5 and 0.9: invalid runs at 5e5 and 1e6 Pa, none at 1e6 and 2e6
    Pa, against estimates of 1.4e6 and 2.5e6 Pa; polyhedra on the full feeder at e 0.5: a phone
    landing on its side face from 0.2 m needed 1.3e7 Pa, against an estimate of 2.3e7 Pa for the
    full drop).
    """
    from dem.validity import impact_mass, overlap_scale
    from dem.validity import softest_valid_E as softest

    nominal = config.items.model_copy(
        update={"counts": {kind: 1 for kind, count in config.items.counts.items() if count}, "spread": 0.0}
    )
    drop = config.tray.wall_height + _FeederRun.INSERT_ZONE_HEIGHT
    speed = math.sqrt(2.0 * GRAVITY * drop)
    return max(
        softest(
            speed,
            impact_mass(item.shape),
            item.shape.equivalent_diameter,
            overlap_scale(item.shape),
            e,
        )
        for item in make_items(nominal, np.random.default_rng(0))
    )


def make_items(config: ItemsConfig, rng: np.random.Generator) -> list:
    """The items of one run, in a fixed order (kind by kind), with their per-item spread."""
    from dem.scenarios import items

    if config.uploaded:
        raise items.ItemsError(
            "items.uploaded: uploaded shapes are kept by the service; run the scenario through its API"
        )
    if config.folder is not None:
        return items.items_from_folder(
            config.folder,
            config.counts,
            config.masses,
            rng,
            config.spread,
            config.resolution,
            representation=config.representation,
            core_tolerance=config.core_tolerance,
        )
    return items.default_items(
        rng,
        config.counts,
        config.spread,
        config.resolution,
        representation=config.representation,
        core_tolerance=config.core_tolerance,
    )


def body_frame_hull(item) -> np.ndarray:
    """Convex hull vertices of an item's mesh in its body (principal) frame, m."""
    shape = item.shape
    hull = item.mesh.convex_hull.vertices
    return transform(np.asarray(hull, dtype=float) - np.asarray(shape.com), shape.axes)


def _run(config: FeederConfig, params: dict[str, float], seed: int, control: RunControl) -> SimulationResult:
    return run_feeder(
        config,
        params,
        seed,
        deadline=control.deadline,
        should_stop=control.should_stop,
        progress=control.progress,
        snapshot_dir=control.snapshot_dir,
        vtk_dir=control.vtk_dir,
    )


def estimated_time_step(config: FeederConfig, params: dict[str, float]) -> float:
    """A cheap step estimate (no items built): a fraction of the contact period of a 10 mm steel
    sphere, ``T_c = pi sqrt(m / K)``, with the stiffer of its contacts: ``K = E D / 2`` with
    another item, the two E in series against a wall of ``E_wall`` (up to twice that). Smaller and
    denser than any item of the feeder's set, so it errs short: more steps, a longer job timeout,
    never a premature one."""
    from dem.contact import wall_stiffness

    if config.run.dt:
        return float(config.run.dt)
    young = float(params.get("E", config.params.E))
    wall = params.get("E_wall", config.params.E_wall)
    diameter, density = 0.01, 8000.0
    mass = density * math.pi * diameter**3 / 6
    stiffness = young * diameter / 2
    if wall is not None:
        stiffness = max(stiffness, wall_stiffness(young, diameter, float(wall)))
    return config.run.dt_fraction * math.pi * math.sqrt(mass / stiffness)


def estimated_cost(config: FeederConfig, params: dict[str, float]) -> float:
    """Body-steps of a run that does not empty early: items x simulated time / step."""
    return sum(config.items.counts.values()) * config.stages.end / estimated_time_step(config, params)


SCENARIO = Scenario(
    kind="feeder",
    title="vibration feeder (items left in the tray after vibrating)",
    config_model=FeederConfig,
    responses=(
        Response(
            "n_remaining",
            unit="items",
            integer=True,
            failed_value=30,  # the paper's set; failed_function gives the config's own count
            description="N_t: items still in the tray at the end of the vibration.",
            label="N_t",
        ),
    ),
    run_function=_run,
    cost_function=estimated_cost,
    time_step_function=estimated_time_step,
    # A failed run counts as the worst case: every item retained.
    failed_function=lambda config: {"n_remaining": sum(config.items.counts.values())},
    duration_function=lambda config: config.stages.end,
    load_function=load_feeder_config,
    progress_label="items left",
)
