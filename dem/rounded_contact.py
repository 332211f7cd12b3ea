r"""Overlap, normal and contact point of rounded shapes: rounded-polyhedron pieces and spheres
with each other, and with planar wall facets.

A rounded shape is a convex core (vertices placed by a rotation and a position) swept by a ball
of radius r; a sphere is a one-vertex core swept by its radius. The geometry of one contact is
``delta = r_a + r_b - D`` with D the distance of the cores (``dem/convex.py``: why one contact
per piece pair makes a face's stiffness independent of how many vertices it has), crowned
(``dem.crown.crowned_contact``: so that the force is conservative and a face's contact point
moves continuously as it tilts); n points from B to A, and the contact point lies midway between
the cores. The patch of ``dem.convex.contact_patch`` supplies the second moments
of a face's dampers.

Cheap rejections come first, so GJK runs only for pieces that nearly touch:

* both: the box of a piece's core (``box_extent``: its body-frame box, turned with the body) is
  taken along the direction first; a box that clears by the rounding clears the core, for three
  dot products instead of two passes over the core's 48 vertices (the callers do this);
* piece pairs: a cached separating direction per pair (the last normal): if the cores are
  further apart than ``r_a + r_b`` along it, the pair is apart without GJK (Bullet's
  separating-axis caching); else GJK starts from the pair's last simplex (its closest features
  of the last step), which in a lasting contact it confirms in one iteration;
* facets: the core's extent along the facet normal (two support queries) against the plane,
  then per triangle the distance of the ball about the body's centre that holds the core.

A facet of several coplanar triangles is one contact. Where the core's features that can touch
(those within ``r + tol`` of its lowest point) lie over the inside of the facet, as a piece on
the tray's floor or against the middle of a wall does, the facet is its plane for them: the
closest point is the core's lowest vertex, with no GJK, and the crowned contact and the patch are
taken against one triangle of the plane around them (``_plane_geometry``). Elsewhere (a piece
over the facet's boundary) D is the smallest over its triangles, and the patch combines the
triangles near that distance weighted by their patch areas (or lengths); there a face lying over
an inner edge can be pinned to that edge (a triangle's closest points on its edge give it a
tilted normal), which the plane does not do. A core is a vertex array and a
``dem.convex.Core``, a crown a 3-tuple, a facet the wall's triangle array and a ``WallFacet``.
Pure numba; the only allocations are a facet contact's per-triangle table (each triangle's GJK
once for its three passes) and its patch sums (the plane's triangle is scratch: ``work[6]``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from dem.conf import JIT_FLAGS, STEP_FLAGS
from dem.convex import (
    SIMPLEX,
    Core,
    contact_patch,
    gjk_query,
    gjk_scratch,
    patch_moments,
    placed,
    plane_basis,
    support,
)
from dem.crown import crown_floor, crowned_contact
from dem.facets import closest_point_on_triangle

IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # walls translate, never turn
NO_CROWN = (0.0, 0.0, 0.0)  # a wall facet is flat: kappa = 0, so phi = 0 on it (dem/crown.py)
# pair_geometry's GJK-first path defers to the cached-axis test within this fraction of the reach
# and the coordinates' size of touching (the test's rounding is a few 1e-16 of the coordinates)
AXIS_BAND = 1e-9
# _near_pair_geometry takes a pair as apart by its crowns' floor (dem.crown.crown_floor) only
# beyond this fraction of the reach: the crowned distance's rounding is a few 1e-16 m
CROWN_FLOOR_BAND = 1e-9


class WallFacet(NamedTuple):
    """A planar wall facet where it is now: triangles ``start .. start + count`` of the wall
    triangle array (three vertex rows each, passed beside it) moved by the wall's ``disp``; its
    plane is ``normal . x = offset`` at the reference position. Plain numbers, as ``Core``."""

    start: int
    count: int
    disp: tuple  # (x, y, z)
    normal: tuple  # (x, y, z)
    offset: float


@numba.njit(inline="always", **JIT_FLAGS)
def box_extent(x, half, rot, i, b, nx, ny, nz):
    """(lowest, highest) projection on n of the box of sphere row i's core: centre ``x[i]``
    (world), half sizes ``half[i]`` along the axes of body b (the columns of ``rot[b]``). Bounds
    the core's own extent (``_extent``) from outside; a plain sphere's box is its centre."""
    c = x[i, 0] * nx + x[i, 1] * ny + x[i, 2] * nz
    e = (
        half[i, 0] * abs(rot[b, 0, 0] * nx + rot[b, 1, 0] * ny + rot[b, 2, 0] * nz)
        + half[i, 1] * abs(rot[b, 0, 1] * nx + rot[b, 1, 1] * ny + rot[b, 2, 1] * nz)
        + half[i, 2] * abs(rot[b, 0, 2] * nx + rot[b, 1, 2] * ny + rot[b, 2, 2] * nz)
    )
    return c - e, c + e


@numba.njit(inline="always", **JIT_FLAGS)
def facet_high(tri, start, count, disp, nx, ny, nz):
    """Highest projection on n of a facet's triangles ``start .. start + count`` of the triangle
    array (three vertex rows each) moved by ``disp`` (3-tuple): its support along n."""
    high = -np.inf
    for v in range(3 * start, 3 * (start + count)):
        high = max(high, (tri[v, 0] + disp[0]) * nx + (tri[v, 1] + disp[1]) * ny + (tri[v, 2] + disp[2]) * nz)
    return high


@numba.njit(inline="always", **JIT_FLAGS)
def facet_axis_clears(x, half, rot, i, b, va, a, reach, tri, start, count, disp, sx, sy, sz):
    """Whether the unit direction s (facet -> piece; any direction) shows the core ``a`` of sphere
    row i (body b; its box ``x[i]``, ``half[i]``, as ``box_extent``) further than ``reach`` from
    the facet's triangles ``start .. start + count`` moved by ``disp``: the piece's box first
    (three dot products), then its core's lowest vertex along s (one support query). A lower
    bound of their distance, so a pair it clears by the rounding is apart."""
    high = facet_high(tri, start, count, disp, sx, sy, sz)
    low, _ = box_extent(x, half, rot, i, b, sx, sy, sz)
    if low - high > reach:
        return True
    lx, ly, lz = support(va, a, -sx, -sy, -sz)
    return lx * sx + ly * sy + lz * sz - high > reach


@numba.njit(**STEP_FLAGS)
def _triangle(facet, t):
    """Triangle t of the wall triangle array as a placed core."""
    return Core(3 * t, 3, IDENTITY, facet.disp)


@numba.njit(**STEP_FLAGS)
def _extent(verts, core, nx, ny, nz):
    """(min, max) of the placed vertices' projections on n, and the lowest vertex (3-tuple): the
    support queries along -n and n in one pass over the vertices, with the same vertices (the
    first of equals) and so the same figures as ``support``."""
    start, count, rot, _ = core
    r0, r1, r2 = rot
    bx = r0[0] * nx + r1[0] * ny + r2[0] * nz
    by = r0[1] * nx + r1[1] * ny + r2[1] * nz
    bz = r0[2] * nx + r1[2] * ny + r2[2] * nz
    low, high = np.inf, -np.inf
    k_low = k_high = start
    for v in range(start, start + count):
        h = verts[v, 0] * bx + verts[v, 1] * by + verts[v, 2] * bz
        if h > high:
            high, k_high = h, v
        if h < low:  # -h > -low: support's test along -n
            low, k_low = h, v
    hx, hy, hz = placed(verts, core, k_high)
    lx, ly, lz = placed(verts, core, k_low)
    return lx * nx + ly * ny + lz * nz, hx * nx + hy * ny + hz * nz, (lx, ly, lz)


@numba.njit(**STEP_FLAGS)
def _segment_meets_box(p, q, box):
    """Whether the segment p-q (2-tuples) meets the box (u_min, u_max, w_min, w_max)."""
    u0, u1, w0, w1 = box
    if max(p[0], q[0]) < u0 or min(p[0], q[0]) > u1 or max(p[1], q[1]) < w0 or min(p[1], q[1]) > w1:
        return False
    eu, ew = q[0] - p[0], q[1] - p[1]
    above = below = False
    for cu, cw in ((u0, w0), (u1, w0), (u0, w1), (u1, w1)):
        side = eu * (cw - p[1]) - ew * (cu - p[0])
        above = above or side >= 0.0
        below = below or side <= 0.0
    return above and below


@numba.njit(**STEP_FLAGS)
def _shared(tri, facet, t, c):
    """Whether edge c (corners c, c + 1) of triangle t is an edge of another triangle of the
    facet: an inner edge of the facet, not its boundary."""
    p, q = 3 * t + c, 3 * t + (c + 1) % 3
    for s in range(facet.start, facet.start + facet.count):
        if s == t:
            continue
        for e in range(3):
            x, y = 3 * s + e, 3 * s + (e + 1) % 3
            same = tri[x, 0] == tri[p, 0] and tri[x, 1] == tri[p, 1] and tri[x, 2] == tri[p, 2]
            same = same and tri[y, 0] == tri[q, 0] and tri[y, 1] == tri[q, 1] and tri[y, 2] == tri[q, 2]
            flip = tri[x, 0] == tri[q, 0] and tri[x, 1] == tri[q, 1] and tri[x, 2] == tri[q, 2]
            flip = flip and tri[y, 0] == tri[p, 0] and tri[y, 1] == tri[p, 1] and tri[y, 2] == tri[p, 2]
            if same or flip:
                return True
    return False


@numba.njit(**STEP_FLAGS)
def _footprint(va, a, facet, reach, pts):
    """The box (u_min, u_max, w_min, w_max), in ``plane_basis`` of the facet's normal and the
    wall's reference position, of the vertices of core ``a`` at most ``reach`` above its lowest
    one along the normal (one pass: a vertex is taken against the lowest seen so far, so the box
    may hold a few more), and how many those vertices are: their (u, w) in pts[:m, :2], the
    lowest first."""
    nx, ny, nz = facet.normal
    ux, uy, uz, wx, wy, wz = plane_basis(nx, ny, nz)
    r0, r1, r2 = a.rot
    px, py, pz = a.pos[0] - facet.disp[0], a.pos[1] - facet.disp[1], a.pos[2] - facet.disp[2]
    low = np.inf
    u0 = w0 = np.inf
    u1 = w1 = -np.inf
    m = 0
    for v in range(a.start, a.start + a.count):
        x = px + r0[0] * va[v, 0] + r0[1] * va[v, 1] + r0[2] * va[v, 2]
        y = py + r1[0] * va[v, 0] + r1[1] * va[v, 1] + r1[2] * va[v, 2]
        z = pz + r2[0] * va[v, 0] + r2[1] * va[v, 1] + r2[2] * va[v, 2]
        h = x * nx + y * ny + z * nz
        lowest = h < low
        low = min(low, h)
        if h <= low + reach:
            cu, cw = x * ux + y * uy + z * uz, x * wx + y * wy + z * wz
            u0, u1, w0, w1 = min(u0, cu), max(u1, cu), min(w0, cw), max(w1, cw)
            if lowest and m > 0:  # keep the lowest first
                pts[m, 0], pts[m, 1] = pts[0, 0], pts[0, 1]
                pts[0, 0], pts[0, 1] = cu, cw
            else:
                pts[m, 0], pts[m, 1] = cu, cw
            m += 1
    margin = 1e-9 * (u1 - u0 + w1 - w0) + 1e-12  # rounding: an edge touching the box counts
    return (u0 - margin, u1 + margin, w0 - margin, w1 + margin), m


@numba.njit(**STEP_FLAGS)
def _line_clears(p, q, pts, m, margin):
    """Whether the points pts[:m] (u, w) all lie on one side of the line through p and q
    (2-tuples), further than margin: then the segment p-q misses their convex hull."""
    eu, ew = q[0] - p[0], q[1] - p[1]
    length = math.sqrt(eu * eu + ew * ew)
    lo, hi = np.inf, -np.inf
    for k in range(m):
        side = (eu * (pts[k, 1] - p[1]) - ew * (pts[k, 0] - p[0])) / length
        lo, hi = min(lo, side), max(hi, side)
    return lo > margin or hi < -margin


@numba.njit(**STEP_FLAGS)
def _in_plane(tri, k, ux, uy, uz, wx, wy, wz):
    """Row k of the triangle array in the plane's coordinates (u, w)."""
    return tri[k, 0] * ux + tri[k, 1] * uy + tri[k, 2] * uz, tri[k, 0] * wx + tri[k, 1] * wy + tri[k, 2] * wz


