r"""Closest features of two convex point sets (GJK) and the centre of their contact patch.

A convex shape here is the convex hull of a few vertices placed by a rotation and a translation:
a rounded polyhedron's core (``dem/polyhedra.py``), a sphere's centre (one vertex) or a wall
triangle. The contact of two rounded shapes (cores A and B, rounding radii r_a and r_b) is that
of their cores:

* ``gjk_distance`` gives the distance d of the cores and the closest points p_a, p_b (Gilbert,
  Johnson & Keerthi 1988, with Ericson's closest-point-on-simplex regions, Real-Time Collision
  Detection 9.5); the overlap is ``delta = r_a + r_b - d`` and the normal ``n = (p_a - p_b) / d``
  points from B to A. The force of the contact law acts along n with the magnitude of *one*
  contact of the body pair, so a face's stiffness does not depend on how many vertices it has.
  Along a configuration path ``d`` changes at the rate ``n . (v_a(p) - v_b(p))`` (envelope
  theorem), so that force applied at a point on the line through the closest points does the
  work ``-dU`` of ``U = K delta^2 / 2``: the law is conservative.
* Where the closest points are not unique (two faces parallel, an edge parallel to a face, two
  parallel edges) they jump between corners as a face rocks, which is not smooth: the contact
  is then taken between crowned cores (``dem/crown.py``), whose unique contact point moves
  continuously across the face. ``contact_patch`` gives the patch where the rounded surfaces
  overlap (depth varying linearly over it): its second moments spread the dampers over a face
  (``dem.contact.patch_damping``) and its loads weigh the triangles of a facet.

A shape travels as its vertex array and a ``Core`` (which rows, and their placement as plain
numbers: a tuple holding arrays costs numba reference counting on every call, which measured 20 %
of a GJK query), points and directions as 3-tuples. Pure numba functions; the scratch array
``work`` (8, MAX_FEATURE, 3) keeps them free of allocation (work[6] is a caller's: the plane's
triangle of ``dem.rounded_contact``; work[7] holds GJK's simplex, ``gjk_scratch``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from dem.conf import JIT_FLAGS, STEP_FLAGS

MAX_FEATURE = 128  # most vertices of a core (the scratch holds every one's projection)
SIMPLEX = 7  # a pair's cached GJK simplex: its size, then the vertex rows (of a, of b) of each point
_MAX_ITERATIONS = 64
_REL_EPS = 1e-12
_COLUMNS = 11  # a simplex row: w, a, b (3 each), the vertex rows of a and b


class Core(NamedTuple):
    """A convex shape placed in the world: the hull of rows ``start .. start + count`` of a vertex
    array (body frame, passed beside it) turned by ``rot`` and moved to ``pos``."""

    start: int
    count: int
    rot: tuple  # the rotation matrix's rows, three 3-tuples
    pos: tuple  # (x, y, z)


@numba.njit(**JIT_FLAGS)
def place(start, count, rot, pos):
    """The ``Core`` of rows ``start .. start + count`` placed by the arrays rot (3x3) and pos (3,);
    the row numbers as int64, so that cores from 32-bit lists and 64-bit tables have one type."""
    return Core(
        np.int64(start),
        np.int64(count),
        (
            (rot[0, 0], rot[0, 1], rot[0, 2]),
            (rot[1, 0], rot[1, 1], rot[1, 2]),
            (rot[2, 0], rot[2, 1], rot[2, 2]),
        ),
        (pos[0], pos[1], pos[2]),
    )


@numba.njit(inline="always", **JIT_FLAGS)
def place_body(start, count, rot, pos, b):
    """``place`` for body b of the bodies' rotation (n, 3, 3) and position (n, 3) tables, read in
    place: the row views ``rot[b]`` and ``pos[b]`` would each cost an atomic reference count."""
    return Core(
        np.int64(start),
        np.int64(count),
        (
            (rot[b, 0, 0], rot[b, 0, 1], rot[b, 0, 2]),
            (rot[b, 1, 0], rot[b, 1, 1], rot[b, 1, 2]),
            (rot[b, 2, 0], rot[b, 2, 1], rot[b, 2, 2]),
        ),
        (pos[b, 0], pos[b, 1], pos[b, 2]),
    )


@numba.njit(inline="always", **JIT_FLAGS)
def at_point(row):
    """The one-vertex ``Core`` of a point given in world coordinates (row ``row`` of its array):
    a sphere's centre."""
    return Core(
        np.int64(row), np.int64(1), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), (0.0, 0.0, 0.0)
    )


def scratch() -> np.ndarray:
    """The work array ``contact_patch`` and ``gjk_query`` need."""
    return np.zeros((8, MAX_FEATURE, 3))


# work[7]'s last row, past GJK's 10 * _COLUMNS + 12 floats (``gjk_scratch``): the crown's two
# highest heights, which ``feature_hulls`` leaves for ``patch_moments``
TOPS_ROW = MAX_FEATURE - 1


@numba.njit(inline="always", **JIT_FLAGS)
def gjk_scratch(work):
    """GJK's simplex rows (10, ``_COLUMNS``) and weights (12,) as views of work[7] (a
    ``scratch``), for ``gjk_query``: the two arrays ``gjk_distance`` allocates per query."""
    flat = work[7].reshape(work.shape[1] * 3)
    return flat[: 10 * _COLUMNS].reshape((10, _COLUMNS)), flat[10 * _COLUMNS : 10 * _COLUMNS + 12]


