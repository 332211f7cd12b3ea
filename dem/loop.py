"""The run loop: a chunk of time steps in one numba call, and the checks after each step.

One step (``dem/integrate.py`` for the stages)::

    kick; drift (and omega at the new pose); t += dt; walls to their prescribed position at t
    (``dem/motion.py``); sphere positions from the bodies' poses
    neighbour lists rebuilt if any sphere moved more than the Verlet skin allows (``dem/neighbours.py``)
    forces (``dem/forces.py``); kick
    checks: NaN, speed limit, bodies that left the domain (removed and listed)

The state travels in the containers of the modules that build them (``BodyArrays`` and
``SphereArrays`` of ``dem/bodies.py``, ``Walls`` of ``dem/walls.py``, ``Neighbours`` of
``dem/neighbours.py``) and two of this module: ``Settings`` (what the driver decides: limits,
gravity, the particles' material) and ``RunState`` (what the driver reads back: time, cost,
counters, the bodies that left). Nothing here allocates per step and nothing raises for
physics: ``run_steps`` returns a status, and ``dem/simulation.py`` decides what it means.

The per-step kernels (the stages of ``dem/integrate.py``, the checks here, the sphere and facet
passes inside ``compute_forces``) are compiled into their caller (``inline="always"``): a compiled
call that is passed a container costs an atomic reference count up and down for every array in
it, a few hundred a step, which was a fixed cost of several us a step whatever the number of
particles (``benchmarks/README.md``, engine speed session 8). ``compute_forces`` itself stays a
call: ``run_steps`` calls it at two sites, and two inlined copies of the force passes doubled the
cold compile. The steps themselves run in ``_steps``, which like ``compute_forces`` is compiled
without numba's runtime (``dem/conf.py``: ``STEP_FLAGS``), so that binding a container's arrays
costs no reference counts at all (about 150 atomic pairs a step were left, 2 us of a one-sphere
step); ``run_steps`` keeps what allocates (the live rows, listed again when bodies leave).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from dem.conf import JIT_FLAGS, STEP_FLAGS
from dem.forces import body_pair_laws, compute_forces
from dem.integrate import drift, kick, live_rows, update_omega, update_spheres
from dem.materials import MaterialArrays
from dem.motion import evaluate_into
from dem.neighbours import rebuild_lists

STATUS_OK = 0
STATUS_UNSTABLE_NAN = 1  # NaN or infinite state
STATUS_UNSTABLE_SPEED = 2  # a body moves faster than the allowed maximum
STATUS_UNSTABLE_OVERLAP = 3  # an overlap exceeds the allowed fraction of a radius
STATUS_CAPACITY = 4  # a neighbour list needs more room; the driver grows it and resumes

# Layout of ``RunState.counters``.
C_STEPS = 0  # steps done in the last call
C_BUILDS = 1  # neighbour list builds, in total
C_EVENTS = 2  # bodies that left the domain, in total (rows of left_body / left_time)
C_BAD_BODY = 3  # the body an unstable status is about
C_MIDSTEP = 4  # a STATUS_CAPACITY came after the drift of a step (resume finishes it)
C_CONTACTS = 5  # force-carrying sphere contacts at the last step
N_COUNTERS = 6
_BODIES_LEFT = -1  # ``_steps``: bodies left the domain after the step at counters[C_STEPS]
# Layout of ``RunState.clock``.
K_T, K_COST = 0, 1


class Settings(NamedTuple):
    """What the driver decides for a run (floats as numba sees them: change freely)."""

    material: MaterialArrays  # every material and pair of materials (``dem/materials.py``)
    gravity: np.ndarray  # (3,) m/s2
    domain_lo: np.ndarray  # (3,) a body whose centre leaves the box is removed
    domain_hi: np.ndarray  # (3,)
    skin: float  # Verlet skin, m
    cell_min: float  # smallest grid cell: largest sphere diameter + skin, m
    overlap_limit: float  # largest overlap as a fraction of a sphere radius
    max_speed: float  # m/s


class RunState(NamedTuple):
    """What the driver reads back, carried from call to call."""

    clock: np.ndarray  # (2,) K_T time, K_COST accumulated cost
    counters: np.ndarray  # (N_COUNTERS,) int64, C_* layout
    left_body: np.ndarray  # (capacity,) int64 bodies that left the domain, in order
    left_time: np.ndarray  # (capacity,) when


def new_run_state() -> RunState:
    return RunState(np.zeros(2), np.zeros(N_COUNTERS, dtype=np.int64), np.zeros(16, np.int64), np.zeros(16))


def with_event_room(run: RunState, n_bodies: int) -> RunState:
    """``run`` with room to list every body as having left."""
    if len(run.left_body) >= n_bodies:
        return run
    left_body = np.zeros(n_bodies, dtype=np.int64)
    left_time = np.zeros(n_bodies)
    left_body[: len(run.left_body)] = run.left_body
    left_time[: len(run.left_time)] = run.left_time
    return RunState(run.clock, run.counters, left_body, left_time)


@numba.njit(**JIT_FLAGS)
def run_steps(n_steps, dt, need_forces, resume, run, settings, bodies, spheres, walls, lists):
    """Advance up to ``n_steps`` steps; returns a status. ``counters[C_STEPS]`` counts steps done
    in this call, ``clock`` holds the time and the accumulated cost, bodies that left go to
    ``left_*``.

    ``need_forces``: forces are stale (bodies added or removed); rebuild and evaluate them at the
    current state without advancing history. ``resume``: the previous call stopped after the
    drift of a step for lack of list capacity; finish that step first.
    """
    clk, cnt = run.clock, run.counters
    lb = np.zeros((bodies.pos.shape[0], 3))
    cnt[C_STEPS] = 0
    live, live_spheres, rotors = live_rows(bodies.active, spheres.body, bodies.inertia)
    force_rebuild = need_forces or resume
    if need_forces and not resume:
        _move_walls(walls, clk[K_T], lists.grid)
        update_spheres(spheres, bodies, live_spheres, lists.grid)
        update_omega(bodies, live)
        if not _rebuild(lists, spheres, bodies, walls, settings, cnt):
            cnt[C_MIDSTEP] = 0
            return STATUS_CAPACITY
        force_rebuild = False
        _, bad = compute_forces(
            bodies, spheres, settings.material, walls, lists, settings.gravity, settings.overlap_limit, 0.0
        )
        if bad >= 0:
            cnt[C_BAD_BODY] = bad
            return STATUS_UNSTABLE_OVERLAP

    while True:
        status = _steps(
            n_steps, dt, resume, force_rebuild, live, live_spheres, rotors, lb,
            run, settings, bodies, spheres, walls, lists,
        )  # fmt: skip
        if status != _BODIES_LEFT:
            break
        live, live_spheres, rotors = live_rows(bodies.active, spheres.body, bodies.inertia)
        resume = False
        force_rebuild = True
    if status == STATUS_OK:
        update_omega(bodies, live)
    return status


@numba.njit(**STEP_FLAGS)
def _steps(
    n_steps, dt, resume, force_rebuild, live, live_spheres, rotors, lb,
    run, settings, bodies, spheres, walls, lists,
):  # fmt: skip
    """The steps of ``run_steps`` from step ``counters[C_STEPS]`` until ``n_steps`` (``STATUS_OK``),
    an unstable state or a full list (their status), or a step after which bodies left the domain
    (``_BODIES_LEFT``: the caller lists the live rows again, which allocates). Compiled without
    numba's runtime (``dem/conf.py``: ``STEP_FLAGS``): no reference counts in the step loop."""
    clk, cnt = run.clock, run.counters
    half = 0.5 * dt
    skin = settings.skin
    step = cnt[C_STEPS]
    while step < n_steps:
        if not resume:
            kick(bodies, live, half)
            drift(bodies, live, rotors, lb, dt)
            clk[K_T] += dt
            _move_walls(walls, clk[K_T], lists.grid)
            sphere_move2 = update_spheres(spheres, bodies, live_spheres, lists.grid)
            sphere_move = math.sqrt(sphere_move2)
            if 2.0 * sphere_move > skin:
                force_rebuild = True
        resume = False
        if force_rebuild:
            if not _rebuild(lists, spheres, bodies, walls, settings, cnt):
                cnt[C_MIDSTEP] = 1
                return STATUS_CAPACITY
            force_rebuild = False
        n_contacts, bad = compute_forces(
            bodies, spheres, settings.material, walls, lists, settings.gravity, settings.overlap_limit, dt
        )
        if bad >= 0:
            cnt[C_BAD_BODY] = bad
            return STATUS_UNSTABLE_OVERLAP
        kick(bodies, live, half)
        step += 1
        cnt[C_STEPS] = step
        clk[K_COST] += live_spheres.shape[0] + n_contacts
        cnt[C_CONTACTS] = n_contacts
        status, n_left = _check_bodies(bodies, live, settings, run)
        if status != STATUS_OK:
            return status
        if n_left > 0:
            return _BODIES_LEFT
    return STATUS_OK