@numba.njit(**STEP_FLAGS)
def _inside_facet(tri, facet, box, pts, m):
    """Whether the convex hull of the footprint (``_footprint``: its box, and its m points in pts)
    lies inside the facet (triangles of ``tri`` at the reference position): no boundary edge of
    the facet meets it, and its lowest point is on the facet. An edge meets the hull only if it
    meets the box and the points lie on both sides of the edge's line: the box alone turned away
    a piece whose box's corner reached over an edge oblique to the plane's axes (a piece beside
    the tray's converging walls), which then took the facet's triangles one by one."""
    nx, ny, nz = facet.normal
    ux, uy, uz, wx, wy, wz = plane_basis(nx, ny, nz)
    cu, cw = pts[0, 0], pts[0, 1]
    margin = 1e-9 * (box[1] - box[0] + box[3] - box[2]) + 1e-12
    on_facet = False
    for t in range(facet.start, facet.start + facet.count):
        sides = 0
        for c in range(3):
            p = _in_plane(tri, 3 * t + c, ux, uy, uz, wx, wy, wz)
            q = _in_plane(tri, 3 * t + (c + 1) % 3, ux, uy, uz, wx, wy, wz)
            if (
                _segment_meets_box(p, q, box)
                and not _shared(tri, facet, t, c)
                and not _line_clears(p, q, pts, m, margin)
            ):
                return False
            side = (q[0] - p[0]) * (cw - p[1]) - (q[1] - p[1]) * (cu - p[0])
            sides += 1 if side >= 0.0 else (-1 if side <= 0.0 else 0)
        on_facet = on_facet or abs(sides) == 3
    return on_facet


