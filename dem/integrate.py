"""Time integration of the rigid bodies: velocity Verlet as in LIGGGHTS, with the free-rotor
splitting for rotation (``dem.quaternion.free_rotor_steps``; a body with equal principal moments
turns exactly about L, ``isotropic_rotor_step``)::

    kick:   v += dt/2 F/m;  L += dt/2 T            (L: world-frame angular momentum)
    drift:  x += dt v;      q <- free rotor over dt
    (forces at the new positions, ``dem/forces.py``)
    kick:   v += dt/2 F/m;  L += dt/2 T

and the kinematics that follow a drift: the spheres' world centres from the body poses, and
omega = R I^-1 R^T L. The order of the stages is the run loop's (``dem/loop.py``). Kernels only,
over the active bodies; they must not know about contacts or walls.

The kernels visit the rows listed in ``live`` (active bodies) or ``live_spheres`` (their
spheres), ascending, from ``live_rows``: as bodies are removed (an emptying tray), a loop over
every row with a test per row kept a cost per step of the bodies that had gone.
"""

from __future__ import annotations

import numba
import numpy as np

from dem.conf import JIT_FLAGS
from dem.quaternion import free_rotor_steps, isotropic_rotor_step, to_matrix


@numba.njit(**JIT_FLAGS)
def live_rows(active, sbody, inertia):
    """(rows of the active bodies, rows of their spheres, rows of the active bodies whose principal
    moments are not all equal: the free rotors), ascending."""
    isotropic = (inertia[:, 0] == inertia[:, 1]) & (inertia[:, 1] == inertia[:, 2])
    return np.nonzero(active)[0], np.nonzero(active[sbody])[0], np.nonzero(active & ~isotropic)[0]


@numba.njit(inline="always", **JIT_FLAGS)
def kick(bodies, live, h):
    """v += h F/m, L += h T."""
    vel, angmom, force, torque, mass = (
        bodies.vel,
        bodies.angmom,
        bodies.force,
        bodies.torque,
        bodies.mass,
    )
    for b in live:
        hm = h / mass[b]
        for k in range(3):
            vel[b, k] += hm * force[b, k]
            angmom[b, k] += h * torque[b, k]


@numba.njit(inline="always", **JIT_FLAGS)
def drift(bodies, live, rotors, lb, dt):
    """x += dt v and the rotation over dt, then omega at the new pose (``update_omega``'s
    formula, in the same pass as a body's rotation where it can: its rotation and L are still in
    cache). The free rotors (``rotors``, from ``live_rows``) turn all together, turn by turn
    (``dem.quaternion.free_rotor_steps``); ``lb`` (bodies, 3) is scratch for their body-frame L."""
    pos, vel, quat, angmom, inertia, rot, omega = (
        bodies.pos,
        bodies.vel,
        bodies.quat,
        bodies.angmom,
        bodies.inertia,
        bodies.rot,
        bodies.omega,
    )
    for b in live:
        for k in range(3):
            pos[b, k] += dt * vel[b, k]
        if inertia[b, 0] == inertia[b, 1] and inertia[b, 1] == inertia[b, 2]:
            isotropic_rotor_step(quat[b], angmom[b], inertia[b, 0], dt)
            to_matrix(quat[b], rot[b])
            _body_omega(rot, angmom, inertia, omega, b)
    for b in rotors:
        r = rot[b]
        for k in range(3):
            lb[b, k] = r[0, k] * angmom[b, 0] + r[1, k] * angmom[b, 1] + r[2, k] * angmom[b, 2]
    free_rotor_steps(quat, lb, inertia, rotors, dt)
    for b in rotors:
        to_matrix(quat[b], rot[b])
        _body_omega(rot, angmom, inertia, omega, b)


@numba.njit(inline="always", **JIT_FLAGS)
def update_spheres(spheres, bodies, live_spheres, grid):
    """World positions of the spheres; returns the largest squared move since ``grid.x_build``
    (the positions at the last list build) and keeps each body's largest since then in
    ``grid.moved2`` (what lets the force passes skip pairs that cannot have closed their gap)."""
    x, offset, sbody = spheres.x, spheres.offset, spheres.body
    pos, rot = bodies.pos, bodies.rot
    x_build, moved2 = grid.x_build, grid.moved2
    worst = 0.0
    # A body's spheres are consecutive rows: its pose is read once for all of them, and its
    # largest move written once.
    b_at = -1
    m2 = 0.0
    px = py = pz = r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = 0.0
    for s in live_spheres:
        b = sbody[s]
        if b != b_at:
            if b_at >= 0:
                moved2[b_at] = m2
            b_at = b
            m2 = moved2[b]
            px, py, pz = pos[b, 0], pos[b, 1], pos[b, 2]
            r00, r01, r02 = rot[b, 0, 0], rot[b, 0, 1], rot[b, 0, 2]
            r10, r11, r12 = rot[b, 1, 0], rot[b, 1, 1], rot[b, 1, 2]
            r20, r21, r22 = rot[b, 2, 0], rot[b, 2, 1], rot[b, 2, 2]
        ox, oy, oz = offset[s, 0], offset[s, 1], offset[s, 2]
        xs = px + r00 * ox + r01 * oy + r02 * oz
        ys = py + r10 * ox + r11 * oy + r12 * oz
        zs = pz + r20 * ox + r21 * oy + r22 * oz
        x[s, 0], x[s, 1], x[s, 2] = xs, ys, zs
        d2 = (xs - x_build[s, 0]) ** 2 + (ys - x_build[s, 1]) ** 2 + (zs - x_build[s, 2]) ** 2
        if d2 > m2:
            m2 = d2
        if d2 > worst:
            worst = d2
    if b_at >= 0:
        moved2[b_at] = m2
    return worst


@numba.njit(inline="always", **JIT_FLAGS)
def update_omega(bodies, live):
    """omega = R I^-1 R^T L for every active body (L / I when the principal moments are equal)."""
    for b in live:
        _body_omega(bodies.rot, bodies.angmom, bodies.inertia, bodies.omega, b)


@numba.njit(inline="always", **JIT_FLAGS)
def _body_omega(rot, angmom, inertia, omega, b):
    """omega of body b: R I^-1 R^T L (L / I when the principal moments are equal)."""
    if inertia[b, 0] == inertia[b, 1] and inertia[b, 1] == inertia[b, 2]:
        for k in range(3):
            omega[b, k] = angmom[b, k] / inertia[b, 0]
        return
    r = rot[b]
    lx = r[0, 0] * angmom[b, 0] + r[1, 0] * angmom[b, 1] + r[2, 0] * angmom[b, 2]
    ly = r[0, 1] * angmom[b, 0] + r[1, 1] * angmom[b, 1] + r[2, 1] * angmom[b, 2]
    lz = r[0, 2] * angmom[b, 0] + r[1, 2] * angmom[b, 1] + r[2, 2] * angmom[b, 2]
    wx, wy, wz = lx / inertia[b, 0], ly / inertia[b, 1], lz / inertia[b, 2]
    for k in range(3):
        omega[b, k] = r[k, 0] * wx + r[k, 1] * wy + r[k, 2] * wz
