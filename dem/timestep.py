"""The automatic time step: a fraction of the shortest contact duration the system can have.

For every pair of body types (and every body type against every wall material) the contact
duration of the linear law is ``t_c = pi sqrt(m* / K)`` (undamped half period; damping only
lengthens it), with ``K`` from ``dem.contact`` and ``m*`` the series of the partners'
*effective* masses. A contact at body-frame point c with normal n accelerates the body both
ways, ``1/m_eff = 1/m + (c x n)^T I^-1 (c x n)`` (the contact point's own radius drops out of
``c x n`` because it lies along n), so a thin plate hit at a corner is several times lighter
than its mass: that is the rotational mode of thin bodies. We take the worst n for every sphere
centre c: ``|c|^2 lambda_max(I^-1 projected on the plane normal to c)``. For a rounded
polyhedron the points c are its core's vertices (``lever_points``): a contact acts at a core
vertex plus r along n, and the r n part drops out of ``c x n`` as well.

Several spheres of one body touching the same partner do not stiffen the contact: the contact
law shares the body pair's stiffness among them (``dem/contact.py``), so a flat face landing on
a wall is one contact of stiffness K for the time step too.

``dt = fraction * min t_c`` (fraction 1/20 by default), hence ``dt ~ 1 / sqrt(E)``. Pure
functions of clumps and materials; nothing here integrates.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from dem.clump import Clump
from dem.contact import ContactParams, normal_stiffness, series, wall_stiffness
from dem.frames import norm, transform
from dem.polyhedra import Polyhedron

DEFAULT_FRACTION = 1.0 / 20.0


class TimeStepError(ValueError):
    """No time step can be derived (no bodies) or the requested fraction is unusable."""


def lever_points(shape: Clump | Polyhedron) -> np.ndarray:
    """Body-frame points whose lever arms bound those of any contact: sphere centres of a clump,
    core vertices of a rounded polyhedron."""
    return np.asarray(shape.core if isinstance(shape, Polyhedron) else shape.offset, dtype=np.float64)


def effective_mass(clump: Clump | Polyhedron) -> float:
    """Smallest effective mass of the body at any of its contacts (kg)."""
    inv_inertia = np.diag(1.0 / np.asarray(clump.inertia, dtype=np.float64))
    worst = 0.0
    for c in lever_points(clump):
        length = norm(c)
        if length == 0.0:
            continue
        axis = c / length
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(axis, helper)
        u /= norm(u)
        basis = np.stack([u, np.cross(axis, u)])
        (p_uu, p_uv), (_, p_vv) = transform(transform(basis, inv_inertia), basis.T).tolist()
        largest = 0.5 * (p_uu + p_vv) + math.sqrt(0.25 * (p_uu - p_vv) ** 2 + p_uv * p_uv)
        worst = max(worst, length * length * largest)
    return 1.0 / (1.0 / clump.mass + worst)


def contact_duration(stiffness: float, mass: float) -> float:
    """pi sqrt(m / K): the undamped linear contact's duration."""
    return math.pi * math.sqrt(mass / stiffness)


def shortest_contact_duration(
    clumps: Iterable[Clump], params: ContactParams, wall_materials: Iterable[ContactParams] = ()
) -> float:
    """min t_c over body-type pairs and body types against walls."""
    clumps = list(clumps)
    if not clumps:
        raise TimeStepError("no bodies: add a body before asking for the automatic time step, or force dt")
    masses = [effective_mass(c) for c in clumps]
    sizes = [c.equivalent_diameter for c in clumps]
    shortest = math.inf
    for a in range(len(clumps)):
        for b in range(a, len(clumps)):
            k = normal_stiffness(params.E, sizes[a], params.E, sizes[b])
            shortest = min(shortest, contact_duration(k, series(masses[a], masses[b])))
        for wall in wall_materials:
            shortest = min(shortest, contact_duration(wall_stiffness(params.E, sizes[a], wall.E), masses[a]))
    return shortest


def automatic_time_step(
    clumps: Iterable[Clump],
    params: ContactParams,
    wall_materials: Iterable[ContactParams] = (),
    fraction: float = DEFAULT_FRACTION,
) -> float:
    """fraction * shortest contact duration."""
    if not 0.0 < fraction <= 1.0:
        raise TimeStepError(f"dt_fraction must be in (0, 1], got {fraction}")
    return fraction * shortest_contact_duration(clumps, params, wall_materials)