@numba.njit(**STEP_FLAGS)
def _plane_geometry(va, a, ra, crown_a, facet, box, lowest, work):
    """``facet_geometry`` where the features of core ``a`` that can touch lie over the inside of
    the facet: its contact is that with the facet's plane, n the facet's normal, d the height of
    the core's lowest vertex (``lowest``, a 3-tuple), and no GJK. The crowned contact and the
    patch are taken against one triangle of the plane large enough to hold the core's footprint
    (``_footprint``)."""
    nx, ny, nz = facet.normal
    dx, dy, dz = facet.disp
    plane = facet.offset + nx * dx + ny * dy + nz * dz
    ax, ay, az = lowest
    d = ax * nx + ay * ny + az * nz - plane
    tol = 4.0 * crown_a[2]
    ux, uy, uz, wx, wy, wz = plane_basis(nx, ny, nz)
    cu, cw = 0.5 * (box[0] + box[1]), 0.5 * (box[2] + box[3])
    size = 4.0 * (math.sqrt((box[1] - box[0]) ** 2 + (box[3] - box[2]) ** 2) + ra)
    big = work[6]  # rows 0-2: an equilateral triangle about the footprint, inradius = size / 2
    for c in range(3):
        angle = 2.0 * math.pi * c / 3.0
        pu, pw = cu + size * math.cos(angle), cw + size * math.sin(angle)
        big[c, 0] = facet.offset * nx + pu * ux + pw * wx
        big[c, 1] = facet.offset * ny + pu * uy + pw * wy
        big[c, 2] = facet.offset * nz + pu * uz + pw * wz
    b = Core(0, 3, IDENTITY, facet.disp)
    p_a, p_b = (ax, ay, az), (ax - d * nx, ay - d * ny, az - d * nz)
    crowned, xx, xy, xz, yx, yy, yz, ex, ey, ez = crowned_contact(
        va, a, crown_a, big, b, NO_CROWN, p_a, p_b, tol, work
    )
    delta = ra - crowned
    if delta <= 0.0:
        return delta, d, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    s_uu, s_uw, s_ww = patch_moments(va, a, big, b, p_a, p_b, delta, tol, work)
    cx, cy, cz = 0.5 * (xx + yx), 0.5 * (xy + yy), 0.5 * (xz + yz)
    return delta, d, ex, ey, ez, cx, cy, cz, s_uu, s_uw, s_ww, True


