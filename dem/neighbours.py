"""Verlet neighbour lists: which sphere pairs and sphere-facet pairs may touch before the next
rebuild.

A cell grid over the spheres' bounding box (cells at least the largest sphere diameter + skin,
counting sort; not over the domain, which may be mostly empty) finds sphere pairs of different
bodies closer than r_i + r_j + skin, and sphere-facet pairs closer than r + skin. The run loop
(``dem/loop.py``) rebuilds the lists only when 2 max|dx_sphere| > skin; sphere-facet pairs of a
moving wall are found with an extra margin of twice its amplitude, so wall motion never forces a
rebuild. Sphere pairs are ordered by (body a, body b, sphere i, sphere j), so each body pair's
sphere contacts are contiguous (a *group*: the resolution rule of ``dem/contact.py`` shares the
pair's stiffness among them); sphere-facet pairs by (sphere, facet). Tangential history lives in
an array parallel to each list and is carried across rebuilds by merging the two sorted lists.
Each build also lists the groups of several pairs (``walks``: two clumps or pieces), orders each
one's pairs by their gap then (``by_gap``, ``gap``) and restarts the bodies' largest sphere moves
(``Grid.moved2``): a pair whose gap exceeds its two bodies' moves since cannot touch, and the force
pass does not visit it (``dem/forces.py``). A group of one pair (every pair of a sphere packing) is
scanned as it is. Sphere-facet pairs likewise: a body's pairs when they hold several of its spheres
(a clump's or a polyhedron's) are tested by their gap at the build against the body's move and
the walls' largest travel since (``Grid.wall_moved2``, kept by the run loop as it moves the
walls).

The containers (``Grid``, ``SpherePairs``, ``WallPairs``, bundled as ``Neighbours``) are built
and grown here, in Python, between kernel calls; the kernels never allocate. A list that lacks
room makes ``rebuild_lists`` return False with the room it needs in its ``count``; the driver
grows it (``grown``) and resumes. The per-pair scratch of the force pass (overlap, normal, the
group's contact-law constants) lives in the lists too, since it is sized and ordered by them;
``dem/forces.py`` says what it means. This module must not compute forces.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from dem.conf import JIT_FLAGS
from dem.contact import N_SUMS
from dem.convex import SIMPLEX
from dem.facets import PLANE_SLACK, closest_point_on_facet, plane_distance
from dem.kept_contact import KEPT

# Layout of a list's ``count``: pairs in use, groups in use (sphere pairs), room needed after a
# failed build, groups of several pairs (sphere pairs).
N_PAIRS, N_GROUPS, N_NEEDED, N_WALKS = 0, 1, 2, 3
# Columns of ``SpherePairs.group_law`` (filled at each build by ``dem.forces.body_pair_laws``).
G_KN, G_CN, G_KT, G_CT, G_MU = 0, 1, 2, 3, 4
_MIN_CAPACITY = 1024
# Listed pairs hold their spheres, facets and groups as 32-bit indices: the force pass streams the
# lists every step, and once they outgrow the cache (about 10,000 spheres) bytes per pair are time.
_INDEX = np.int32


class Grid(NamedTuple):
    """The cell grid of the last build and the per-sphere state of the lists."""

    dims: np.ndarray  # (3,) int64 cells per axis
    origin: np.ndarray  # (4,) lower corner (3) and cell size of the last build
    cell_start: np.ndarray  # (max_cells + 1,) int64 first entry of each cell in cell_items
    cell_items: np.ndarray  # (n_spheres,) int64 spheres sorted by cell
    sphere_cell: np.ndarray  # (n_spheres,) int64 each sphere's cell, -1 when its body is inactive
    candidates: np.ndarray  # (n_spheres,) int64 scratch: one sphere's partners while sorting them
    x_build: np.ndarray  # (n_spheres, 3) sphere centres at the last build (the skin criterion)
    moved2: np.ndarray  # (n_bodies,) largest squared move of any of a body's spheres since the last build
    wall_build: np.ndarray  # (n_walls, 3) each wall's displacement at the last build
    wall_moved2: np.ndarray  # (n_walls,) its largest squared travel from there since


class SpherePairs(NamedTuple):
    """Sphere pairs of different bodies, grouped by body pair, with their tangential history."""

    count: np.ndarray  # (4,) int64: N_PAIRS, N_GROUPS, N_NEEDED, N_WALKS
    i: np.ndarray  # (capacity,) int32 first sphere (i < j)
    j: np.ndarray  # (capacity,) int32
    hist: np.ndarray  # (capacity, 3) tangential spring elongation
    group: np.ndarray  # (capacity,) int32 index of the body pair
    new_i: np.ndarray  # (capacity,) int32 scratch of a rebuild
    new_j: np.ndarray  # (capacity,) int32
    new_hist: np.ndarray  # (capacity, 3)
    delta: np.ndarray  # (capacity,) scratch of the force pass: overlap, -1 when apart
    normal: np.ndarray  # (capacity, 3) scratch of the force pass: unit normal j -> i
    group_sum: np.ndarray  # (capacity, 5) scratch of the force pass: the group's sums (contact.N_SUMS)
    group_law: np.ndarray  # (capacity, 5) the group's contact-law constants, G_* columns
    axis: np.ndarray  # (capacity, 3) rounded pieces: cached separating direction (any is valid)
    point: np.ndarray  # (capacity, 3) scratch of the force pass: a piece pair's contact point
    moment: np.ndarray  # (capacity, 3) scratch of the force pass: its patch's second moments
    simplex: np.ndarray  # (capacity, SIMPLEX) int32 rounded pieces: last GJK simplex (any is valid)
    touch: np.ndarray  # (capacity,) int32 scratch of the force pass: the pairs it works on, in order
    walk: np.ndarray  # (capacity + 1, 2) int32 first and end pair of each group of several pairs, then (n, n)
    by_gap: np.ndarray  # (capacity,) int32 in such a group's range: its pairs by their gap at the build
    gap: np.ndarray  # (capacity,) those gaps, in that order
    kept: np.ndarray  # (capacity, KEPT) rounded pieces: a contact kept (dem/kept_contact.py)


class WallPairs(NamedTuple):
    """Sphere-facet pairs sorted by (sphere, facet), with their tangential history."""

    count: np.ndarray  # (4,) int64: N_PAIRS, unused, N_NEEDED, N_WALKS
    i: np.ndarray  # (capacity,) int32 sphere
    f: np.ndarray  # (capacity,) int32 facet
    hist: np.ndarray  # (capacity, 3)
    new_i: np.ndarray  # (capacity,) int32 scratch of a rebuild
    new_f: np.ndarray  # (capacity,) int32
    new_hist: np.ndarray  # (capacity, 3)
    delta: np.ndarray  # (capacity,) scratch of the force pass: overlap, -1 when apart
    normal: np.ndarray  # (capacity, 3) scratch of the force pass: unit normal facet -> sphere
    point: np.ndarray  # (capacity, 3) scratch of the force pass: closest point on the facet
    keep: np.ndarray  # (capacity,) bool scratch of the force pass: the contact carries force
    moment: np.ndarray  # (capacity, 3) scratch of the force pass: a piece's patch moments
    touching: np.ndarray  # (capacity,) int32 scratch of the force pass: the touching pairs, in order
    walk: np.ndarray  # (capacity + 1, 2) int32 first and end pair of a body's run of several spheres; (n, n)
    gap: np.ndarray  # (capacity,) in such a run: each pair's gap at the build
    axis: np.ndarray  # (capacity, 3) rounded pieces: cached direction facet -> piece (any is valid; 0: none)
    kept: np.ndarray  # (capacity, KEPT) rounded pieces: a contact kept (dem/kept_contact.py)


class Neighbours(NamedTuple):
    grid: Grid
    pairs: SpherePairs
    wall_pairs: WallPairs


# ------------------------------------------------------------------------------- containers


def empty_neighbours() -> Neighbours:
    """Lists for no spheres, with the minimum capacity."""
    return Neighbours(
        sized_grid(None, 0, 0, 0), _sphere_pairs(_MIN_CAPACITY, None), _wall_pairs(_MIN_CAPACITY, None)
    )


def sized_grid(grid: Grid | None, n_spheres: int, n_bodies: int, n_walls: int) -> Grid:
    """A grid for ``n_spheres`` of ``n_bodies`` and ``n_walls`` (the same one if it fits),
    keeping the build positions of the spheres it had."""
    sizes = (n_spheres, n_bodies, n_walls)
    if grid is not None and (len(grid.x_build), len(grid.moved2), len(grid.wall_moved2)) == sizes:
        return grid
    # At most this many cells (a few per sphere keeps the empty-cell overhead small); the kernel
    # enlarges the cells when the spheres' bounding box needs more.
    n_cells = max(8 * n_spheres, _MIN_CAPACITY)
    x_build = np.zeros((n_spheres, 3))
    if grid is not None:
        keep = min(len(grid.x_build), n_spheres)
        x_build[:keep] = grid.x_build[:keep]
    return Grid(
        np.ones(3, dtype=np.int64),
        np.zeros(4),
        np.zeros(n_cells + 1, dtype=np.int64),
        np.zeros(n_spheres, dtype=np.int64),
        np.zeros(n_spheres, dtype=np.int64),
        np.zeros(n_spheres, dtype=np.int64),
        x_build,
        np.zeros(n_bodies),
        np.zeros((n_walls, 3)),
        np.zeros(n_walls),
    )


def grown(lists: Neighbours) -> Neighbours:
    """The lists with room for what the failed build needed (twice, to spare), entries kept."""
    pairs, wall_pairs = lists.pairs, lists.wall_pairs
    need_pp, need_wp = int(pairs.count[N_NEEDED]), int(wall_pairs.count[N_NEEDED])
    cap_pp = max(_MIN_CAPACITY, 2 * need_pp, len(pairs.i))
    cap_wp = max(_MIN_CAPACITY, 2 * need_wp, len(wall_pairs.i))
    if cap_pp > len(pairs.i):
        pairs = _sphere_pairs(cap_pp, pairs)
    if cap_wp > len(wall_pairs.i):
        wall_pairs = _wall_pairs(cap_wp, wall_pairs)
    return Neighbours(lists.grid, pairs, wall_pairs)


def _kept(new: np.ndarray, old: np.ndarray | None, n: int) -> np.ndarray:
    if old is not None:
        new[:n] = old[:n]
    return new


def _sphere_pairs(capacity: int, old: SpherePairs | None) -> SpherePairs:
    n = int(old.count[N_PAIRS]) if old is not None else 0
    count = old.count if old is not None else np.zeros(4, dtype=np.int64)

    def ints(name):
        return _kept(np.zeros(capacity, dtype=_INDEX), getattr(old, name, None), n)

    return SpherePairs(
        count,
        ints("i"),
        ints("j"),
        _kept(np.zeros((capacity, 3)), getattr(old, "hist", None), n),
        ints("group"),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros((capacity, 3)),
        np.zeros(capacity),
        np.zeros((capacity, 3)),
        np.zeros((capacity, N_SUMS)),
        np.zeros((capacity, 5)),
        np.zeros((capacity, 3)),
        np.zeros((capacity, 3)),
        np.zeros((capacity, 3)),
        np.zeros((capacity, SIMPLEX), dtype=_INDEX),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros((capacity + 1, 2), dtype=_INDEX),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros(capacity),
        np.zeros((capacity, KEPT)),
    )


def _wall_pairs(capacity: int, old: WallPairs | None) -> WallPairs:
    n = int(old.count[N_PAIRS]) if old is not None else 0
    count = old.count if old is not None else np.zeros(4, dtype=np.int64)
    return WallPairs(
        count,
        _kept(np.zeros(capacity, dtype=_INDEX), getattr(old, "i", None), n),
        _kept(np.zeros(capacity, dtype=_INDEX), getattr(old, "f", None), n),
        _kept(np.zeros((capacity, 3)), getattr(old, "hist", None), n),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros((capacity, 3)),
        np.zeros(capacity),
        np.zeros((capacity, 3)),
        np.zeros((capacity, 3)),
        np.zeros(capacity, dtype=np.bool_),
        np.zeros((capacity, 3)),
        np.zeros(capacity, dtype=_INDEX),
        np.zeros((capacity + 1, 2), dtype=_INDEX),
        np.zeros(capacity),
        np.zeros((capacity, 3)),
        np.zeros((capacity, KEPT)),
    )


# ------------------------------------------------------------------------------- kernels


@numba.njit(**JIT_FLAGS)
def rebuild_lists(lists, spheres, active, walls, skin, cell_min):
    """Rebuild both neighbour lists, carrying the tangential history of surviving pairs.

    ``active`` is the bodies' flag; ``skin`` the Verlet skin and ``cell_min`` the smallest cell
    size (largest sphere diameter + skin). Returns False (lists untouched, needed sizes in their
    ``count``) when a list lacks capacity.
    """
    grid, pairs, wall_pairs = lists.grid, lists.pairs, lists.wall_pairs
    _fill_cells(grid, spheres.x, spheres.body, active, cell_min)
    n_pp = _build_sphere_pairs(grid, spheres, skin, pairs.new_i, pairs.new_j)
    n_wp = _build_wall_pairs(spheres, active, walls, skin, wall_pairs.new_i, wall_pairs.new_f)
    if n_pp > pairs.new_i.shape[0] or n_wp > wall_pairs.new_i.shape[0]:
        pairs.count[N_NEEDED] = n_pp
        wall_pairs.count[N_NEEDED] = n_wp
        return False
    _adopt_sphere_pairs(pairs, spheres.body, active.shape[0], n_pp)
    _adopt_wall_pairs(wall_pairs, n_wp)
    _sphere_pair_gaps(pairs, spheres)
    _wall_pair_gaps(wall_pairs, spheres, walls)
    x, x_build, moved2 = spheres.x, grid.x_build, grid.moved2
    for s in range(x.shape[0]):
        for k in range(3):
            x_build[s, k] = x[s, k]
    for b in range(moved2.shape[0]):
        moved2[b] = 0.0
    for w in range(grid.wall_moved2.shape[0]):
        for k in range(3):
            grid.wall_build[w, k] = walls.disp[w, k]
        grid.wall_moved2[w] = 0.0
    return True


@numba.njit(**JIT_FLAGS)
def _fill_cells(grid, x, sbody, active, cell_min):
    """Counting sort of the spheres into a grid over their bounding box, with cells enlarged if
    the box needs more cells than allocated."""
    dims, origin, cell_start, cell_items, sphere_cell = (
        grid.dims,
        grid.origin,
        grid.cell_start,
        grid.cell_items,
        grid.sphere_cell,
    )
    ns = x.shape[0]
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for s in range(ns):
        if active[sbody[s]]:
            for k in range(3):
                lo[k] = min(lo[k], x[s, k])
                hi[k] = max(hi[k], x[s, k])
    h = cell_min
    max_cells = cell_start.shape[0] - 1
    while True:
        n_cells = 1
        for k in range(3):
            dims[k] = max(int((hi[k] - lo[k]) / h) + 1, 1) if hi[k] >= lo[k] else 1
            n_cells *= dims[k]
        if n_cells <= max_cells:
            break
        h *= 1.25
    for k in range(3):
        origin[k] = lo[k] if hi[k] >= lo[k] else 0.0
    origin[3] = h
    for c in range(n_cells + 1):
        cell_start[c] = 0
    for s in range(ns):
        if not active[sbody[s]]:
            sphere_cell[s] = -1
            continue
        ix = min(max(int((x[s, 0] - origin[0]) / h), 0), dims[0] - 1)
        iy = min(max(int((x[s, 1] - origin[1]) / h), 0), dims[1] - 1)
        iz = min(max(int((x[s, 2] - origin[2]) / h), 0), dims[2] - 1)
        c = (iz * dims[1] + iy) * dims[0] + ix
        sphere_cell[s] = c
        cell_start[c + 1] += 1
    for c in range(n_cells):
        cell_start[c + 1] += cell_start[c]
    for s in range(ns):
        c = sphere_cell[s]
        if c >= 0:
            cell_items[cell_start[c]] = s
            cell_start[c] += 1
    for c in range(n_cells, 0, -1):
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0


@numba.njit(**JIT_FLAGS)
def _build_sphere_pairs(grid, spheres, skin, new_i, new_j):
    """Candidate sphere pairs (i < j, different bodies) sorted by (i, j); returns their number
    (which may exceed the capacity of ``new_i``: then only counting)."""
    dims, cell_start, cell_items, sphere_cell, tmp = (
        grid.dims,
        grid.cell_start,
        grid.cell_items,
        grid.sphere_cell,
        grid.candidates,
    )
    x, radius, sbody = spheres.x, spheres.radius, spheres.body
    cap = new_i.shape[0]
    n = 0
    nx_, ny_ = dims[0], dims[1]
    for i in range(x.shape[0]):
        c = sphere_cell[i]
        if c < 0:
            continue
        ix = c % nx_
        iy = (c // nx_) % ny_
        iz = c // (nx_ * ny_)
        m = 0
        for oz in range(max(iz - 1, 0), min(iz + 2, dims[2])):
            for oy in range(max(iy - 1, 0), min(iy + 2, dims[1])):
                for ox in range(max(ix - 1, 0), min(ix + 2, dims[0])):
                    cc = (oz * ny_ + oy) * nx_ + ox
                    for k in range(cell_start[cc], cell_start[cc + 1]):
                        j = cell_items[k]
                        if j <= i or sbody[j] == sbody[i]:
                            continue
                        cut = radius[i] + radius[j] + skin
                        d2 = (x[i, 0] - x[j, 0]) ** 2 + (x[i, 1] - x[j, 1]) ** 2 + (x[i, 2] - x[j, 2]) ** 2
                        if d2 < cut * cut:
                            tmp[m] = j
                            m += 1
        for a in range(1, m):  # insertion sort: the per-sphere lists are short
            v = tmp[a]
            b = a - 1
            while b >= 0 and tmp[b] > v:
                tmp[b + 1] = tmp[b]
                b -= 1
            tmp[b + 1] = v
        for a in range(m):
            if n < cap:
                new_i[n] = i
                new_j[n] = tmp[a]
            n += 1
    return n


@numba.njit(**JIT_FLAGS)
def _build_wall_pairs(spheres, active, walls, skin, new_i, new_f):
    """Candidate sphere-facet pairs sorted by (sphere, facet); returns their number (which may
    exceed the capacity of ``new_i``: then only counting)."""
    x, radius, sbody = spheres.x, spheres.radius, spheres.body
    facets, wall_disp, motion = walls.facets, walls.disp, walls.motion
    f_wall, f_lo, f_hi = facets.wall, facets.lo, facets.hi
    cap = new_i.shape[0]
    n = 0
    for i in range(x.shape[0]):
        if not active[sbody[i]]:
            continue
        for f in range(f_wall.shape[0]):
            w = f_wall[f]
            # A moving wall stays within twice its amplitude of where it is now, so pairs found
            # with that margin stay valid however far it moves: no rebuild for wall motion.
            reach = radius[i] + skin + 2.0 * motion[w, 4]
            outside = False
            for k in range(3):
                xk = x[i, k] - wall_disp[w, k]
                if xk < f_lo[f, k] - reach or xk > f_hi[f, k] + reach:
                    outside = True
            if outside:
                continue
            s = plane_distance(
                x[i, 0], x[i, 1], x[i, 2], facets, f, wall_disp[w, 0], wall_disp[w, 1], wall_disp[w, 2]
            )
            if s * s >= reach * reach * PLANE_SLACK:
                continue
            d2, _, _, _, _ = closest_point_on_facet(
                x[i, 0], x[i, 1], x[i, 2], facets, f, wall_disp[w, 0], wall_disp[w, 1], wall_disp[w, 2]
            )
            if d2 < reach * reach:
                if n < cap:
                    new_i[n] = i
                    new_f[n] = f
                n += 1
    return n


@numba.njit(**JIT_FLAGS)
def _pair_before(ba, bb, i, j, ca, cb, k, m):
    """Order of sphere pairs: (body a, body b, sphere i, sphere j) lexicographic."""
    if ba != ca:
        return ba < ca
    if bb != cb:
        return bb < cb
    if i != k:
        return i < k
    return j < m


@numba.njit(**JIT_FLAGS)
def _adopt_sphere_pairs(pairs, sbody, nb, n_pp):
    """Group the ``n_pp`` new pairs by body pair, carry the history of surviving pairs, number
    the groups and make the new pairs current."""
    new_i, new_j, new_hist = pairs.new_i, pairs.new_j, pairs.new_hist
    pp_i, pp_j, pp_hist, pp_group = pairs.i, pairs.j, pairs.hist, pairs.group
    # Group the sphere pairs of each body pair (a stable sort keeps (i, j) order inside).
    ordered = True
    for p in range(1, n_pp):
        if sbody[new_i[p]] * nb + sbody[new_j[p]] < sbody[new_i[p - 1]] * nb + sbody[new_j[p - 1]]:
            ordered = False
            break
    if not ordered:
        keys = np.empty(n_pp, dtype=np.int64)
        for p in range(n_pp):
            keys[p] = sbody[new_i[p]] * nb + sbody[new_j[p]]
        order = np.argsort(keys, kind="mergesort")
        si = new_i[:n_pp].copy()
        sj = new_j[:n_pp].copy()
        for p in range(n_pp):
            new_i[p] = si[order[p]]
            new_j[p] = sj[order[p]]

    # Carry history: both lists are sorted the same way, so one merge pass suffices.
    old = 0
    n_old = pairs.count[N_PAIRS]
    for p in range(n_pp):
        i, j = new_i[p], new_j[p]
        ba, bb = sbody[i], sbody[j]
        while old < n_old and _pair_before(
            sbody[pp_i[old]], sbody[pp_j[old]], pp_i[old], pp_j[old], ba, bb, i, j
        ):
            old += 1
        if old < n_old and pp_i[old] == i and pp_j[old] == j:
            for k in range(3):
                new_hist[p, k] = pp_hist[old, k]
        else:
            for k in range(3):
                new_hist[p, k] = 0.0
    n_groups = 0
    for p in range(n_pp):
        pp_i[p] = new_i[p]
        pp_j[p] = new_j[p]
        for k in range(3):
            pp_hist[p, k] = new_hist[p, k]
        if p > 0 and (sbody[new_i[p]] != sbody[new_i[p - 1]] or sbody[new_j[p]] != sbody[new_j[p - 1]]):
            n_groups += 1
        pp_group[p] = n_groups
    pairs.count[N_GROUPS] = n_groups + 1 if n_pp > 0 else 0
    pairs.count[N_PAIRS] = n_pp


@numba.njit(**JIT_FLAGS)
def _adopt_wall_pairs(wall_pairs, n_wp):
    """Carry the history of surviving sphere-facet pairs and make the ``n_wp`` new pairs current."""
    new_wi, new_wf, new_whist = wall_pairs.new_i, wall_pairs.new_f, wall_pairs.new_hist
    wp_i, wp_f, wp_hist = wall_pairs.i, wall_pairs.f, wall_pairs.hist
    old = 0
    n_old = wall_pairs.count[N_PAIRS]
    for p in range(n_wp):
        i, f = new_wi[p], new_wf[p]
        while old < n_old and (wp_i[old] < i or (wp_i[old] == i and wp_f[old] < f)):
            old += 1
        if old < n_old and wp_i[old] == i and wp_f[old] == f:
            for k in range(3):
                new_whist[p, k] = wp_hist[old, k]
        else:
            for k in range(3):
                new_whist[p, k] = 0.0
    for p in range(n_wp):
        wp_i[p] = new_wi[p]
        wp_f[p] = new_wf[p]
        for k in range(3):
            wp_hist[p, k] = new_whist[p, k]
    wall_pairs.count[N_PAIRS] = n_wp


# A gap is lowered by this fraction of the radii it is measured against, far more than the
# rounding of the distances on either side of the test, so a skipped pair never touches.
_GAP_ROUNDING = 1e-8


@numba.njit(inline="always", **JIT_FLAGS)
def _run_end(p, n, owner, first, second):
    """End of the run of listed pairs from p whose rows ``first`` and ``second`` have the same
    owners as p's (``owner``: the spheres' bodies): a body pair's sphere pairs, or, with ``first``
    and ``second`` both the sphere, a body's sphere-facet pairs."""
    a, b = owner[first[p]], owner[second[p]]
    q = p + 1
    while q < n and owner[first[q]] == a and owner[second[q]] == b:
        q += 1
    return q


