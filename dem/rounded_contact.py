r"""Overlap, normal and contact point of rounded shapes: rounded-polyhedron pieces and spheres
with each other, and with planar wall facets.

A rounded shape is a convex core (vertices placed by a rotation and a position) swept by a ball
of radius r; a sphere is a one-vertex core swept by its radius. The geometry of one contact is
``delta = r_a + r_b - d`` with d the distance of the cores and n from B to A (``dem/convex.py``:
why this single contact per piece pair is conservative and independent of how many vertices a
face has); the contact point is the centroid of the closest-point set, moved to the plane midway
between the cores.

The contact point is the centre of pressure of the overlap patch (``dem.convex.contact_patch``).
Cheap rejections come first, so GJK runs only for pieces that nearly touch:

* piece pairs: a cached separating direction per pair (the last normal): if the cores are
  further apart than ``r_a + r_b`` along it, the pair is apart without GJK (Bullet's
  separating-axis caching);
* facets: the core's extent along the facet normal (two support queries) against the plane.

A facet of several coplanar triangles is one contact: d is the smallest over its triangles, and
the patch combines the triangles at that distance weighted by their patch areas (or lengths),
so a face lying across a facet's diagonal feels no torque. Pure numba; no allocation.
"""

from __future__ import annotations

import numba
import numpy as np

from dem.conf import JIT_FLAGS
from dem.convex import contact_patch, gjk_distance, plane_basis, support


@numba.njit(**JIT_FLAGS)
def _extent(verts, start, count, rot, pos, nx, ny, nz):
    """(min, max) of the placed vertices' projections on n."""
    hx, hy, hz = support(verts, start, count, rot, pos[0], pos[1], pos[2], nx, ny, nz)
    lx, ly, lz = support(verts, start, count, rot, pos[0], pos[1], pos[2], -nx, -ny, -nz)
    return lx * nx + ly * ny + lz * nz, hx * nx + hy * ny + hz * nz


@numba.njit(**JIT_FLAGS)
def pair_geometry(va, sa, ca, rot_a, pa, ra, vb, sb, cb, rot_b, pb, rb, axis, work):
    """Contact of rounded shapes A and B: ``(delta, d, nx, ny, nz, cx, cy, cz, s_uu, s_uw,
    s_ww)``, s the patch's second moments (``dem.convex.contact_patch``).

    delta <= 0: apart (n and c are then not computed). d = 0 with delta > 0: the cores
    intersect (an overlap beyond the rounding; the caller reports it). ``axis`` (3,) is the
    pair's cached separating direction, from B to A, updated here.
    """
    reach = ra + rb
    if axis[0] != 0.0 or axis[1] != 0.0 or axis[2] != 0.0:
        lo_a, _ = _extent(va, sa, ca, rot_a, pa, axis[0], axis[1], axis[2])
        _, hi_b = _extent(vb, sb, cb, rot_b, pb, axis[0], axis[1], axis[2])
        gap = lo_a - hi_b
        if gap > reach:
            return reach - gap, gap, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    d, ax, ay, az, bx, by, bz = gjk_distance(va, sa, ca, rot_a, pa, vb, sb, cb, rot_b, pb)
    if d > 0.0:
        axis[0], axis[1], axis[2] = (ax - bx) / d, (ay - by) / d, (az - bz) / d
    delta = reach - d
    if delta <= 0.0 or d == 0.0:
        return delta, d, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    _, _, cx, cy, cz, s_uu, s_uw, s_ww = contact_patch(
        va, sa, ca, rot_a, pa, vb, sb, cb, rot_b, pb, ax, ay, az, bx, by, bz, delta, work
    )
    return delta, d, axis[0], axis[1], axis[2], cx, cy, cz, s_uu, s_uw, s_ww