@numba.njit(inline="always", **JIT_FLAGS)
def pair_geometry(va, a, ra, crown_a, vb, b, rb, crown_b, axis, simplex, work, touching=False):
    """Contact of rounded shapes A and B (cores ``a`` and ``b`` of the vertex arrays va and vb,
    rounding radii ``ra`` and ``rb``, crowns ``crown_*``): ``(delta, d, nx, ny, nz, cx, cy, cz,
    s_uu, s_uw, s_ww)``, delta the crowned overlap and c its contact point
    (``dem.crown.crowned_contact``), s the patch's second moments (``dem.convex.contact_patch``).

    delta <= 0: apart (n and c are then not computed). d = 0 with delta > 0: the cores
    intersect (an overlap beyond the rounding; the caller reports it). ``axis`` (3,) is the
    pair's cached separating direction, from B to A, and ``simplex`` (``dem.convex.SIMPLEX``
    ints) its last GJK simplex, GJK's warm start; both updated here.

    ``touching``: the pair touched at the last step (a hint: whether the pair touches, and its
    contact if it does, do not depend on it; a pair apart may be told so by its crowns' floor
    where it did not touch, and its margin is then a lower bound of the crowned one).
    The cached axis is then taken after GJK instead of before, and only where GJK leaves the
    cores apart or within the axis test's rounding of it (``AXIS_BAND``, far above it): cores
    closer than the reach are no further apart along any axis, so that test would have passed,
    and where it would not have, the axis and simplex GJK changed are put back and the test's
    answer is returned, as before. The same results and state to the bit, without the test's two
    passes over the cores for a resting contact.
    """
    reach = ra + rb
    if axis[0] != 0.0 or axis[1] != 0.0 or axis[2] != 0.0:
        ux, uy, uz = axis[0], axis[1], axis[2]
        kept = (simplex[0], simplex[1], simplex[2], simplex[3], simplex[4], simplex[5], simplex[6])
        near = (-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        if touching:
            near = _near_pair_geometry(va, a, ra, crown_a, vb, b, rb, crown_b, axis, simplex, work, True)
            # the axis test's rounding: a few 1e-16 of the coordinates
            scale = (
                abs(a.pos[0]) + abs(a.pos[1]) + abs(a.pos[2]) + abs(b.pos[0]) + abs(b.pos[1]) + abs(b.pos[2])
            )
            if 0.0 < near[1] <= reach - AXIS_BAND * (reach + scale):
                return near
        # A's lowest and B's highest point along the axis: one support query each.
        lx, ly, lz = support(va, a, -ux, -uy, -uz)
        hx, hy, hz = support(vb, b, ux, uy, uz)
        gap = (lx * ux + ly * uy + lz * uz) - (hx * ux + hy * uy + hz * uz)
        if gap > reach:
            if touching:
                axis[0], axis[1], axis[2] = ux, uy, uz
                for k in range(SIMPLEX):
                    simplex[k] = kept[k]
            return reach - gap, gap, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if touching:
            return near
    return _near_pair_geometry(va, a, ra, crown_a, vb, b, rb, crown_b, axis, simplex, work, touching)


@numba.njit(**STEP_FLAGS)
def _near_pair_geometry(va, a, ra, crown_a, vb, b, rb, crown_b, axis, simplex, work, touching):
    """``pair_geometry`` past the cached axis, which is inlined in its callers: most listed pairs
    end at that test, and each array passed to a compiled call costs an atomic reference count
    up and down. ``touching``: as ``pair_geometry``'s; a pair that did not touch is first tried
    against its crowns' floor."""
    reach = ra + rb
    s, lam = gjk_scratch(work)
    d, ax, ay, az, bx, by, bz = gjk_query(va, a, vb, b, simplex, s, lam)
    if d > 0.0:
        axis[0], axis[1], axis[2] = (ax - bx) / d, (ay - by) / d, (az - bz) / d
    delta = reach - d
    if delta <= 0.0 or d == 0.0:
        return delta, d, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    tol = 4.0 * (crown_a[2] + crown_b[2])
    p_a, p_b = (ax, ay, az), (bx, by, bz)
    if not touching:
        # A pair that did not touch at the last step may be held apart by its crowns alone (a
        # shaken pile's edges and corners): their floor (``dem.crown.crown_floor``) then says so
        # without the crowned contact, and minus the margin returned is a lower bound of the
        # crowned one (``dem.kept_contact`` keeps either). A pair that touched mostly still does.
        nx, ny, nz = ax - bx, ay - by, az - bz
        dn = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / dn, ny / dn, nz / dn
        floor = (
            dn
            + crown_floor(va, a, crown_a, p_a, nx, ny, nz, tol)
            + crown_floor(vb, b, crown_b, p_b, -nx, -ny, -nz, tol)
        )
        if floor - reach > CROWN_FLOOR_BAND * reach:
            return reach - floor, d, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    crowned, xx, xy, xz, yx, yy, yz, ex, ey, ez = crowned_contact(
        va, a, crown_a, vb, b, crown_b, p_a, p_b, tol, work
    )
    delta = reach - crowned
    if delta <= 0.0:
        return delta, d, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    s_uu, s_uw, s_ww = patch_moments(va, a, vb, b, p_a, p_b, delta, tol, work)
    cx, cy, cz = 0.5 * (xx + yx), 0.5 * (xy + yy), 0.5 * (xz + yz)
    return delta, d, ex, ey, ez, cx, cy, cz, s_uu, s_uw, s_ww


@numba.njit(**STEP_FLAGS)
def facet_geometry(va, a, ra, crown_a, tri, facet, work, axis=None):
    """Contact of rounded shape A (core ``a`` of the vertex array va, rounding radius ``ra``,
    crown ``crown_a``) with a ``WallFacet`` of the triangle array ``tri``: ``(delta, d, nx, ny,
    nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face)``, delta the crowned overlap (the least crowned
    distance over the triangles, ``dem.crown``) and c its contact point. ``is_face``: the closest
    point of the facet is inside it (not on its boundary). When apart (delta <= 0), d may be a
    lower bound of the distance rather than the distance, and -delta is then ra less that bound
    (a lower bound of the margin, which ``dem.kept_contact`` keeps).

    ``axis`` (3,), optional: where the triangles are taken one by one and the core's distance is
    found, the unit direction of its closest points from the facet to the core is written there
    (the caller's cached separating direction, ``dem.forces``); otherwise it is left as it is.

    Compiled without numba's runtime, as the callers: the usual cases (apart, or a piece over the
    inside of the facet) borrow their arrays without a reference count; the triangles one by one
    (``_facet_triangles``) allocate their tables.
    """
    disp, normal, offset = facet.disp, facet.normal, facet.offset
    shift = normal[0] * disp[0] + normal[1] * disp[1] + normal[2] * disp[2]
    lo, hi, lowest = _extent(va, a, normal[0], normal[1], normal[2])
    gap = max(lo - (offset + shift), (offset + shift) - hi)  # from the plane: a lower bound
    if gap > ra:
        return ra - gap, gap, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    tol = 4.0 * crown_a[2]
    if lo > offset + shift:
        # The features that can touch (at most ra + tol above the lowest vertex) over the inside
        # of the facet: the facet is a plane for them.
        box, m = _footprint(va, a, facet, ra + tol - (lo - offset - shift), work[6])
        if _inside_facet(tri, facet, box, work[6], m):
            return _plane_geometry(va, a, ra, crown_a, facet, box, lowest, work)
    return _facet_triangles(va, a, ra, crown_a, tri, facet, tol, work, axis)


@numba.njit(**JIT_FLAGS)
def _facet_triangles(va, a, ra, crown_a, tri, facet, tol, work, axis):
    """``facet_geometry`` over the facet's triangles one by one (the piece is not over its inside
    or reaches below its plane); the closest points' direction to ``axis`` unless it is None."""
    disp, normal, offset = facet.disp, facet.normal, facet.offset
    t_start, t_count = facet.start, facet.count
    # Each triangle's distance and closest points, computed once for the three passes below. A
    # triangle farther than ra + tol from the ball about the body's centre that holds the core
    # cannot hold the contact (its crowned distance is at least its distance): no GJK for it.
    core_reach2 = 0.0
    for v in range(a.start, a.start + a.count):
        core_reach2 = max(core_reach2, va[v, 0] ** 2 + va[v, 1] ** 2 + va[v, 2] ** 2)
    core_reach = math.sqrt(core_reach2)
    px, py, pz = a.pos[0] - disp[0], a.pos[1] - disp[1], a.pos[2] - disp[2]
    gjk = np.empty((t_count, 7))
    s, lam = gjk_scratch(work)
    best = np.inf
    bound = np.inf  # the least distance of a triangle passed over (a lower bound)
    ax = ay = az = bx = by = bz = 0.0
    for k in range(t_count):
        t = t_start + k
        qx, qy, qz = closest_point_on_triangle(px, py, pz, tri[3 * t : 3 * t + 3])
        apart = math.sqrt((px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2) - core_reach
        if apart > ra + tol:
            gjk[k, 0] = np.inf
            bound = min(bound, apart)
            continue
        d, qx, qy, qz, wx, wy, wz = gjk_query(va, a, tri, _triangle(facet, t), None, s, lam)
        gjk[k, 0], gjk[k, 1], gjk[k, 2], gjk[k, 3] = d, qx, qy, qz
        gjk[k, 4], gjk[k, 5], gjk[k, 6] = wx, wy, wz
        if d < best:
            best, ax, ay, az, bx, by, bz = d, qx, qy, qz, wx, wy, wz
    if axis is not None and 0.0 < best < np.inf:
        axis[0], axis[1], axis[2] = (ax - bx) / best, (ay - by) / best, (az - bz) / best
    if best > bound:  # apart (the distance is at least the bound)
        return ra - bound, bound, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    delta = ra - best
    if delta <= 0.0 or best == 0.0:
        return delta, best, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    plane = (ax - disp[0]) * normal[0] + (ay - disp[1]) * normal[1] + (az - disp[2]) * normal[2] - offset
    is_face = plane * plane >= best * best * (1.0 - 1e-10)
    # The crowned distance of the facet is the least over its triangles (each with its own
    # closest points; coplanar triangles agree where they meet).
    crowned = np.inf
    nx = ny = nz = cx = cy = cz = 0.0
    for k in range(t_count):
        d = gjk[k, 0]
        if d > best + tol or d == 0.0:
            continue
        value, xx, xy, xz, yx, yy, yz, ex, ey, ez = crowned_contact(
            va,
            a,
            crown_a,
            tri,
            _triangle(facet, t_start + k),
            NO_CROWN,
            (gjk[k, 1], gjk[k, 2], gjk[k, 3]),
            (gjk[k, 4], gjk[k, 5], gjk[k, 6]),
            tol,
            work,
        )
        if value < crowned:
            crowned = value
            nx, ny, nz = ex, ey, ez
            cx, cy, cz = 0.5 * (xx + yx), 0.5 * (xy + yy), 0.5 * (xz + yz)
    delta = ra - crowned
    if delta <= 0.0:
        return delta, best, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    if t_count == 1:
        _, _, _, _, _, s_uu, s_uw, s_ww = contact_patch(
            va, a, tri, _triangle(facet, t_start), (ax, ay, az), (bx, by, bz), delta, work
        )
        return delta, best, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face
    # Several triangles: combine the patches of those the rounded surface overlaps (within delta
    # of the closest), by their loads: area loads if any, else line loads, else equally.
    ux, uy, uz, vx, vy, vz = plane_basis((ax - bx) / best, (ay - by) / best, (az - bz) / best)
    sums = np.zeros((3, 7))  # per kind of load: weight, c (3), weight * (c_u^2, c_u c_w, c_w^2) + s
    for k in range(t_count):
        if gjk[k, 0] > best + delta:
            continue
        t = t_start + k
        # The facet's triangles are coplanar: every patch is taken along the facet's contact
        # normal (a triangle's own closest points may lie on its edge, with a tilted normal).
        area, length, px, py, pz, s_uu, s_uw, s_ww = contact_patch(
            va, a, tri, _triangle(facet, t), (ax, ay, az), (bx, by, bz), delta, work
        )
        kind, weight = (0, area) if area > 0.0 else ((1, length) if length > 0.0 else (2, 1.0))
        cu = px * ux + py * uy + pz * uz
        cw = px * vx + py * vy + pz * vz
        row = sums[kind]
        row[0] += weight
        row[1] += weight * px
        row[2] += weight * py
        row[3] += weight * pz
        row[4] += weight * (s_uu + cu * cu)
        row[5] += weight * (s_uw + cu * cw)
        row[6] += weight * (s_ww + cw * cw)
    kind = 0 if sums[0, 0] > 0.0 else (1 if sums[1, 0] > 0.0 else 2)
    row = sums[kind]
    total = row[0]
    cu = (row[1] * ux + row[2] * uy + row[3] * uz) / total
    cw = (row[1] * vx + row[2] * vy + row[3] * vz) / total
    # parallel axes: moments about the combined centre
    s_uu = row[4] / total - cu * cu
    s_uw = row[5] / total - cu * cw
    s_ww = row[6] / total - cw * cw
    return delta, best, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face