@numba.njit(**JIT_FLAGS)
def _sphere_pair_gaps(pairs, spheres):
    """The groups of several pairs (``walk``), each one's pairs ordered by their gap
    |x_i - x_j| - r_i - r_j at the build (-inf for a pair holding a spring), and every pair's
    overlap reset to -1 (apart): the force pass visits such a group's pairs only as far as its
    bodies' moves since the build could have closed a gap (``dem/forces.py``)."""
    pp_i, pp_j, pp_hist = pairs.i, pairs.j, pairs.hist
    walk, by_gap, gap = pairs.walk, pairs.by_gap, pairs.gap
    x, radius = spheres.x, spheres.radius
    n_pp = pairs.count[N_PAIRS]
    for p in range(n_pp):
        pairs.delta[p] = -1.0
    n_walks = 0
    p_first = 0
    while p_first < n_pp:
        p_end = _run_end(p_first, n_pp, spheres.body, pp_i, pp_j)
        if p_end - p_first > 1:
            walk[n_walks, 0], walk[n_walks, 1] = p_first, p_end
            n_walks += 1
            for k in range(p_first, p_end):
                i, j = pp_i[k], pp_j[k]
                rs = radius[i] + radius[j]
                d = np.sqrt((x[i, 0] - x[j, 0]) ** 2 + (x[i, 1] - x[j, 1]) ** 2 + (x[i, 2] - x[j, 2]) ** 2)
                g = d - rs - _GAP_ROUNDING * rs
                if pp_hist[k, 0] != 0.0 or pp_hist[k, 1] != 0.0 or pp_hist[k, 2] != 0.0:
                    g = -np.inf
                # Insertion sort, stable: a group holds a few dozen pairs at most.
                at = k
                while at > p_first and gap[at - 1] > g:
                    gap[at], by_gap[at] = gap[at - 1], by_gap[at - 1]
                    at -= 1
                gap[at], by_gap[at] = g, k
        p_first = p_end
    walk[n_walks, 0], walk[n_walks, 1] = n_pp, n_pp
    pairs.count[N_WALKS] = n_walks