@numba.njit(inline="always", **JIT_FLAGS)
def support_row(verts, core, dx, dy, dz):
    """Row of ``verts`` of the vertex of ``core`` furthest along d (the first of equals)."""
    start, count, rot, _ = core
    r0, r1, r2 = rot
    bx = r0[0] * dx + r1[0] * dy + r2[0] * dz
    by = r0[1] * dx + r1[1] * dy + r2[1] * dz
    bz = r0[2] * dx + r1[2] * dy + r2[2] * dz
    best = -np.inf
    k = start
    for v in range(start, start + count):
        s = verts[v, 0] * bx + verts[v, 1] * by + verts[v, 2] * bz
        if s > best:
            best = s
            k = v
    return k


@numba.njit(inline="always", **JIT_FLAGS)
def placed(verts, core, k):
    """World position of row k of ``verts``, a vertex of ``core``."""
    _, _, rot, pos = core
    r0, r1, r2 = rot
    x, y, z = verts[k, 0], verts[k, 1], verts[k, 2]
    return (
        pos[0] + r0[0] * x + r0[1] * y + r0[2] * z,
        pos[1] + r1[0] * x + r1[1] * y + r1[2] * z,
        pos[2] + r2[0] * x + r2[1] * y + r2[2] * z,
    )


@numba.njit(inline="always", **JIT_FLAGS)
def support(verts, core, dx, dy, dz):
    """World position of the vertex of ``core`` (rows of ``verts``) furthest along d."""
    return placed(verts, core, support_row(verts, core, dx, dy, dz))


@numba.njit(inline="always", **JIT_FLAGS)
def _keep(simplex, lam, idx0, idx1, idx2, k):
    """Reduce the simplex (rows: w, a, b stacked in columns 0:3, 3:6, 6:9, and the vertex rows of
    a and b in columns 9 and 10) to rows idx*, which increase (row r comes from a row >= r):
    copied in place, in order, without a heap array."""
    sel = (idx0, idx1, idx2)
    for r in range(k):
        src = sel[r]
        if src != r:
            for c in range(_COLUMNS):
                simplex[r, c] = simplex[src, c]
    return k


@numba.njit(inline="always", **JIT_FLAGS)
def _closest_segment(s, lam):
    """Closest point to the origin of segment rows 0-1; reduces the simplex; returns its size."""
    ex, ey, ez = s[1, 0] - s[0, 0], s[1, 1] - s[0, 1], s[1, 2] - s[0, 2]
    ee = ex * ex + ey * ey + ez * ez
    t = -(s[0, 0] * ex + s[0, 1] * ey + s[0, 2] * ez) / ee if ee > 0.0 else 0.0
    if t <= 0.0:
        lam[0] = 1.0
        return 1
    if t >= 1.0:
        _keep(s, lam, 1, 0, 0, 1)
        lam[0] = 1.0
        return 1
    lam[0] = 1.0 - t
    lam[1] = t
    return 2


@numba.njit(**STEP_FLAGS)
def _closest_triangle(s, lam):
    """Closest point to the origin of triangle rows 0-2 (Ericson 5.1.5 regions)."""
    abx, aby, abz = s[1, 0] - s[0, 0], s[1, 1] - s[0, 1], s[1, 2] - s[0, 2]
    acx, acy, acz = s[2, 0] - s[0, 0], s[2, 1] - s[0, 1], s[2, 2] - s[0, 2]
    d1 = -(abx * s[0, 0] + aby * s[0, 1] + abz * s[0, 2])
    d2 = -(acx * s[0, 0] + acy * s[0, 1] + acz * s[0, 2])
    if d1 <= 0.0 and d2 <= 0.0:
        lam[0] = 1.0
        return 1
    d3 = -(abx * s[1, 0] + aby * s[1, 1] + abz * s[1, 2])
    d4 = -(acx * s[1, 0] + acy * s[1, 1] + acz * s[1, 2])
    if d3 >= 0.0 and d4 <= d3:
        _keep(s, lam, 1, 0, 0, 1)
        lam[0] = 1.0
        return 1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        lam[0], lam[1] = 1.0 - t, t
        return 2
    d5 = -(abx * s[2, 0] + aby * s[2, 1] + abz * s[2, 2])
    d6 = -(acx * s[2, 0] + acy * s[2, 1] + acz * s[2, 2])
    if d6 >= 0.0 and d5 <= d6:
        _keep(s, lam, 2, 0, 0, 1)
        lam[0] = 1.0
        return 1
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        _keep(s, lam, 0, 2, 0, 2)
        lam[0], lam[1] = 1.0 - t, t
        return 2
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        _keep(s, lam, 1, 2, 0, 2)
        lam[0], lam[1] = 1.0 - t, t
        return 2
    total = va + vb + vc
    if not total > 0.0:  # degenerate (collinear) triangle: keep its best edge
        _keep(s, lam, 0, 1, 0, 2)
        return _closest_segment(s, lam)
    v = vb / total
    w = vc / total
    lam[0], lam[1], lam[2] = 1.0 - v - w, v, w
    return 3


