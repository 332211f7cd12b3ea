"""Every wall's planar facets flattened for the kernels, and the point-to-facet distance queries
that the neighbour lists (``dem/neighbours.py``) and the contact forces (``dem/forces.py``) share.

A facet (see ``dem/walls.py``) is a set of coplanar triangles; the kernels find one contact per
sphere and facet at the facet's closest point. Each facet's plane (unit normal and offset, at the
reference position) is stored so that a sphere farther from the plane than its reach is dismissed
before the closest-point test on each of its triangles. Walls move rigidly: every query takes the
owning wall's displacement and shifts the point instead of the triangles.

This module must not know about bodies or forces.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np

from dem.conf import JIT_FLAGS
from dem.frames import dot, norm

if TYPE_CHECKING:
    from dem.walls import WallMesh

# A sphere is rejected on its plane distance only when that exceeds its reach by far more than
# rounding, so the plane test never drops a pair that the closest-point test would keep.
PLANE_SLACK = 1.0 + 1e-9


class Facets(NamedTuple):
    """Every wall's facets at their reference positions (before motion), for the kernels."""

    tri: np.ndarray  # (n_tri, 3, 3) triangle corners, grouped by facet
    tri_start: np.ndarray  # (n_facets,) first triangle of each facet
    tri_count: np.ndarray  # (n_facets,)
    wall: np.ndarray  # (n_facets,) index of the owning wall
    lo: np.ndarray  # (n_facets, 3) bounding box at the reference position
    hi: np.ndarray  # (n_facets, 3)
    normal: np.ndarray  # (n_facets, 3) the plane n . x = offset (unit normal)
    offset: np.ndarray  # (n_facets,)

    @property
    def n(self) -> int:
        return len(self.wall)


def build_facets(walls: list[WallMesh]) -> Facets:
    """Flatten the facets of ``walls`` (in order) into one ``Facets``."""
    tris, starts, counts, owners, los, his, normals, offsets = [], [], [], [], [], [], [], []
    n_tri = 0
    for w, wall in enumerate(walls):
        for facet in wall.facets:
            corners = wall.vertices[wall.faces[facet]]
            tris.append(corners)
            starts.append(n_tri)
            counts.append(len(facet))
            owners.append(w)
            los.append(corners.reshape(-1, 3).min(axis=0))
            his.append(corners.reshape(-1, 3).max(axis=0))
            normal = np.cross(corners[0, 1] - corners[0, 0], corners[0, 2] - corners[0, 0])
            normal /= norm(normal)
            normals.append(normal)
            offsets.append(dot(normal, corners[0, 0]))
            n_tri += len(facet)
    if not tris:
        return Facets(
            np.zeros((0, 3, 3)),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            np.zeros(0),
        )
    return Facets(
        np.ascontiguousarray(np.concatenate(tris)),
        np.array(starts, dtype=np.int64),
        np.array(counts, dtype=np.int64),
        np.array(owners, dtype=np.int64),
        np.array(los),
        np.array(his),
        np.array(normals),
        np.array(offsets),
    )


@numba.njit(inline="always", **JIT_FLAGS)
def closest_point_on_triangle(px, py, pz, tri):
    """Closest point of triangle ``tri`` (3, 3) to p (Ericson, Real-Time Collision Detection 5.1.5)."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    abx, aby, abz = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    acx, acy, acz = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - tri[1, 0], py - tri[1, 1], pz - tri[1, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return tri[1, 0], tri[1, 1], tri[1, 2]
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - tri[2, 0], py - tri[2, 1], pz - tri[2, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return tri[2, 0], tri[2, 1], tri[2, 2]
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return (
            tri[1, 0] + w * (tri[2, 0] - tri[1, 0]),
            tri[1, 1] + w * (tri[2, 1] - tri[1, 1]),
            tri[1, 2] + w * (tri[2, 2] - tri[1, 2]),
        )
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


# The two queries below take the ``Facets`` container for their callers' convenience but are
# inlined (``inline="always"``) and hand the search on in plain arrays and scalars: a named tuple
# of eight arrays passed to a compiled call costs about 100 ns, three times the search itself.


@numba.njit(inline="always", **JIT_FLAGS)
def plane_distance(px, py, pz, facets, f, dx, dy, dz):
    """Signed distance of p from the plane of facet f displaced by (dx, dy, dz)."""
    normal = facets.normal
    return (px - dx) * normal[f, 0] + (py - dy) * normal[f, 1] + (pz - dz) * normal[f, 2] - facets.offset[f]


@numba.njit(inline="always", **JIT_FLAGS)
def closest_point_on_facet(px, py, pz, facets, f, dx, dy, dz):
    """(squared distance, closest point, face flag) of p to facet f displaced by (dx, dy, dz).

    The face flag is True when the closest point is the projection of p on the facet's plane
    (an interior contact), False on an edge or a corner.
    """
    normal = facets.normal
    return _closest_point_on_triangles(
        (px - dx, py - dy, pz - dz),
        facets.tri,
        facets.tri_start[f],
        facets.tri_count[f],
        (normal[f, 0], normal[f, 1], normal[f, 2]),
        facets.offset[f],
        (dx, dy, dz),
    )


@numba.njit(**JIT_FLAGS)
def _closest_point_on_triangles(q, tri, start, count, n, offset, disp):
    """``closest_point_on_facet`` for q = p - displacement, the facet being triangles
    ``start:start + count`` of ``tri`` in the plane n . x = offset (q, n, disp: 3-tuples)."""
    qx, qy, qz = q
    nx, ny, nz = n
    dx, dy, dz = disp
    best = np.inf
    bx = by = bz = 0.0
    for t in range(start, start + count):
        cx, cy, cz = closest_point_on_triangle(qx, qy, qz, tri[t])
        d2 = (qx - cx) ** 2 + (qy - cy) ** 2 + (qz - cz) ** 2
        if d2 < best:
            best, bx, by, bz = d2, cx, cy, cz
    plane = (qx * nx + qy * ny + qz * nz - offset) ** 2
    is_face = best - plane <= 1e-10 * best + 1e-30
    return best, bx + dx, by + dy, bz + dz, is_face