@numba.njit(**JIT_FLAGS)
def _rebuild(lists, spheres, bodies, walls, settings, cnt):
    """Rebuild the lists and their body pairs' contact-law constants; False when out of room."""
    if not rebuild_lists(lists, spheres, bodies.active, walls, settings.skin, settings.cell_min):
        return False
    body_pair_laws(lists.pairs, spheres.body, bodies, settings.material)
    cnt[C_BUILDS] += 1
    return True


@numba.njit(inline="always", **JIT_FLAGS)
def _move_walls(walls, t, grid):
    """The walls to their place at t; each one's largest travel since the last list build kept
    in ``grid.wall_moved2`` (what lets the facet pass skip pairs that cannot have closed their gap)."""
    disp, at_build, moved2 = walls.disp, grid.wall_build, grid.wall_moved2
    for w in range(walls.motion.shape[0]):
        evaluate_into(walls.motion[w], t, disp[w], walls.vel[w])
        dx, dy, dz = disp[w, 0] - at_build[w, 0], disp[w, 1] - at_build[w, 1], disp[w, 2] - at_build[w, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > moved2[w]:
            moved2[w] = d2


@numba.njit(inline="always", **JIT_FLAGS)
def _check_bodies(bodies, live, settings, run):
    """After a step: a NaN or too fast body ends the call with its status; a body whose centre
    left the domain is deactivated and listed. Returns (status, bodies that left)."""
    active, pos, vel, angmom = bodies.active, bodies.pos, bodies.vel, bodies.angmom
    lo, hi = settings.domain_lo, settings.domain_hi
    vmax2 = settings.max_speed**2
    cnt = run.counters
    n_left = 0
    for b in live:
        v2 = vel[b, 0] ** 2 + vel[b, 1] ** 2 + vel[b, 2] ** 2
        l2 = angmom[b, 0] ** 2 + angmom[b, 1] ** 2 + angmom[b, 2] ** 2
        if not (math.isfinite(v2) and math.isfinite(l2) and math.isfinite(pos[b, 0] + pos[b, 1] + pos[b, 2])):
            cnt[C_BAD_BODY] = b
            return STATUS_UNSTABLE_NAN, n_left
        if v2 > vmax2:
            cnt[C_BAD_BODY] = b
            return STATUS_UNSTABLE_SPEED, n_left
        inside = True
        for k in range(3):
            if pos[b, k] < lo[k] or pos[b, k] > hi[k]:
                inside = False
        if not inside:
            active[b] = False
            run.left_body[cnt[C_EVENTS]] = b
            run.left_time[cnt[C_EVENTS]] = run.clock[K_T]
            cnt[C_EVENTS] += 1
            n_left += 1
    return STATUS_OK, n_left