@numba.njit(**JIT_FLAGS)
def _wall_pair_gaps(wall_pairs, spheres, walls):
    """The bodies' runs of sphere-facet pairs that hold several of their spheres (``walk``),
    their pairs' gaps |x_i - facet| - r_i at the build (-inf for a pair holding a spring), and
    every pair reset to apart (overlap -1, no force): the force pass examines such a pair only
    when the body's move and the walls' travel since the build could have closed its gap
    (``dem/forces.py``). A facet moves with its wall, as a translation."""
    wp_i, wp_f, wp_hist = wall_pairs.i, wall_pairs.f, wall_pairs.hist
    walk, gap = wall_pairs.walk, wall_pairs.gap
    x, radius = spheres.x, spheres.radius
    facets, wall_disp = walls.facets, walls.disp
    n_wp = wall_pairs.count[N_PAIRS]
    for p in range(n_wp):
        wall_pairs.delta[p] = -1.0
        wall_pairs.keep[p] = False
    n_walks = 0
    p_first = 0
    while p_first < n_wp:
        p_end = _run_end(p_first, n_wp, spheres.body, wp_i, wp_i)
        if wp_i[p_first] != wp_i[p_end - 1]:
            walk[n_walks, 0], walk[n_walks, 1] = p_first, p_end
            n_walks += 1
            for k in range(p_first, p_end):
                i, f = wp_i[k], wp_f[k]
                w = facets.wall[f]
                d2, _, _, _, _ = closest_point_on_facet(
                    x[i, 0], x[i, 1], x[i, 2], facets, f, wall_disp[w, 0], wall_disp[w, 1], wall_disp[w, 2]
                )
                g = np.sqrt(d2) - radius[i] - _GAP_ROUNDING * radius[i]
                if wp_hist[k, 0] != 0.0 or wp_hist[k, 1] != 0.0 or wp_hist[k, 2] != 0.0:
                    g = -np.inf
                gap[k] = g
        p_first = p_end
    walk[n_walks, 0], walk[n_walks, 1] = n_wp, n_wp
    wall_pairs.count[N_WALKS] = n_walks
