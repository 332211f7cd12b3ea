"""The engine's driver: a set of rigid clump bodies and walls advanced in time by the kernels.

``Simulation`` owns the state (bodies and spheres, ``dem/bodies.py``; walls, ``dem/walls.py``;
neighbour lists, ``dem/neighbours.py``; the run's clock and counters, ``dem/loop.py``), each in
the container of the module that builds it, and runs ``dem.loop.run_steps`` in chunks of
simulated time. Between
chunks Python has control again: progress callbacks, a wall-clock deadline, cancellation and
signals (a numba loop ignores them, so chunks are kept short). ``run`` may be called again and
again, with bodies added or removed in between; physics blow-ups end a run with status
``unstable`` and the time, never with an exception; an overlap beyond ``overlap_limit`` of a
sphere radius while the step resolves the contact (the automatic step, or a smaller forced one)
is not a blow-up but a material too soft for its impacts, and ends the run ``invalid``.

Decisions a user should know:
* the automatic step (``dem/timestep.py``) is recomputed when bodies or walls are added;
* a body whose centre leaves ``[domain_min, domain_max]`` is removed and listed in
  ``removed_out_of_domain`` with the time;
* the cost is the sum over steps of active spheres plus force-carrying sphere contacts, a
  machine-independent measure of work;
* everything is float64 and serial, so the same inputs give bit-identical results.
This module must not know about scenarios (feeder) or the optimiser.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dem import loop as L
from dem import neighbours
from dem.bodies import Bodies, Spheres
from dem.clump import Clump
from dem.contact import ContactParams, wall_stiffness
from dem.facets import closest_point_on_facet
from dem.frames import norm, transform
from dem.materials import Interaction, MaterialTable
from dem.motion import evaluate
from dem.polyhedra import Polyhedron
from dem.quaternion import to_matrix
from dem.result import OVERLAP_LIMIT, SimulationStatus
from dem.timestep import DEFAULT_FRACTION, automatic_time_step
from dem.walls import WallMesh, wall_arrays

log = logging.getLogger(__name__)

_UNSTABLE_REASONS = {
    L.STATUS_UNSTABLE_NAN: "has a NaN or infinite state",
    L.STATUS_UNSTABLE_SPEED: "moves faster than max_speed",
    L.STATUS_UNSTABLE_OVERLAP: "overlaps beyond overlap_limit of a sphere radius",
}


class SimulationError(ValueError):
    """A simulation was set up wrongly (bad body, bad bounds); the message says what to fix."""


@dataclass(frozen=True)
class RunStatus:
    """How a call to ``Simulation.run`` ended."""

    status: SimulationStatus
    message: str
    t: float
    steps: int

    @property
    def ok(self) -> bool:
        return self.status is SimulationStatus.OK


def _vector(value, n: int, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64).reshape(-1)
    if array.shape != (n,) or not np.all(np.isfinite(array)):
        raise SimulationError(f"{name} must be {n} finite numbers, got {value!r}")
    return array


class Simulation:
    """Rigid bodies (sphere clumps, rounded polyhedra), walls, gravity and the contact law of
    ``params``."""

    def __init__(
        self,
        params: ContactParams,
        gravity=(0.0, 0.0, -9.81),
        *,
        domain_min,
        domain_max,
        dt: float | None = None,
        dt_fraction: float = DEFAULT_FRACTION,
        seed: int = 0,
        skin: float | None = None,
        max_speed: float = 100.0,
        overlap_limit: float = OVERLAP_LIMIT,
        interactions: dict[tuple[str, str], Interaction] | None = None,
    ) -> None:
        self.params = params
        # Every body's and wall's material; ``params`` is the default of both, ``interactions``
        # give pairs of named materials their own e and mu (``dem/materials.py``).
        self.materials = MaterialTable(interactions)
        self._default_material = self.materials.index(params)
        self.gravity = _vector(gravity, 3, "gravity")
        self.domain_min = _vector(domain_min, 3, "domain_min")
        self.domain_max = _vector(domain_max, 3, "domain_max")
        if np.any(self.domain_max <= self.domain_min):
            raise SimulationError("domain_max must exceed domain_min on every axis")
        if dt is not None and not (math.isfinite(dt) and dt > 0):
            raise SimulationError(f"dt must be a positive number of seconds, got {dt!r}")
        if skin is not None and not skin > 0:
            raise SimulationError(f"skin must be > 0 m, got {skin!r}")
        if not max_speed > 0 or not 0 < overlap_limit <= 1:
            raise SimulationError("max_speed must be > 0 m/s and overlap_limit in (0, 1]")
        self.dt_fraction = dt_fraction
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.bodies = Bodies()
        self.spheres = Spheres()
        self.walls: list[WallMesh] = []
        self.removed_out_of_domain: list[tuple[int, float]] = []
        self.steps = 0
        self._forced_dt = dt
        self._auto_dt: float | None = None
        self._skin = skin
        self._max_speed = max_speed
        self._overlap_limit = overlap_limit
        self._clumps: list[Clump] = []
        self._stale = True
        self._run = L.new_run_state()
        self._walls = wall_arrays([], self._material_index)
        self._lists = neighbours.empty_neighbours()
        self._settings: L.Settings | None = None
        self._events_seen = 0
        self.max_overlap = 0.0  # largest overlap / radius seen at the end of a chunk (or a trip)

    # ---------------------------------------------------------------- set-up

    def add_body(
        self,
        clump: Clump | Polyhedron,
        position,
        quaternion=(1.0, 0.0, 0.0, 0.0),
        velocity=(0.0, 0.0, 0.0),
        omega=(0.0, 0.0, 0.0),
        material: ContactParams | None = None,
    ) -> int:
        """Add a rigid body (its centre of mass at ``position``) of ``material`` (default: the
        simulation's ``params``); returns its index."""
        position = _vector(position, 3, "position")
        q = _vector(quaternion, 4, "quaternion")
        if norm(q) == 0:
            raise SimulationError("quaternion must not be zero")
        q = q / norm(q)
        inertia = _vector(clump.inertia, 3, "body inertia")
        if isinstance(clump, Polyhedron):
            if not clump.mass > 0 or np.any(inertia <= 0) or clump.n_pieces == 0 or not clump.rounding > 0:
                raise SimulationError(
                    f"polyhedron {clump.name!r}: needs mass > 0, inertia > 0, a piece and rounding > 0"
                )
        elif not clump.mass > 0 or np.any(inertia <= 0) or clump.n_spheres == 0 or np.any(clump.radius <= 0):
            raise SimulationError(
                f"clump {clump.name!r}: needs mass > 0, inertia > 0 and at least one sphere of radius > 0"
            )
        if np.any(position < self.domain_min) or np.any(position > self.domain_max):
            raise SimulationError(f"position {position.tolist()} is outside the domain")
        rot = np.empty((3, 3))
        to_matrix(q, rot)
        omega = _vector(omega, 3, "omega")
        angmom = transform(inertia * transform(omega, rot), rot.T)
        if not any(c is clump for c in self._clumps):
            self._clumps.append(clump)
        b = self.bodies.append(
            pos=position,
            quat=q,
            vel=_vector(velocity, 3, "velocity"),
            angmom=angmom,
            omega=omega,
            rot=rot,
            mass=clump.mass,
            inertia=inertia,
            diameter=clump.equivalent_diameter,
            active=True,
            clump_type=next(i for i, c in enumerate(self._clumps) if c is clump),
            material=self._material_index(material),
        )
        start = self.spheres.append(b, clump, rot, position)
        self.bodies.sphere_start[b] = start
        self.bodies.sphere_count[b] = self.spheres.n - start
        self._auto_dt = None
        self._stale = True
        return b

    def _material_index(self, material: ContactParams | None) -> int:
        return self._default_material if material is None else self.materials.index(material)

    def add_wall(self, wall: WallMesh) -> int:
        """Add a wall; returns its index."""
        self.walls.append(wall)
        self._walls = wall_arrays(self.walls, self._material_index)
        self._auto_dt = None
        self._stale = True
        return len(self.walls) - 1

    def remove_body(self, i: int) -> None:
        """Take body ``i`` out of the simulation (it keeps its index and last state)."""
        if not 0 <= i < self.bodies.n:
            raise SimulationError(f"no body {i}; there are {self.bodies.n}")
        self.bodies.active[i] = False
        self._stale = True

    # ---------------------------------------------------------------- state

    @property
    def t(self) -> float:
        return float(self._run.clock[L.K_T])

    @property
    def cost(self) -> float:
        return float(self._run.clock[L.K_COST])

    @property
    def dt(self) -> float:
        if self._forced_dt is not None:
            return self._forced_dt
        if self._auto_dt is None:
            table = self.materials.materials
            walls = [table[k] for k in self._walls.material]
            stiffest = max(
                (table[k] for k in set(self.bodies.material.tolist())), key=lambda m: m.E, default=self.params
            )
            self._auto_dt = automatic_time_step(self._clumps, stiffest, walls, self.dt_fraction)
        return self._auto_dt

    @property
    def n_contacts(self) -> int:
        """Sphere contacts (sphere-sphere and sphere-facet) that carried force at the last step."""
        return int(self._run.counters[L.C_CONTACTS])

    @property
    def n_builds(self) -> int:
        """How often the neighbour lists were rebuilt."""
        return int(self._run.counters[L.C_BUILDS])

    def wall_displacement(self, k: int, t: float | None = None) -> np.ndarray:
        return evaluate(self._walls.motion[k], self.t if t is None else t)[0]

    def wall_vertices(self, k: int, t: float | None = None) -> np.ndarray:
        """Vertices of wall k at time t (now by default)."""
        return self.walls[k].vertices + self.wall_displacement(k, t)

    def shape(self, b: int) -> Clump | Polyhedron:
        """The clump or polyhedron body ``b`` was added as."""
        return self._clumps[int(self.bodies.clump_type[b])]

    def sphere_positions(self) -> np.ndarray:
        """World sphere centres (recomputed from body poses)."""
        b = self.spheres.body
        return self.bodies.pos[b] + np.einsum("sij,sj->si", self.bodies.rot[b], self.spheres.offset)

    def kinetic_energy(self) -> float:
        """Translational plus rotational kinetic energy of the active bodies (J)."""
        a = self.bodies.active
        trans = 0.5 * np.sum(self.bodies.mass[a] * np.sum(self.bodies.vel[a] ** 2, axis=1))
        rot = 0.5 * np.sum(self.bodies.omega[a] * self.bodies.angmom[a])
        return float(trans + rot)

    def potential_energy(self) -> float:
        """Gravitational potential energy of the active bodies relative to the origin (J)."""
        a = self.bodies.active
        return float(-np.sum(self.bodies.mass[a] * (self.bodies.pos[a] @ self.gravity)))

    # ---------------------------------------------------------------- running

    def run(
        self,
        until: float,
        *,
        chunk_time: float = 0.01,
        deadline: float | None = None,
        should_stop: Callable[[], bool] | None = None,
        on_chunk: Callable[[Simulation], None] | None = None,
    ) -> RunStatus:
        """Advance to simulated time ``until`` in chunks of ``chunk_time`` simulated seconds.

        ``deadline`` is a ``time.monotonic()`` value checked between chunks (status ``timeout``);
        ``should_stop()`` returning True ends with ``cancelled``; ``on_chunk(sim)`` runs after
        every chunk (progress, snapshots, removing bodies).
        """
        if not chunk_time > 0:
            raise SimulationError(f"chunk_time must be > 0 s, got {chunk_time!r}")
        start_steps = self.steps
        if self.bodies.n == 0:
            self._run.clock[L.K_T] = max(self.t, until)
            return RunStatus(SimulationStatus.OK, "no bodies", self.t, 0)
        dt = self.dt
        # Ceil, not round: a stop less than half a step ahead must still be reached, or a caller
        # looping 'while t < stop: run(until=stop)' would never advance.
        remaining = max(0, math.ceil((until - self.t) / dt - 1e-9))
        chunk_steps = max(1, int(round(chunk_time / dt)))
        while remaining > 0:
            if should_stop is not None and should_stop():
                return RunStatus(
                    SimulationStatus.CANCELLED,
                    f"cancelled at t={self.t:.6g} s",
                    self.t,
                    self.steps - start_steps,
                )
            if deadline is not None and time.monotonic() > deadline:
                return RunStatus(
                    SimulationStatus.TIMEOUT,
                    f"deadline passed at t={self.t:.6g} s",
                    self.t,
                    self.steps - start_steps,
                )
            n = min(chunk_steps, remaining)
            status, done = self._advance(n, dt)
            remaining -= done
            if status != L.STATUS_OK:
                report = self._failure(status, dt, self.steps - start_steps)
                log.warning(report.message)
                return report
            self._watch_overlap()
            if on_chunk is not None:
                on_chunk(self)
        return RunStatus(SimulationStatus.OK, "", self.t, self.steps - start_steps)

    # ---------------------------------------------------------------- validity

    def resolves_contacts(self) -> bool:
        """Whether the step is at most the automatic one, i.e. integrates every contact well.

        Then an overlap beyond the limit is physical (too soft for the impact), not numerical.
        """
        if self._forced_dt is None:
            return True
        materials = [w.material or self.params for w in self.walls]
        automatic = automatic_time_step(self._clumps, self.params, materials, DEFAULT_FRACTION)
        return self._forced_dt <= automatic * (1 + 1e-9)

    def current_overlap(self) -> float:
        """Largest overlap of the last step's contacts, as a fraction of the smaller
        ``overlap_scale`` (a sphere's radius, a polyhedron piece's rounding: ``dem/validity.py``)."""
        worst = 0.0
        radius = self.spheres.rounding
        pairs, wall_pairs = self._lists.pairs, self._lists.wall_pairs
        n_pp, n_wp = int(pairs.count[neighbours.N_PAIRS]), int(wall_pairs.count[neighbours.N_PAIRS])
        if n_pp:
            delta = pairs.delta[:n_pp]
            touching = delta > 0
            if np.any(touching):
                i, j = pairs.i[:n_pp][touching], pairs.j[:n_pp][touching]
                worst = max(worst, float(np.max(delta[touching] / np.minimum(radius[i], radius[j]))))
        if n_wp:
            delta = wall_pairs.delta[:n_wp]
            touching = delta > 0
            if np.any(touching):
                worst = max(worst, float(np.max(delta[touching] / radius[wall_pairs.i[:n_wp][touching]])))
        return worst

    def _watch_overlap(self) -> None:
        self.max_overlap = max(self.max_overlap, self.current_overlap())

    def _body_overlap(self, body: int) -> float:
        """The deepest overlap of ``body``'s spheres with other bodies' spheres and the walls,
        as a fraction of the smaller radius, measured at the current state.

        A rounded polyhedron's contacts need the cores' closest features, which only the kernels
        compute: its figure is the deepest overlap the last step recorded for the body, and at
        least the limit, since the kernel stopped at a contact beyond it (before recording it)."""
        s = self.spheres
        if np.any(s.core_count[s.body == body] > 0):
            return max(self._recorded_overlap(body), self._overlap_limit)
        x, radius, owner = self.sphere_positions(), s.radius, s.body
        mine = np.flatnonzero(owner == body)
        others = np.flatnonzero((owner != body) & self.bodies.active[owner])
        worst = 0.0
        if len(mine) and len(others):
            gap = np.linalg.norm(x[mine, None, :] - x[None, others, :], axis=2)
            reach = radius[mine, None] + radius[None, others]
            ratio = (reach - gap) / np.minimum(radius[mine, None], radius[None, others])
            worst = max(worst, float(ratio.max()))
        facets = self._walls.facets
        for k in mine:
            for facet in range(len(facets.wall)):
                disp = self._walls.disp[facets.wall[facet]]
                d2, *_ = closest_point_on_facet(x[k, 0], x[k, 1], x[k, 2], facets, facet, *disp)
                worst = max(worst, (radius[k] - math.sqrt(d2)) / radius[k])
        return max(worst, 0.0)

    def _recorded_overlap(self, body: int) -> float:
        """The deepest overlap the last step recorded for ``body``'s contacts, as in
        ``current_overlap``."""
        owner, scale = self.spheres.body, self.spheres.rounding
        worst = 0.0
        for pairs, wall in ((self._lists.pairs, False), (self._lists.wall_pairs, True)):
            n = int(pairs.count[neighbours.N_PAIRS])
            delta, i = pairs.delta[:n], pairs.i[:n]
            if wall:
                mine, size = owner[i] == body, scale[i]
            else:
                j = pairs.j[:n]
                mine, size = (owner[i] == body) | (owner[j] == body), np.minimum(scale[i], scale[j])
            mine &= delta > 0
            if np.any(mine):
                worst = max(worst, float(np.max(delta[mine] / size[mine])))
        return worst

    def _failure(self, status: int, dt: float, steps: int) -> RunStatus:
        """What a kernel's bad status means: physics beyond the contact model, or numerics."""
        body = int(self._run.counters[L.C_BAD_BODY])
        where = f"at t={self.t:.6g} s: body {body}"
        if status == L.STATUS_UNSTABLE_OVERLAP and self.resolves_contacts():
            # The kernel stops at the first step past the limit, so the overlap measured now is
            # just above it. How far the impact would have gone is the measure of invalidity:
            # an undamped linear spring at overlap d0 closing at speed v reaches
            # sqrt(d0^2 + m v^2 / K), and the E that keeps it at the limit scales as its square.
            overlap = self._body_overlap(body)
            speed = float(np.linalg.norm(self.bodies.vel[body]))
            own = self.spheres.body == body
            r = float(self.spheres.rounding[own].min())
            unit = "its rounding" if np.any(self.spheres.core_count[own] > 0) else "a sphere radius"
            stiffness = wall_stiffness(self.params.E, float(self.bodies.diameter[body]), self.params.E)
            heading = math.sqrt(overlap**2 + float(self.bodies.mass[body]) * speed**2 / (stiffness * r * r))
            self.max_overlap = max(self.max_overlap, heading)
            needed = self.params.E * (heading / self._overlap_limit) ** 2
            message = (
                f"invalid {where} overlapped {overlap:.2f} of {unit} (limit "
                f"{self._overlap_limit:g}) closing at {speed:.2g} m/s, heading for {heading:.2f}, with "
                f"a step that resolves the contact (dt={dt:.3g} s): E = {self.params.E:.3g} Pa is too "
                f"soft for this impact (about {needed:.2g} Pa would keep it within the limit); the "
                "parameters are outside the linear contact model's range of validity"
            )
            return RunStatus(SimulationStatus.INVALID, message, self.t, steps)
        if self._forced_dt is not None and not self.resolves_contacts():
            advice = "the forced dt exceeds the automatic step; remove it or make it smaller"
        elif status == L.STATUS_UNSTABLE_SPEED:
            advice = f"lower dt_fraction, or raise max_speed ({self._max_speed:g} m/s) if speeds are real"
        else:
            advice = "lower dt_fraction"
        message = f"unstable {where} {_UNSTABLE_REASONS[status]} (dt={dt:.3g} s); {advice}"
        return RunStatus(SimulationStatus.UNSTABLE, message, self.t, steps)

    def _advance(self, n: int, dt: float) -> tuple[int, int]:
        """Run n steps through the kernel, growing lists as needed; returns (status, steps done)."""
        self._prepare()
        counters = self._run.counters
        done = 0
        resume = False
        while True:
            need_forces = self._stale and not resume
            status = L.run_steps(
                n - done,
                dt,
                need_forces,
                resume,
                self._run,
                self._settings,
                self.bodies.arrays(),
                self.spheres.arrays(),
                self._walls,
                self._lists,
            )
            done += int(counters[L.C_STEPS])
            self.steps += int(counters[L.C_STEPS])
            self._collect_events()
            if status == L.STATUS_CAPACITY:
                resume = bool(counters[L.C_MIDSTEP])
                self._lists = neighbours.grown(self._lists)
                continue
            if need_forces and status == L.STATUS_OK:
                self._stale = False
            if status != L.STATUS_OK or done >= n:
                return status, done

    def _collect_events(self) -> None:
        run = self._run
        for k in range(self._events_seen, int(run.counters[L.C_EVENTS])):
            body, t = int(run.left_body[k]), float(run.left_time[k])
            self.removed_out_of_domain.append((body, t))
            self._stale = True
            log.debug("body %d left the domain at t=%.6g s", body, t)
        self._events_seen = int(run.counters[L.C_EVENTS])

    # ---------------------------------------------------------------- kernel state

    def _prepare(self) -> None:
        """Size the lists' per-sphere state and the event list, and settle the run's settings."""
        ns = self.spheres.n
        grid = neighbours.sized_grid(self._lists.grid, ns, self.bodies.n, len(self._walls.motion))
        if grid is not self._lists.grid:
            self._lists = self._lists._replace(grid=grid)
            self._stale = True
        self._run = L.with_event_room(self._run, self.bodies.n)
        radius = self.spheres.radius
        active_r = radius[self.bodies.active[self.spheres.body]] if ns else radius
        r_max = float(active_r.max()) if len(active_r) else float(radius.max())
        skin = self._skin if self._skin is not None else 1.0 * float(np.mean(radius))
        old = self._settings
        self._settings = L.Settings(
            material=self.materials.arrays(),
            gravity=self.gravity,
            domain_lo=self.domain_min,
            domain_hi=self.domain_max,
            skin=float(skin),
            cell_min=float(2.0 * r_max + skin),
            overlap_limit=float(self._overlap_limit),
            max_speed=float(self._max_speed),
        )
        if old is not None and not (
            np.array_equal(old.material.E, self._settings.material.E)
            and np.array_equal(old.material.law, self._settings.material.law)
        ):
            self._stale = True  # the body pairs' law constants are computed at list builds
