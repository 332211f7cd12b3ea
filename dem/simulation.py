"""The engine's driver: a set of rigid clump bodies and walls advanced in time by the kernels.

``Simulation`` owns the state arrays (``dem/bodies.py``), the wall geometry (``dem/walls.py``)
and the neighbour lists, and runs ``dem.kernels.run_steps`` in chunks of simulated time. Between
chunks Python has control again: progress callbacks, a wall-clock deadline, cancellation and
signals (a numba loop ignores them, so chunks are kept short). ``run`` may be called again and
again, with bodies added or removed in between; physics blow-ups end a run with status
``unstable`` and the time, never with an exception.

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

from dem import kernels as K
from dem.bodies import Bodies, Spheres
from dem.clump import Clump
from dem.contact import ContactParams
from dem.motion import MOTION_ROW, evaluate, motion_row
from dem.quaternion import to_matrix
from dem.result import SimulationStatus
from dem.timestep import DEFAULT_FRACTION, automatic_time_step
from dem.walls import FacetArrays, WallMesh

log = logging.getLogger(__name__)

_UNSTABLE_REASONS = {
    K.STATUS_UNSTABLE_NAN: "has a NaN or infinite state",
    K.STATUS_UNSTABLE_SPEED: "moves faster than max_speed",
    K.STATUS_UNSTABLE_OVERLAP: "overlaps beyond overlap_limit of a sphere radius",
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
    """Rigid multi-sphere bodies, walls, gravity and the contact law of ``params``."""

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
        overlap_limit: float = 0.5,
    ) -> None:
        self.params = params
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
        self._clk = np.zeros(2)
        self._cnt = np.zeros(K.N_CNT, dtype=np.int64)
        self._facets = FacetArrays.build([])
        self._wall_arrays()
        self._grow_lists(1024, 1024)
        self._ev_body = np.zeros(16, dtype=np.int64)
        self._ev_time = np.zeros(16)
        self._events_seen = 0

    # ---------------------------------------------------------------- set-up

    def add_body(
        self,
        clump: Clump,
        position,
        quaternion=(1.0, 0.0, 0.0, 0.0),
        velocity=(0.0, 0.0, 0.0),
        omega=(0.0, 0.0, 0.0),
    ) -> int:
        """Add a rigid body (its centre of mass at ``position``); returns its index."""
        position = _vector(position, 3, "position")
        q = _vector(quaternion, 4, "quaternion")
        if np.linalg.norm(q) == 0:
            raise SimulationError("quaternion must not be zero")
        q = q / np.linalg.norm(q)
        inertia = _vector(clump.inertia, 3, "clump inertia")
        if not clump.mass > 0 or np.any(inertia <= 0) or clump.n_spheres == 0 or np.any(clump.radius <= 0):
            raise SimulationError(
                f"clump {clump.name!r}: needs mass > 0, inertia > 0 and at least one sphere of radius > 0"
            )
        if np.any(position < self.domain_min) or np.any(position > self.domain_max):
            raise SimulationError(f"position {position.tolist()} is outside the domain")
        rot = np.empty((3, 3))
        to_matrix(q, rot)
        omega = _vector(omega, 3, "omega")
        angmom = rot @ (inertia * (rot.T @ omega))
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
            sphere_count=clump.n_spheres,
            clump_type=next(i for i, c in enumerate(self._clumps) if c is clump),
        )
        start = self.spheres.append(b, clump, position + np.asarray(clump.offset) @ rot.T)
        self.bodies.raw("sphere_start")[b] = start
        self._auto_dt = None
        self._stale = True
        return b

    def add_wall(self, wall: WallMesh) -> int:
        """Add a wall; returns its index."""
        self.walls.append(wall)
        self._facets = FacetArrays.build(self.walls)
        self._wall_arrays()
        self._auto_dt = None
        self._stale = True
        return len(self.walls) - 1

    def remove_body(self, i: int) -> None:
        """Take body ``i`` out of the simulation (it keeps its index and last state)."""
        if not 0 <= i < self.bodies.n:
            raise SimulationError(f"no body {i}; there are {self.bodies.n}")
        self.bodies.raw("active")[i] = False
        self._stale = True

    # ---------------------------------------------------------------- state

    @property
    def t(self) -> float:
        return float(self._clk[K.K_T])

    @property
    def cost(self) -> float:
        return float(self._clk[K.K_COST])

    @property
    def dt(self) -> float:
        if self._forced_dt is not None:
            return self._forced_dt
        if self._auto_dt is None:
            materials = [w.material or self.params for w in self.walls]
            self._auto_dt = automatic_time_step(self._clumps, self.params, materials, self.dt_fraction)
        return self._auto_dt

    @property
    def n_contacts(self) -> int:
        """Sphere contacts (sphere-sphere and sphere-facet) that carried force at the last step."""
        return int(self._cnt[K.C_CONTACTS])

    @property
    def n_builds(self) -> int:
        """How often the neighbour lists were rebuilt."""
        return int(self._cnt[K.C_BUILDS])

    def wall_displacement(self, k: int, t: float | None = None) -> np.ndarray:
        return evaluate(self._motion_rows[k], self.t if t is None else t)[0]

    def wall_velocity(self, k: int, t: float | None = None) -> np.ndarray:
        return evaluate(self._motion_rows[k], self.t if t is None else t)[1]

    def wall_vertices(self, k: int, t: float | None = None) -> np.ndarray:
        """Vertices of wall k at time t (now by default)."""
        return self.walls[k].vertices + self.wall_displacement(k, t)

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
            self._clk[K.K_T] = max(self.t, until)
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
            if status != K.STATUS_OK:
                body = int(self._cnt[K.C_BAD_BODY])
                message = (
                    f"unstable at t={self.t:.6g} s: body {body} {_UNSTABLE_REASONS[status]} "
                    f"(dt={dt:.3g} s); use a smaller dt or dt_fraction"
                )
                log.warning(message)
                return RunStatus(SimulationStatus.UNSTABLE, message, self.t, self.steps - start_steps)
            if on_chunk is not None:
                on_chunk(self)
        return RunStatus(SimulationStatus.OK, "", self.t, self.steps - start_steps)

    def _advance(self, n: int, dt: float) -> tuple[int, int]:
        """Run n steps through the kernel, growing lists as needed; returns (status, steps done)."""
        self._prepare()
        done = 0
        resume = False
        while True:
            need_forces = self._stale and not resume
            status = self._call_kernel(n - done, need_forces, resume, dt)
            done += int(self._cnt[K.C_STEPS])
            self.steps += int(self._cnt[K.C_STEPS])
            self._collect_events()
            if status == K.STATUS_CAPACITY:
                resume = bool(self._cnt[K.C_MIDSTEP])
                self._grow_lists(int(self._cnt[K.C_NEED_PP]), int(self._cnt[K.C_NEED_WP]))
                continue
            if need_forces and status == K.STATUS_OK:
                self._stale = False
            if status != K.STATUS_OK or done >= n:
                return status, done

    def _call_kernel(self, n: int, need_forces: bool, resume: bool, dt: float) -> int:
        b, s, f = self.bodies, self.spheres, self._facets
        return K.run_steps(
            n,
            need_forces,
            resume,
            dt,
            self._clk,
            self._cnt,
            self._par,
            self._dims,
            s.n,
            b.n,
            b.raw("pos"),
            b.raw("vel"),
            b.raw("quat"),
            b.raw("angmom"),
            b.raw("omega"),
            b.raw("rot"),
            b.raw("force"),
            b.raw("torque"),
            b.raw("mass"),
            b.raw("inertia"),
            b.raw("diameter"),
            b.raw("active"),
            s._x,
            self._x_build,
            s._radius,
            s._offset,
            s._body,
            self._motion_rows,
            self._wall_disp,
            self._wall_vel,
            self._wall_mat,
            f.tri,
            f.facet_tri_start,
            f.facet_tri_count,
            f.facet_wall,
            f.facet_lo,
            f.facet_hi,
            f.facet_normal,
            f.facet_offset,
            self._cell_start,
            self._cell_items,
            self._sphere_cell,
            self._tmp,
            self._lb,
            self._pp_i,
            self._pp_j,
            self._pp_hist,
            self._pp_group,
            self._pp_delta,
            self._pp_n,
            self._grp_sum,
            self._grp_law,
            self._new_i,
            self._new_j,
            self._new_hist,
            self._wp_i,
            self._wp_f,
            self._wp_hist,
            self._wp_delta,
            self._wp_n,
            self._wp_cp,
            self._wp_keep,
            self._facet_sum,
            self._new_wi,
            self._new_wf,
            self._new_whist,
            self._ev_body,
            self._ev_time,
        )

    def _collect_events(self) -> None:
        for k in range(self._events_seen, int(self._cnt[K.C_EVENTS])):
            body, t = int(self._ev_body[k]), float(self._ev_time[k])
            self.removed_out_of_domain.append((body, t))
            self._stale = True
            log.debug("body %d left the domain at t=%.6g s", body, t)
        self._events_seen = int(self._cnt[K.C_EVENTS])

    # ---------------------------------------------------------------- arrays

    def _prepare(self) -> None:
        """Size the per-sphere scratch arrays, the cell grid and the parameter vector."""
        ns = self.spheres.n
        if not hasattr(self, "_x_build") or len(self._x_build) != len(self.spheres._x):
            old = getattr(self, "_x_build", np.zeros((0, 3)))
            self._x_build = np.zeros_like(self.spheres._x)
            self._x_build[: len(old)] = old
            self._stale = True
        if len(self._ev_body) < len(self.bodies.raw("pos")):
            for name in ("_ev_body", "_ev_time"):
                old = getattr(self, name)
                new = np.zeros(len(self.bodies.raw("pos")), dtype=old.dtype)
                new[: len(old)] = old
                setattr(self, name, new)
        radius = self.spheres.radius
        active_r = radius[self.bodies.active[self.spheres.body]] if ns else radius
        r_max = float(active_r.max()) if len(active_r) else float(radius.max())
        skin = self._skin if self._skin is not None else 1.0 * float(np.mean(radius))
        # The kernel grids the spheres' bounding box with cells of at least this size, using
        # at most this many cells (a few per sphere keeps the empty-cell overhead small).
        n_cells = max(8 * ns, 1024)
        if not hasattr(self, "_cell_start") or len(self._cell_start) != n_cells + 1:
            self._cell_start = np.zeros(n_cells + 1, dtype=np.int64)
            self._dims = np.ones(3, dtype=np.int64)
        if not hasattr(self, "_tmp") or len(self._tmp) != ns:
            self._cell_items = np.zeros(ns, dtype=np.int64)
            self._sphere_cell = np.zeros(ns, dtype=np.int64)
            self._tmp = np.zeros(ns, dtype=np.int64)
            self._lb = np.zeros(3)
        p = self.params
        old_par = getattr(self, "_par", None)
        self._par = np.zeros(K.N_PAR)
        self._par[[K.P_E, K.P_ZETA, K.P_MU, K.P_KT]] = p.E, p.damping_ratio, p.mu, p.tangential_ratio
        self._par[K.P_SKIN] = skin
        self._par[K.P_OVERLAP] = self._overlap_limit
        self._par[K.P_VMAX] = self._max_speed
        self._par[K.P_GX : K.P_GX + 3] = self.gravity
        self._par[K.P_LO : K.P_LO + 3] = self.domain_min
        self._par[K.P_HI : K.P_HI + 3] = self.domain_max
        self._par[K.P_CELL_MIN] = 2.0 * r_max + skin
        law = [K.P_E, K.P_ZETA, K.P_KT]
        if old_par is not None and not np.array_equal(old_par[law], self._par[law]):
            self._stale = True  # the body pairs' law constants are computed at list builds

    def _wall_arrays(self) -> None:
        n = len(self.walls)
        self._motion_rows = np.zeros((n, MOTION_ROW))
        self._wall_mat = np.zeros((n, 4))
        for k, wall in enumerate(self.walls):
            m = wall.material or self.params
            self._motion_rows[k] = motion_row(wall.motion)
            self._wall_mat[k] = m.E, m.damping_ratio, m.mu, m.tangential_ratio
        self._wall_disp = np.zeros((n, 3))
        self._wall_vel = np.zeros((n, 3))
        self._facet_sum = np.zeros(max(len(self._facets.facet_wall), 1))

    def _grow_lists(self, need_pp: int, need_wp: int) -> None:
        """(Re)allocate the neighbour lists with room to spare, keeping the current entries."""
        cap_pp = max(1024, 2 * need_pp, len(getattr(self, "_pp_i", ())))
        cap_wp = max(1024, 2 * need_wp, len(getattr(self, "_wp_i", ())))
        n_pp, n_wp = int(self._cnt[K.C_PP]), int(self._cnt[K.C_WP])

        def grown(name, shape, dtype, keep):
            new = np.zeros(shape, dtype=dtype)
            if keep and hasattr(self, name):
                old = getattr(self, name)
                new[:keep] = old[:keep]
            setattr(self, name, new)

        if not hasattr(self, "_pp_i") or cap_pp > len(self._pp_i):
            grown("_pp_i", cap_pp, np.int64, n_pp)
            grown("_pp_j", cap_pp, np.int64, n_pp)
            grown("_pp_hist", (cap_pp, 3), np.float64, n_pp)
            grown("_pp_group", cap_pp, np.int64, n_pp)
            for name, shape in (
                ("_pp_delta", cap_pp),
                ("_pp_n", (cap_pp, 3)),
                ("_grp_sum", cap_pp),
                ("_grp_law", (cap_pp, 4)),
                ("_new_hist", (cap_pp, 3)),
            ):
                grown(name, shape, np.float64, 0)
            grown("_new_i", cap_pp, np.int64, 0)
            grown("_new_j", cap_pp, np.int64, 0)
        if not hasattr(self, "_wp_i") or cap_wp > len(self._wp_i):
            grown("_wp_i", cap_wp, np.int64, n_wp)
            grown("_wp_f", cap_wp, np.int64, n_wp)
            grown("_wp_hist", (cap_wp, 3), np.float64, n_wp)
            for name, shape in (
                ("_wp_delta", cap_wp),
                ("_wp_n", (cap_wp, 3)),
                ("_wp_cp", (cap_wp, 3)),
                ("_new_whist", (cap_wp, 3)),
            ):
                grown(name, shape, np.float64, 0)
            grown("_wp_keep", cap_wp, np.bool_, 0)
            grown("_new_wi", cap_wp, np.int64, 0)
            grown("_new_wf", cap_wp, np.int64, 0)