@numba.njit(**JIT_FLAGS)
def facet_geometry(va, sa, ca, rot_a, pa, ra, tri_verts, t_start, t_count, disp, normal, offset, eye, work):
    """Contact of rounded shape A with a facet (triangles ``t_start .. t_start + t_count`` of the
    flat vertex array ``tri_verts``, three rows each, displaced by ``disp``; plane
    ``normal . x = offset`` at the reference position): ``(delta, d, nx, ny, nz, cx, cy, cz,
    s_uu, s_uw, s_ww, is_face)``. ``is_face``: the closest point of the facet is inside it (not on
    its boundary).
    """
    shift = normal[0] * disp[0] + normal[1] * disp[1] + normal[2] * disp[2]
    lo, hi = _extent(va, sa, ca, rot_a, pa, normal[0], normal[1], normal[2])
    if lo - (offset + shift) > ra or (offset + shift) - hi > ra:
        return -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    best = np.inf
    ax = ay = az = bx = by = bz = 0.0
    for t in range(t_start, t_start + t_count):
        d, qx, qy, qz, wx, wy, wz = gjk_distance(va, sa, ca, rot_a, pa, tri_verts, 3 * t, 3, eye, disp)
        if d < best:
            best, ax, ay, az, bx, by, bz = d, qx, qy, qz, wx, wy, wz
    delta = ra - best
    if delta <= 0.0 or best == 0.0:
        return delta, best, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    nx, ny, nz = (ax - bx) / best, (ay - by) / best, (az - bz) / best
    plane = (ax - disp[0]) * normal[0] + (ay - disp[1]) * normal[1] + (az - disp[2]) * normal[2] - offset
    is_face = plane * plane >= best * best * (1.0 - 1e-10)
    if t_count == 1:
        _, _, cx, cy, cz, s_uu, s_uw, s_ww = contact_patch(
            va, sa, ca, rot_a, pa, tri_verts, 3 * t_start, 3, eye, disp, ax, ay, az, bx, by, bz, delta, work
        )
        return delta, best, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face
    # Several triangles: combine the patches of those the rounded surface overlaps (within delta
    # of the closest), by their loads: area loads if any, else line loads, else equally.
    ux, uy, uz, vx, vy, vz = plane_basis(nx, ny, nz)
    sums = np.zeros((3, 7))  # per kind of load: weight, c (3), weight * (c_u^2, c_u c_w, c_w^2) + s
    for t in range(t_start, t_start + t_count):
        d, _, _, _, _, _, _ = gjk_distance(va, sa, ca, rot_a, pa, tri_verts, 3 * t, 3, eye, disp)
        if d > best + delta:
            continue
        # The facet's triangles are coplanar: every patch is taken along the facet's contact
        # normal (a triangle's own closest points may lie on its edge, with a tilted normal).
        area, length, cx, cy, cz, s_uu, s_uw, s_ww = contact_patch(
            va, sa, ca, rot_a, pa, tri_verts, 3 * t, 3, eye, disp, ax, ay, az, bx, by, bz, delta, work
        )
        kind, weight = (0, area) if area > 0.0 else ((1, length) if length > 0.0 else (2, 1.0))
        cu = cx * ux + cy * uy + cz * uz
        cw = cx * vx + cy * vy + cz * vz
        row = sums[kind]
        row[0] += weight
        row[1] += weight * cx
        row[2] += weight * cy
        row[3] += weight * cz
        row[4] += weight * (s_uu + cu * cu)
        row[5] += weight * (s_uw + cu * cw)
        row[6] += weight * (s_ww + cw * cw)
    kind = 0 if sums[0, 0] > 0.0 else (1 if sums[1, 0] > 0.0 else 2)
    row = sums[kind]
    total = row[0]
    cx, cy, cz = row[1] / total, row[2] / total, row[3] / total
    cu = cx * ux + cy * uy + cz * uz
    cw = cx * vx + cy * vy + cz * vz
    # parallel axes: moments about the combined centre
    s_uu = row[4] / total - cu * cu
    s_uw = row[5] / total - cu * cw
    s_ww = row[6] / total - cw * cw
    return delta, best, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face