@numba.njit(**STEP_FLAGS)
def _closest_tetrahedron(s, lam):
    """Closest point to the origin of tetrahedron rows 0-3; 4 (and lam unset) if it holds the origin.
    Scratch in the caller's arrays (no allocation per call): s rows 4-6 the best face, 7-9 the
    face at hand; lam 4-7 and 8-11 their weights."""
    faces = ((0, 1, 2, 3), (0, 1, 3, 2), (0, 2, 3, 1), (1, 2, 3, 0))
    best = np.inf
    best_face = -1
    best_k = 0
    tri = s[7:10]
    tlam = lam[4:8]
    blam = lam[8:12]
    for f in range(4):
        a, b, c, o = faces[f]
        abx, aby, abz = s[b, 0] - s[a, 0], s[b, 1] - s[a, 1], s[b, 2] - s[a, 2]
        acx, acy, acz = s[c, 0] - s[a, 0], s[c, 1] - s[a, 1], s[c, 2] - s[a, 2]
        nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
        side_origin = -(nx * s[a, 0] + ny * s[a, 1] + nz * s[a, 2])
        side_other = nx * (s[o, 0] - s[a, 0]) + ny * (s[o, 1] - s[a, 1]) + nz * (s[o, 2] - s[a, 2])
        if side_origin * side_other >= 0.0:
            continue  # the origin is on the inner side of this face
        for r, idx in enumerate((a, b, c)):
            for col in range(_COLUMNS):
                tri[r, col] = s[idx, col]
        tlam[:] = 0.0
        k = _closest_triangle(tri, tlam)
        px = py = pz = 0.0
        for r in range(k):
            px += tlam[r] * tri[r, 0]
            py += tlam[r] * tri[r, 1]
            pz += tlam[r] * tri[r, 2]
        d2 = px * px + py * py + pz * pz
        if d2 < best:
            best = d2
            best_face = f
            best_k = k
            for r in range(k):
                blam[r] = tlam[r]
            for r in range(3):
                for col in range(_COLUMNS):
                    s[4 + r, col] = tri[r, col]
    if best_face < 0:
        return 4
    for r in range(best_k):
        for col in range(_COLUMNS):
            s[r, col] = s[4 + r, col]
        lam[r] = blam[r]
    return best_k


@numba.njit(**STEP_FLAGS)
def _flat(s):
    """Whether simplex rows 0-3 span (almost) no volume."""
    ax, ay, az = s[1, 0] - s[0, 0], s[1, 1] - s[0, 1], s[1, 2] - s[0, 2]
    bx, by, bz = s[2, 0] - s[0, 0], s[2, 1] - s[0, 1], s[2, 2] - s[0, 2]
    cx, cy, cz = s[3, 0] - s[0, 0], s[3, 1] - s[0, 1], s[3, 2] - s[0, 2]
    volume = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    scale = max(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz, cx * cx + cy * cy + cz * cz)
    return abs(volume) <= 1e-12 * scale**1.5


@numba.njit(inline="always", **JIT_FLAGS)
def _put(s, r, va, a, ka, vb, b, kb):
    """Simplex row r: the support point of vertex row ka of a and kb of b."""
    ax, ay, az = placed(va, a, ka)
    bx, by, bz = placed(vb, b, kb)
    s[r, 0], s[r, 1], s[r, 2] = ax - bx, ay - by, az - bz
    s[r, 3], s[r, 4], s[r, 5] = ax, ay, az
    s[r, 6], s[r, 7], s[r, 8] = bx, by, bz
    s[r, 9], s[r, 10] = ka, kb


@numba.njit(**STEP_FLAGS)
def _warm_start(va, a, vb, b, simplex, s, lam):
    """The cached simplex (``SIMPLEX`` ints) as the starting simplex in s, reduced to its point
    closest to the origin (weights in lam); returns its size, 0 if the cache holds none or rows
    that are not vertices of these cores (a list rebuild reorders the pairs)."""
    k = simplex[0]
    if k < 1 or k > 3:
        return 0
    for r in range(k):
        ka, kb = simplex[1 + 2 * r], simplex[2 + 2 * r]
        if not (a.start <= ka < a.start + a.count and b.start <= kb < b.start + b.count):
            return 0
    for r in range(k):
        _put(s, r, va, a, simplex[1 + 2 * r], vb, b, simplex[2 + 2 * r])
    if k == 1:
        lam[0] = 1.0
        return 1
    if k == 2:
        return _closest_segment(s, lam)
    return _closest_triangle(s, lam)


@numba.njit(**JIT_FLAGS)
def gjk_distance(va, a, vb, b, simplex=None):
    """Distance of the convex shapes ``a`` and ``b`` (``Core``s of the vertex arrays va, vb) and
    their closest points.

    Returns ``(d, ax, ay, az, bx, by, bz)``; d = 0 when the hulls intersect (closest points are
    then meaningless). ``simplex`` (``SIMPLEX`` ints, optional): the final simplex of the last
    query of this pair, to start from (warm start: in contact, the closest features rarely
    change between steps, and one iteration confirms them instead of about eight); updated.
    Without it GJK starts from the support points along the line of the centres.
    """
    s = np.zeros((10, _COLUMNS))  # rows 0-3 the simplex, 4-9 scratch for the tetrahedron case
    lam = np.zeros(12)  # 0-3 the simplex's weights, 4-11 scratch for the tetrahedron case
    return gjk_query(va, a, vb, b, simplex, s, lam)


@numba.njit(**STEP_FLAGS)
def gjk_query(va, a, vb, b, simplex, s, lam):
    """``gjk_distance`` in the caller's scratch: s (10, ``_COLUMNS``) and lam (12,), as
    ``gjk_scratch`` gives them (every row and weight it reads it writes first), so that the step
    allocates nothing for a query."""
    pa, pb = a.pos, b.pos
    lam[:] = 0.0
    k = 0
    if simplex is not None:
        k = _warm_start(va, a, vb, b, simplex, s, lam)
    if k == 0:
        dx, dy, dz = pa[0] - pb[0], pa[1] - pb[1], pa[2] - pb[2]
        if dx == 0.0 and dy == 0.0 and dz == 0.0:
            dx = 1.0
        _put(s, 0, va, a, support_row(va, a, -dx, -dy, -dz), vb, b, support_row(vb, b, dx, dy, dz))
        lam[0] = 1.0
        k = 1
        vx, vy, vz = s[0, 0], s[0, 1], s[0, 2]
    else:
        vx = vy = vz = 0.0
        for r in range(k):
            vx += lam[r] * s[r, 0]
            vy += lam[r] * s[r, 1]
            vz += lam[r] * s[r, 2]
    for _ in range(_MAX_ITERATIONS):
        vv = vx * vx + vy * vy + vz * vz
        if vv == 0.0:
            if simplex is not None:
                simplex[0] = 0  # intersecting: the next query starts afresh
            return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        ka, kb = support_row(va, a, -vx, -vy, -vz), support_row(vb, b, vx, vy, vz)
        ax, ay, az = placed(va, a, ka)
        bx, by, bz = placed(vb, b, kb)
        wx, wy, wz = ax - bx, ay - by, az - bz
        if vv - (vx * wx + vy * wy + vz * wz) <= _REL_EPS * vv:
            break
        duplicate = False
        for r in range(k):
            if s[r, 0] == wx and s[r, 1] == wy and s[r, 2] == wz:
                duplicate = True
        if duplicate:
            break
        s[k, 0], s[k, 1], s[k, 2] = wx, wy, wz
        s[k, 3], s[k, 4], s[k, 5] = ax, ay, az
        s[k, 6], s[k, 7], s[k, 8] = bx, by, bz
        s[k, 9], s[k, 10] = ka, kb
        k += 1
        if k == 4 and _flat(s):
            k = 3  # w lies in the triangle's plane: no progress is possible
            break
        lam[:] = 0.0
        if k == 2:
            k = _closest_segment(s, lam)
        elif k == 3:
            k = _closest_triangle(s, lam)
        else:
            k = _closest_tetrahedron(s, lam)
            if k == 4:
                if simplex is not None:
                    simplex[0] = 0
                return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        nvx = nvy = nvz = 0.0
        for r in range(k):
            nvx += lam[r] * s[r, 0]
            nvy += lam[r] * s[r, 1]
            nvz += lam[r] * s[r, 2]
        if nvx * nvx + nvy * nvy + nvz * nvz >= vv:
            break  # no progress: rounding; v is as good as it gets
        vx, vy, vz = nvx, nvy, nvz
    ax = ay = az = bx = by = bz = 0.0
    for r in range(k):
        ax += lam[r] * s[r, 3]
        ay += lam[r] * s[r, 4]
        az += lam[r] * s[r, 5]
        bx += lam[r] * s[r, 6]
        by += lam[r] * s[r, 7]
        bz += lam[r] * s[r, 8]
    if simplex is not None:
        simplex[0] = k
        for r in range(k):
            simplex[1 + 2 * r], simplex[2 + 2 * r] = int(s[r, 9]), int(s[r, 10])
    d = math.sqrt((ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2)
    return d, ax, ay, az, bx, by, bz


@numba.njit(inline="always", **JIT_FLAGS)
def _world(verts, core, k):
    """Vertex k of a shape, placed (as ``placed``, written out the way the projections take it)."""
    start, _, rot, p = core
    r0, r1, r2 = rot
    v = start + k
    x = p[0] + r0[0] * verts[v, 0] + r0[1] * verts[v, 1] + r0[2] * verts[v, 2]
    y = p[1] + r1[0] * verts[v, 0] + r1[1] * verts[v, 1] + r1[2] * verts[v, 2]
    z = p[2] + r2[0] * verts[v, 0] + r2[1] * verts[v, 1] + r2[2] * verts[v, 2]
    return x, y, z


@numba.njit(inline="always", **JIT_FLAGS)
def _heights(verts, core, n, sign, tol, out):
    """Every vertex's height along sign*n into out[:, 2] where it can be within tol of the
    highest, -inf where it cannot. Each is first taken in the body frame (n turned into it: three
    products a vertex instead of the placed vertex's twelve), which differs from the placed
    vertex's height only by rounding, far below ``margin``: a vertex lower than the highest by more
    than tol and the rounding of both needs no more (two thirds of a phone's 48 vertices).
    Returns the highest placed height; the body-frame heights stay in out[:, 1]."""
    start, count, rot, p = core
    r0, r1, r2 = rot
    nx, ny, nz = n
    bx = sign * (r0[0] * nx + r1[0] * ny + r2[0] * nz)
    by = sign * (r0[1] * nx + r1[1] * ny + r2[1] * nz)
    bz = sign * (r0[2] * nx + r1[2] * ny + r2[2] * nz)
    top = -np.inf
    reach = 0.0
    for k in range(count):
        v = start + k
        h = verts[v, 0] * bx + verts[v, 1] * by + verts[v, 2] * bz
        out[k, 1] = h
        top = max(top, h)
        reach = max(reach, abs(verts[v, 0]) + abs(verts[v, 1]) + abs(verts[v, 2]))
    margin = 1e-12 * (1.0 + abs(p[0]) + abs(p[1]) + abs(p[2]) + reach)
    floor = top - tol - 3.0 * margin
    best = -np.inf
    for k in range(count):
        if out[k, 1] >= floor:
            x, y, z = _world(verts, core, k)
            h = sign * (x * nx + y * ny + z * nz)
            out[k, 2] = h
            best = max(best, h)
        else:
            out[k, 2] = -np.inf
    return best


@numba.njit(inline="always", **JIT_FLAGS)
def _feature(verts, core, u, w, heights, best, tol, out):
    """The vertices within tol of their supporting plane (by their ``_heights``), projected on u
    and w, their column 2 ``tol - height above the plane``; returns how many (at most
    MAX_FEATURE). Only these are projected: about a third of a phone's vertices in a crowned
    contact, a tenth in its patch. best: the highest of the heights (``_heights`` returns it).
    Each one's (u, w) also goes to heights[k, :2], for ``_feature_again``."""
    ux, uy, uz = u
    wx, wy, wz = w
    m = 0
    for k in range(core.count):
        depth = tol - (best - heights[k, 2])
        if depth >= 0.0 and m < out.shape[0]:
            x, y, z = _world(verts, core, k)
            pu = x * ux + y * uy + z * uz
            pw = x * wx + y * wy + z * wz
            out[m, 0], out[m, 1], out[m, 2] = pu, pw, depth
            heights[k, 0], heights[k, 1] = pu, pw
            m += 1
    return m


@numba.njit(inline="always", **JIT_FLAGS)
def _feature_again(count, heights, best, tol, out):
    """``_feature`` for a tolerance at most that of the last ``_feature`` on these heights, in the
    same plane basis: its vertices are among those, whose (u, w) it left in heights[k, :2] (the
    same figures: the same vertices placed and projected by the same expressions), so none is
    placed again."""
    m = 0
    for k in range(count):
        depth = tol - (best - heights[k, 2])
        if depth >= 0.0 and m < out.shape[0]:
            out[m, 0], out[m, 1], out[m, 2] = heights[k, 0], heights[k, 1], depth
            m += 1
    return m


@numba.njit(inline="always", **JIT_FLAGS)
def _cross2(o, a, b):
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


@numba.njit(inline="always", **JIT_FLAGS)
def _copy_row(dst, i, src, j):
    dst[i, 0], dst[i, 1], dst[i, 2] = src[j, 0], src[j, 1], src[j, 2]


@numba.njit(inline="always", **JIT_FLAGS)
def _outline(pts, m, out, eps):
    """``_hull2``'s hull of pts[:m], to the bit, if they are in their order the corners of a convex
    polygon going once round one way, every three consecutive corners' cross product beyond eps^2
    by a margin (1e-12 of the points' largest |x| + |y|, squared) far above the cross products'
    rounding (about 1e-16 of it): then any three of the points turn the same way by at least as
    much (the least triangle on a convex polygon's corners is of three consecutive ones), every
    test of the monotone chain goes the way the geometry says and none merges, so the chain keeps
    them all, counter-clockwise from the least in (x, y); they are copied in that order. Else 0
    (and ``_hull2`` sorts). ``tests/dem/test_polyhedra.py`` checks it against the chain."""
    if m < 3:
        return 0
    lo = 0
    size = abs(pts[0, 0]) + abs(pts[0, 1])
    for a in range(1, m):
        if pts[a, 0] < pts[lo, 0] or (pts[a, 0] == pts[lo, 0] and pts[a, 1] < pts[lo, 1]):
            lo = a
        size = max(size, abs(pts[a, 0]) + abs(pts[a, 1]))
    least = eps * eps + 1e-12 * size * size
    sense = 1.0 if _cross2(pts[m - 1], pts[0], pts[1]) > 0.0 else -1.0
    turns = 0
    last = pts[0, 0] - pts[m - 1, 0]
    for a in range(m):
        b = a + 1 if a + 1 < m else 0
        if sense * _cross2(pts[a - 1 if a > 0 else m - 1], pts[a], pts[b]) <= least:
            return 0
        dx = pts[b, 0] - pts[a, 0]
        if dx != 0.0:
            if last != 0.0 and (dx > 0.0) != (last > 0.0):
                turns += 1
            last = dx
    if turns != 2:  # round more than once (a star), or x never turning back
        return 0
    step = 1 if sense > 0.0 else m - 1
    k = lo
    for a in range(m):
        _copy_row(out, a, pts, k)
        k = (k + step) % m
    return m


@numba.njit(**STEP_FLAGS)
def _hull2(pts, m, out, eps):
    """Counter-clockwise convex hull of pts[:m] (Andrew's monotone chain; column 2 rides along)
    into out; returns its size. Points closer than eps collapse; collinear points are dropped,
    so a segment has 2 points. Points that come as a convex outline (a whole face of a core
    whose rows go round it, ``dem.polyhedra.face_loop_order``) are their hull as they are
    (``_outline``): the same rows in the same order, without the sort."""
    h = _outline(pts, m, out, eps)
    if h > 0:
        return h
    for a in range(1, m):  # insertion sort by (x, y): features are small
        x, y, h = pts[a, 0], pts[a, 1], pts[a, 2]
        b = a - 1
        while b >= 0 and (pts[b, 0] > x or (pts[b, 0] == x and pts[b, 1] > y)):
            _copy_row(pts, b + 1, pts, b)
            b -= 1
        pts[b + 1, 0], pts[b + 1, 1], pts[b + 1, 2] = x, y, h
    h = 0
    for a in range(m):
        while h >= 2 and _cross2(out[h - 2], out[h - 1], pts[a]) <= eps * eps:
            h -= 1
        _copy_row(out, h, pts, a)
        h += 1
    lower = h + 1
    for a in range(m - 2, -1, -1):
        while h >= lower and _cross2(out[h - 2], out[h - 1], pts[a]) <= eps * eps:
            h -= 1
        _copy_row(out, h, pts, a)
        h += 1
    h = max(h - 1, 1)
    if h == 2 and (out[0, 0] - out[1, 0]) ** 2 + (out[0, 1] - out[1, 1]) ** 2 <= eps * eps:
        h = 1
    return h


@numba.njit(**STEP_FLAGS)
def _clip(poly, m, clip, c, out):
    """Sutherland-Hodgman: poly[:m] (convex, ccw, or a segment/point) clipped by the ccw convex
    polygon clip[:c], poly's depth (column 2) interpolated; result in poly (out is scratch);
    returns its size.

    An edge whose inner side holds poly's box, by more than the rounding of the side tests,
    keeps every point and is passed over: an edge of a phone's face lying on the face of another
    has most of that face's 24 edges far from it."""
    xlo, xhi, ylo, yhi = _box(poly, m)
    for e in range(c):
        ex0, ey0 = clip[e, 0], clip[e, 1]
        ex1, ey1 = clip[(e + 1) % c, 0], clip[(e + 1) % c, 1]
        # The least of the side tests below over poly's box: they are linear in (px, py).
        dx, dy = ex1 - ex0, ey1 - ey0
        least = dx * ((ylo if dx >= 0.0 else yhi) - ey0) - dy * ((xhi if dy >= 0.0 else xlo) - ex0)
        scale = abs(ex0) + abs(ey0) + max(abs(xlo), abs(xhi)) + max(abs(ylo), abs(yhi))
        if least > 1e-12 * (abs(dx) + abs(dy)) * (1.0 + scale):
            continue
        n = 0
        if m == 1:
            side = (ex1 - ex0) * (poly[0, 1] - ey0) - (ey1 - ey0) * (poly[0, 0] - ex0)
            if side >= 0.0:
                _copy_row(out, 0, poly, 0)
                n = 1
        else:
            edges = m if m > 2 else 1
            for a in range(edges):
                q = (a + 1) % m
                px, py = poly[a, 0], poly[a, 1]
                qx, qy = poly[q, 0], poly[q, 1]
                sp = (ex1 - ex0) * (py - ey0) - (ey1 - ey0) * (px - ex0)
                sq = (ex1 - ex0) * (qy - ey0) - (ey1 - ey0) * (qx - ex0)
                if sp >= 0.0:
                    _copy_row(out, n, poly, a)
                    n += 1
                if (sp >= 0.0) != (sq >= 0.0):
                    t = sp / (sp - sq)
                    out[n, 0], out[n, 1] = px + t * (qx - px), py + t * (qy - py)
                    out[n, 2] = poly[a, 2] + t * (poly[q, 2] - poly[a, 2])
                    n += 1
                if m == 2 and sq >= 0.0:
                    _copy_row(out, n, poly, q)
                    n += 1
        for a in range(n):
            _copy_row(poly, a, out, a)
        m = n
        if m == 0:
            return 0
        xlo, xhi, ylo, yhi = _box(poly, m)
    return m


@numba.njit(inline="always", **JIT_FLAGS)
def _box(pts, m):
    """(x_min, x_max, y_min, y_max) of pts[:m]."""
    xlo = xhi = pts[0, 0]
    ylo = yhi = pts[0, 1]
    for a in range(1, m):
        xlo, xhi = min(xlo, pts[a, 0]), max(xhi, pts[a, 0])
        ylo, yhi = min(ylo, pts[a, 1]), max(yhi, pts[a, 1])
    return xlo, xhi, ylo, yhi


@numba.njit(**STEP_FLAGS)
def _segment_load(x0, y0, p0, x1, y1, p1):
    """(load, cx, cy) of a segment under a linear line load p (uniform if p vanishes)."""
    length = math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
    if p0 + p1 <= 0.0:
        p0 = p1 = 1.0
    load = 0.5 * length * (p0 + p1)
    k = 1.0 / (3.0 * (p0 + p1))
    return load, (x0 * (2 * p0 + p1) + x1 * (p0 + 2 * p1)) * k, (y0 * (2 * p0 + p1) + y1 * (p0 + 2 * p1)) * k


@numba.njit(**STEP_FLAGS)
def _pressure_centre(poly, m):
    """(area load, line load, cx, cy, suu, suw, sww) of polygon poly[:m] under the pressure that
    varies linearly between its vertices' depths (column 2): the loads and the centre of pressure
    exactly (fan of triangles, Gauss's formula for a linear density), and the patch's second
    moments of area about that centre per unit area (s_uu = <u^2>, ...). A degenerate polygon is a
    segment under a line load; a point has no load and no moments."""
    if m >= 3:
        total = mx = my = 0.0
        plain = pmx = pmy = 0.0
        s_uu = s_uw = s_ww = 0.0
        for a in range(1, m - 1):
            b = a + 1
            area = 0.5 * _cross2(poly[0], poly[a], poly[b])
            if area <= 0.0:
                continue
            ps = poly[0, 2] + poly[a, 2] + poly[b, 2]
            xs = poly[0, 0] + poly[a, 0] + poly[b, 0]
            ys = poly[0, 1] + poly[a, 1] + poly[b, 1]
            px = poly[0, 2] * poly[0, 0] + poly[a, 2] * poly[a, 0] + poly[b, 2] * poly[b, 0]
            py = poly[0, 2] * poly[0, 1] + poly[a, 2] * poly[a, 1] + poly[b, 2] * poly[b, 1]
            total += area * ps / 3.0
            mx += area / 12.0 * (ps * xs + px)
            my += area / 12.0 * (ps * ys + py)
            plain += area
            pmx += area * xs / 3.0
            pmy += area * ys / 3.0
            # int x x^T dA over the triangle: A/12 (sum_k x_k x_k^T + xs xs^T)
            qxx = poly[0, 0] ** 2 + poly[a, 0] ** 2 + poly[b, 0] ** 2
            qyy = poly[0, 1] ** 2 + poly[a, 1] ** 2 + poly[b, 1] ** 2
            qxy = poly[0, 0] * poly[0, 1] + poly[a, 0] * poly[a, 1] + poly[b, 0] * poly[b, 1]
            s_uu += area / 12.0 * (qxx + xs * xs)
            s_ww += area / 12.0 * (qyy + ys * ys)
            s_uw += area / 12.0 * (qxy + xs * ys)
        if plain > 0.0:
            if total > 0.0:
                cx, cy = mx / total, my / total
            else:  # no depth anywhere: the area centroid
                cx, cy, total = pmx / plain, pmy / plain, plain
            s_uu = s_uu / plain - 2.0 * cx * pmx / plain + cx * cx
            s_ww = s_ww / plain - 2.0 * cy * pmy / plain + cy * cy
            s_uw = s_uw / plain - cx * pmy / plain - cy * pmx / plain + cx * cy
            return total, 0.0, cx, cy, s_uu, s_uw, s_ww
    if m == 1:
        return 0.0, 0.0, poly[0, 0], poly[0, 1], 0.0, 0.0, 0.0
    lo = hi = 0
    for a in range(1, m):
        if poly[a, 0] < poly[lo, 0] or (poly[a, 0] == poly[lo, 0] and poly[a, 1] < poly[lo, 1]):
            lo = a
        if poly[a, 0] > poly[hi, 0] or (poly[a, 0] == poly[hi, 0] and poly[a, 1] > poly[hi, 1]):
            hi = a
    x0, y0, x1, y1 = poly[lo, 0], poly[lo, 1], poly[hi, 0], poly[hi, 1]
    load, cx, cy = _segment_load(x0, y0, poly[lo, 2], x1, y1, poly[hi, 2])
    # <(x - c)(x - c)^T> along the segment (uniform): from <x x^T> = (x0 x0 + x0 x1 + x1 x1) / 3
    s_uu = (x0 * x0 + x0 * x1 + x1 * x1) / 3.0 - cx * (x0 + x1) + cx * cx
    s_ww = (y0 * y0 + y0 * y1 + y1 * y1) / 3.0 - cy * (y0 + y1) + cy * cy
    s_uw = (
        (2 * x0 * y0 + x0 * y1 + x1 * y0 + 2 * x1 * y1) / 6.0
        - 0.5 * (cx * (y0 + y1) + cy * (x0 + x1))
        + cx * cy
    )
    return 0.0, load, cx, cy, s_uu, s_uw, s_ww


@numba.njit(**STEP_FLAGS)
def plane_basis(nx, ny, nz):
    """Unit vectors u, w with (u, w, n) right-handed: the patch's coordinates."""
    if abs(nx) < 0.9:
        ux, uy, uz = 0.0, nz, -ny
    else:
        ux, uy, uz = -nz, 0.0, nx
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / norm, uy / norm, uz / norm
    return ux, uy, uz, ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux


@numba.njit(**STEP_FLAGS)
def feature_hulls(va, a, vb, b, d, n, tol, work):
    """Projected hulls of the vertices of cores ``a`` and ``b`` (of the vertex arrays va, vb)
    within tol of their supporting planes across the unit normal n (3-tuple, B to A) of cores a
    distance d apart, in ``plane_basis(n)``, column 2 ``tol - height``: A's in work[0], B's in
    work[1]; returns their sizes and the length under which points merge. Every vertex's
    height that can be within tol stays in work[4] and work[5] for ``patch_moments``."""
    ux, uy, uz, wx, wy, wz = plane_basis(n[0], n[1], n[2])
    u, w = (ux, uy, uz), (wx, wy, wz)
    top_a = _heights(va, a, n, -1.0, tol, work[4])
    top_b = _heights(vb, b, n, 1.0, tol, work[5])
    work[7, TOPS_ROW, 0], work[7, TOPS_ROW, 1] = top_a, top_b  # for patch_moments
    na = _feature(va, a, u, w, work[4], top_a, tol, work[0])
    nb = _feature(vb, b, u, w, work[5], top_b, tol, work[1])
    return _hulls(na, nb, d, tol, work)


@numba.njit(**STEP_FLAGS)
def _hulls(na, nb, d, tol, work):
    """The hulls of the features (``_feature``) of na points in work[0] and nb in work[1], in
    place; returns their sizes and the length under which points merge."""
    eps = 1e-9 * d + 1e-12 * (tol + 1.0)
    ha = _hull2(work[0], na, work[2], eps)
    for k in range(ha):
        _copy_row(work[0], k, work[2], k)
    hb = _hull2(work[1], nb, work[2], eps)
    for k in range(hb):
        _copy_row(work[1], k, work[2], k)
    return ha, hb, eps


@numba.njit(**STEP_FLAGS)
def contact_patch(va, a, vb, b, p_a, p_b, tol, work):
    """Centre of the contact patch of two separated convex shapes ``a`` and ``b`` (``Core``s of
    the vertex arrays va, vb) whose closest points (from ``gjk_distance``, 3-tuples) are p_a and
    p_b, for the overlap ``tol`` of their rounded surfaces: returns ``(area_load, line_load, cx,
    cy, cz, s_uu, s_uw, s_ww)`` with c on the plane midway between the cores and s the patch's
    second moments about c per unit area in ``plane_basis(n)``.

    The patch is where the rounded surfaces overlap: the vertices of each shape less than tol
    above its supporting plane, clipped against the other's in projection. The pressure at a
    vertex is its depth (tol minus its height), linear in between (a Winkler foundation), and c
    is the centre of that pressure: the centroid when two faces are parallel, moving continuously
    to the lower edge as a face tilts by tol over its width, the closest point once one vertex or
    edge alone is within tol. The loads weight patches of several coplanar triangles
    (``patch_moments``: the moments alone, from the crowned contact's projections)."""
    ax, ay, az = p_a
    bx, by, bz = p_b
    nx, ny, nz = ax - bx, ay - by, az - bz
    d = math.sqrt(nx * nx + ny * ny + nz * nz)
    mx, my, mz = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
    if d == 0.0:
        return 0.0, 0.0, mx, my, mz, 0.0, 0.0, 0.0
    nx, ny, nz = nx / d, ny / d, nz / d
    ux, uy, uz, wx, wy, wz = plane_basis(nx, ny, nz)
    ha, hb, eps = feature_hulls(va, a, vb, b, d, (nx, ny, nz), tol, work)
    m = _overlap(ha, hb, eps, work)
    if m == 0:  # crossing edges, or features apart in projection: the closest points
        return 0.0, 0.0, mx, my, mz, 0.0, 0.0, 0.0
    area_load, line_load, cu, cw, s_uu, s_uw, s_ww = _pressure_centre(_overlap_row(ha, hb, work), m)
    h = mx * nx + my * ny + mz * nz
    cx, cy, cz = h * nx + cu * ux + cw * wx, h * ny + cu * uy + cw * wy, h * nz + cu * uz + cw * wz
    return area_load, line_load, cx, cy, cz, s_uu, s_uw, s_ww


@numba.njit(**STEP_FLAGS)
def _overlap(ha, hb, eps, work):
    """The overlap in projection of the hulls work[0][:ha] and work[1][:hb], written where
    ``_overlap_row`` says: the lower-dimensional feature clipped by the other (a polygon clips
    anything), two parallel edges' common part, or nothing (crossing edges, features apart);
    returns its size (0: nothing)."""
    if hb >= 3:
        return _clip(work[0], ha, work[1], hb, work[3])
    if ha >= 3:
        return _clip(work[1], hb, work[0], ha, work[3])
    if ha == 2 and hb == 2:
        return _parallel_segments(work[0], work[1], eps)
    return 0


@numba.njit(inline="always", **JIT_FLAGS)
def _overlap_row(ha, hb, work):
    """Where ``_overlap`` leaves the overlap: work[1] when only A's hull is a polygon."""
    return work[1] if ha >= 3 and hb < 3 else work[0]


@numba.njit(**STEP_FLAGS)
def patch_moments(va, a, vb, b, p_a, p_b, tol, hull_tol, work):
    """``contact_patch``'s second moments ``(s_uu, s_uw, s_ww)`` for cores ``a`` and ``b`` whose
    closest points p_a, p_b were those of the last ``feature_hulls`` in work (as
    ``dem.crown.crowned_contact``'s, for ``hull_tol``), from the heights it left: no second pass
    over the cores unless tol exceeds hull_tol (a deep impact). Where
    one core has a single vertex within tol, the patch is that point or nothing, with no moments
    either way, so the other's hull and the clipping are skipped (a corner on a face of 24
    outline vertices: about a third of a resting pile's contacts)."""
    nx, ny, nz = p_a[0] - p_b[0], p_a[1] - p_b[1], p_a[2] - p_b[2]
    d = math.sqrt(nx * nx + ny * ny + nz * nz)  # n, u and w as contact_patch's, to the bit
    if d == 0.0:
        return 0.0, 0.0, 0.0
    nx, ny, nz = nx / d, ny / d, nz / d
    ux, uy, uz, wx, wy, wz = plane_basis(nx, ny, nz)
    if tol > hull_tol:
        top_a = _heights(va, a, (nx, ny, nz), -1.0, tol, work[4])
        top_b = _heights(vb, b, (nx, ny, nz), 1.0, tol, work[5])
        na = _feature(va, a, (ux, uy, uz), (wx, wy, wz), work[4], top_a, tol, work[0])
        nb = _feature(vb, b, (ux, uy, uz), (wx, wy, wz), work[5], top_b, tol, work[1])
    else:  # the patch's vertices are among the crown's, already projected
        top_a, top_b = work[7, TOPS_ROW, 0], work[7, TOPS_ROW, 1]
        na = _feature_again(a.count, work[4], top_a, tol, work[0])
        nb = _feature_again(b.count, work[5], top_b, tol, work[1])
    if na == 1 or nb == 1:
        return 0.0, 0.0, 0.0
    ha, hb, eps = _hulls(na, nb, d, tol, work)
    m = _overlap(ha, hb, eps, work)
    if m == 0:
        return 0.0, 0.0, 0.0
    _, _, _, _, s_uu, s_uw, s_ww = _pressure_centre(_overlap_row(ha, hb, work), m)
    return s_uu, s_uw, s_ww


@numba.njit(**STEP_FLAGS)
def _parallel_segments(s, t, tol):
    """Overlap of two projected segments if they are collinear (parallel edges): written to s,
    returns 2; else 0 (crossing edges have a unique closest point)."""
    ex, ey = s[1, 0] - s[0, 0], s[1, 1] - s[0, 1]
    length = math.sqrt(ex * ex + ey * ey)
    if length == 0.0:
        return 0
    ex, ey = ex / length, ey / length
    for k in range(2):
        if abs(ex * (t[k, 1] - s[0, 1]) - ey * (t[k, 0] - s[0, 0])) > tol:
            return 0
    lo, hi = 0.0, length
    t0 = ex * (t[0, 0] - s[0, 0]) + ey * (t[0, 1] - s[0, 1])
    t1 = ex * (t[1, 0] - s[0, 0]) + ey * (t[1, 1] - s[0, 1])
    lo = max(lo, min(t0, t1))
    hi = min(hi, max(t0, t1))
    if hi < lo:
        return 0
    x0, y0, p0, p1 = s[0, 0], s[0, 1], s[0, 2], s[1, 2]
    s[0, 0], s[0, 1], s[0, 2] = x0 + lo * ex, y0 + lo * ey, p0 + (p1 - p0) * lo / length
    s[1, 0], s[1, 1], s[1, 2] = x0 + hi * ex, y0 + hi * ey, p0 + (p1 - p0) * hi / length
    return 2
