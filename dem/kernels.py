"""The numba kernels of one time step and of a chunk of steps: integration, neighbour lists,
contact forces.

Scheme (velocity Verlet as in LIGGGHTS, with the free-rotor splitting for rotation)::

    v += dt/2 F/m;  L += dt/2 T            (L: world-frame angular momentum)
    x += dt v;      q <- free rotor over dt (``dem.quaternion.free_rotor_step``)
    walls to their prescribed position at t + dt; sphere positions from (x, q)
    neighbour lists rebuilt if any sphere (or wall) moved more than the Verlet skin allows
    F, T <- gravity + contacts (``dem.contact.sphere_contact_force``)
    v += dt/2 F/m;  L += dt/2 T

Neighbour lists: a cell grid over the spheres' bounding box (cells at least the largest sphere
diameter + skin, counting sort) finds sphere pairs of different bodies closer than
r_i + r_j + skin, and sphere-facet pairs closer than r + skin. Lists are rebuilt only when
2 max|dx_sphere| > skin; sphere-facet pairs of a moving wall are found with an extra margin of
twice its amplitude, so wall motion never forces a rebuild. Sphere pairs are ordered by
(body a, body b, sphere i, sphere j), so each body pair's sphere contacts are contiguous (the
resolution rule of ``dem/contact.py`` shares the pair's stiffness among them); sphere-facet pairs
by (sphere, facet). Tangential history lives in an array parallel to each list and is carried
across rebuilds by merging the two sorted lists.

Per step, the work that only changes at a build is not redone: each body pair's contact-law
constants (``grp_law``) are computed when the lists are built, and a sphere-facet pair whose
distance from the facet's plane (precomputed in ``dem/walls.py``) exceeds the sphere's radius is
dismissed before the closest-point test on each of its triangles.

Nothing here allocates per step; arrays come from ``dem/simulation.py`` which also decides
what a status code means. The kernels never raise for physics: they return a status.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from dem.conf import JIT_FLAGS
from dem.contact import share_weight, sphere_contact_force
from dem.motion import evaluate_into
from dem.quaternion import free_rotor_step, to_matrix

STATUS_OK = 0
STATUS_UNSTABLE_NAN = 1  # NaN or infinite state
STATUS_UNSTABLE_SPEED = 2  # a body moves faster than the allowed maximum
STATUS_UNSTABLE_OVERLAP = 3  # an overlap exceeds the allowed fraction of a radius
STATUS_CAPACITY = 4  # a neighbour list needs more room; the driver grows it and resumes

# Layout of the float parameter vector ``par``.
P_E, P_ZETA, P_MU, P_KT, P_SKIN, P_OVERLAP, P_VMAX = 0, 1, 2, 3, 4, 5, 6
P_GX, P_GY, P_GZ = 7, 8, 9
P_LO, P_HI = 10, 13  # domain bounds (3 each)
P_CELL_LO, P_CELL_H = 16, 19  # the grid of the last build (written by the kernel)
P_CELL_MIN = 20  # smallest cell size: largest sphere diameter + skin
N_PAR = 21
# Layout of the per-wall material rows ``wall_mat``.
W_E, W_ZETA, W_MU, W_KT = 0, 1, 2, 3
# Layout of the per-body-pair contact law rows ``grp_law`` (filled at each list build).
G_KN, G_CN, G_KT, G_CT = 0, 1, 2, 3
# Layout of the integer counters ``cnt``.
C_STEPS, C_BUILDS, C_NEED_PP, C_NEED_WP, C_EVENTS, C_BAD_BODY, C_PP, C_WP, C_GROUPS, C_MIDSTEP = range(10)
C_CONTACTS = 10  # force-carrying sphere contacts at the last step
N_CNT = 11
# Layout of the float clock ``clk``: time, accumulated cost.
K_T, K_COST = 0, 1
# A sphere is rejected on its plane distance only when that exceeds its reach by far more than
# rounding, so the plane test never drops a pair that the closest-point test would keep.
_PLANE_SLACK = 1.0 + 1e-9


@numba.njit(**JIT_FLAGS)
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


@numba.njit(**JIT_FLAGS)
def plane_distance(px, py, pz, f_normal, f_offset, f, dx, dy, dz):
    """Signed distance of p from the plane of facet f displaced by (dx, dy, dz)."""
    return (px - dx) * f_normal[f, 0] + (py - dy) * f_normal[f, 1] + (pz - dz) * f_normal[f, 2] - f_offset[f]


@numba.njit(**JIT_FLAGS)
def closest_point_on_facet(px, py, pz, tri, f_start, f_count, f_normal, f_offset, f, dx, dy, dz):
    """(squared distance, closest point, face flag) of p to facet f displaced by (dx, dy, dz).

    The face flag is True when the closest point is the projection of p on the facet's plane
    (an interior contact), False on an edge or a corner.
    """
    best = np.inf
    bx = by = bz = 0.0
    qx, qy, qz = px - dx, py - dy, pz - dz
    start = f_start[f]
    for t in range(start, start + f_count[f]):
        cx, cy, cz = closest_point_on_triangle(qx, qy, qz, tri[t])
        d2 = (qx - cx) ** 2 + (qy - cy) ** 2 + (qz - cz) ** 2
        if d2 < best:
            best, bx, by, bz = d2, cx, cy, cz
    plane = plane_distance(qx, qy, qz, f_normal, f_offset, f, 0.0, 0.0, 0.0) ** 2
    is_face = best - plane <= 1e-10 * best + 1e-30
    return best, bx + dx, by + dy, bz + dz, is_face


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
def _fill_cells(ns, x, sbody, active, par, dims, cell_start, cell_items, sphere_cell):
    """Counting sort of the spheres into a grid over their bounding box (not the domain, which
    may be mostly empty), with cells enlarged if the box needs more cells than allocated."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for s in range(ns):
        if active[sbody[s]]:
            for k in range(3):
                lo[k] = min(lo[k], x[s, k])
                hi[k] = max(hi[k], x[s, k])
    h = par[P_CELL_MIN]
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
        par[P_CELL_LO + k] = lo[k] if hi[k] >= lo[k] else 0.0
    par[P_CELL_H] = h
    for c in range(n_cells + 1):
        cell_start[c] = 0
    for s in range(ns):
        if not active[sbody[s]]:
            sphere_cell[s] = -1
            continue
        ix = min(max(int((x[s, 0] - par[P_CELL_LO]) / h), 0), dims[0] - 1)
        iy = min(max(int((x[s, 1] - par[P_CELL_LO + 1]) / h), 0), dims[1] - 1)
        iz = min(max(int((x[s, 2] - par[P_CELL_LO + 2]) / h), 0), dims[2] - 1)
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
def _build_sphere_pairs(
    ns, x, radius, sbody, par, dims, cell_start, cell_items, sphere_cell, tmp, new_i, new_j
):
    """Candidate sphere pairs (i < j, different bodies) sorted by (i, j); returns their number
    (which may exceed the capacity of ``new_i``: then only counting)."""
    skin = par[P_SKIN]
    cap = new_i.shape[0]
    n = 0
    nx_, ny_ = dims[0], dims[1]
    for i in range(ns):
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
def _build_wall_pairs(
    ns,
    x,
    radius,
    sbody,
    active,
    par,
    tri,
    f_start,
    f_count,
    f_wall,
    f_lo,
    f_hi,
    f_normal,
    f_offset,
    wall_disp,
    motion_rows,
    new_i,
    new_f,
):
    skin = par[P_SKIN]
    cap = new_i.shape[0]
    n = 0
    for i in range(ns):
        if not active[sbody[i]]:
            continue
        for f in range(f_start.shape[0]):
            w = f_wall[f]
            # A moving wall stays within twice its amplitude of where it is now, so pairs found
            # with that margin stay valid however far it moves: no rebuild for wall motion.
            reach = radius[i] + skin + 2.0 * motion_rows[w, 4]
            outside = False
            for k in range(3):
                xk = x[i, k] - wall_disp[w, k]
                if xk < f_lo[f, k] - reach or xk > f_hi[f, k] + reach:
                    outside = True
            if outside:
                continue
            s = plane_distance(
                x[i, 0],
                x[i, 1],
                x[i, 2],
                f_normal,
                f_offset,
                f,
                wall_disp[w, 0],
                wall_disp[w, 1],
                wall_disp[w, 2],
            )
            if s * s >= reach * reach * _PLANE_SLACK:
                continue
            d2, _, _, _, _ = closest_point_on_facet(
                x[i, 0],
                x[i, 1],
                x[i, 2],
                tri,
                f_start,
                f_count,
                f_normal,
                f_offset,
                f,
                wall_disp[w, 0],
                wall_disp[w, 1],
                wall_disp[w, 2],
            )
            if d2 < reach * reach:
                if n < cap:
                    new_i[n] = i
                    new_f[n] = f
                n += 1
    return n


@numba.njit(**JIT_FLAGS)
def rebuild_lists(
    ns,
    nb,
    x,
    radius,
    sbody,
    active,
    par,
    dims,
    cell_start,
    cell_items,
    sphere_cell,
    tmp,
    pp_i,
    pp_j,
    pp_hist,
    pp_group,
    grp_law,
    mass,
    diameter,
    new_i,
    new_j,
    new_hist,
    tri,
    f_start,
    f_count,
    f_wall,
    f_lo,
    f_hi,
    f_normal,
    f_offset,
    wall_disp,
    wp_i,
    wp_f,
    wp_hist,
    new_wi,
    new_wf,
    new_whist,
    x_build,
    motion_rows,
    cnt,
):
    """Rebuild both neighbour lists, carrying the tangential history of surviving pairs.

    Returns False (lists untouched, needed sizes in ``cnt``) when a list lacks capacity.
    """
    _fill_cells(ns, x, sbody, active, par, dims, cell_start, cell_items, sphere_cell)
    n_pp = _build_sphere_pairs(
        ns, x, radius, sbody, par, dims, cell_start, cell_items, sphere_cell, tmp, new_i, new_j
    )
    n_wp = _build_wall_pairs(
        ns,
        x,
        radius,
        sbody,
        active,
        par,
        tri,
        f_start,
        f_count,
        f_wall,
        f_lo,
        f_hi,
        f_normal,
        f_offset,
        wall_disp,
        motion_rows,
        new_wi,
        new_wf,
    )
    if n_pp > new_i.shape[0] or n_wp > new_wi.shape[0]:
        cnt[C_NEED_PP] = n_pp
        cnt[C_NEED_WP] = n_wp
        return False

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
    n_old = cnt[C_PP]
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
    cnt[C_GROUPS] = n_groups + 1 if n_pp > 0 else 0
    cnt[C_PP] = n_pp
    # The contact law's constants belong to the body pair (dem/contact.py), so they are
    # computed once per build, not once per sphere contact and step.
    E, zeta, kt_ratio = par[P_E], par[P_ZETA], par[P_KT]
    for p in range(n_pp):
        if p > 0 and pp_group[p] == pp_group[p - 1]:
            continue
        ba, bb = sbody[pp_i[p]], sbody[pp_j[p]]
        k_n = E * diameter[ba] * diameter[bb] / (diameter[ba] + diameter[bb])
        m_eff = mass[ba] * mass[bb] / (mass[ba] + mass[bb])
        k_t = kt_ratio * k_n
        g = pp_group[p]
        grp_law[g, G_KN] = k_n
        grp_law[g, G_CN] = 2.0 * zeta * math.sqrt(k_n * m_eff)
        grp_law[g, G_KT] = k_t
        grp_law[g, G_CT] = 2.0 * zeta * math.sqrt(k_t * m_eff)

    old = 0
    n_old = cnt[C_WP]
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
    cnt[C_WP] = n_wp

    for s in range(ns):
        for k in range(3):
            x_build[s, k] = x[s, k]
    cnt[C_BUILDS] += 1
    return True


@numba.njit(**JIT_FLAGS)
def update_spheres(ns, x, offset, sbody, active, pos, rot, x_build):
    """World positions of the spheres; returns the largest squared move since the last build."""
    worst = 0.0
    for s in range(ns):
        b = sbody[s]
        if not active[b]:
            continue
        ox, oy, oz = offset[s, 0], offset[s, 1], offset[s, 2]
        r = rot[b]
        x[s, 0] = pos[b, 0] + r[0, 0] * ox + r[0, 1] * oy + r[0, 2] * oz
        x[s, 1] = pos[b, 1] + r[1, 0] * ox + r[1, 1] * oy + r[1, 2] * oz
        x[s, 2] = pos[b, 2] + r[2, 0] * ox + r[2, 1] * oy + r[2, 2] * oz
        d2 = (x[s, 0] - x_build[s, 0]) ** 2 + (x[s, 1] - x_build[s, 1]) ** 2 + (x[s, 2] - x_build[s, 2]) ** 2
        if d2 > worst:
            worst = d2
    return worst


@numba.njit(**JIT_FLAGS)
def update_omega(nb, active, rot, angmom, inertia, omega):
    """omega = R I^-1 R^T L for every active body."""
    for b in range(nb):
        if not active[b]:
            continue
        r = rot[b]
        lx = r[0, 0] * angmom[b, 0] + r[1, 0] * angmom[b, 1] + r[2, 0] * angmom[b, 2]
        ly = r[0, 1] * angmom[b, 0] + r[1, 1] * angmom[b, 1] + r[2, 1] * angmom[b, 2]
        lz = r[0, 2] * angmom[b, 0] + r[1, 2] * angmom[b, 1] + r[2, 2] * angmom[b, 2]
        wx, wy, wz = lx / inertia[b, 0], ly / inertia[b, 1], lz / inertia[b, 2]
        for k in range(3):
            omega[b, k] = r[k, 0] * wx + r[k, 1] * wy + r[k, 2] * wz


@numba.njit(**JIT_FLAGS)
def _kick(nb, active, vel, angmom, force, torque, mass, h):
    for b in range(nb):
        if not active[b]:
            continue
        hm = h / mass[b]
        for k in range(3):
            vel[b, k] += hm * force[b, k]
            angmom[b, k] += h * torque[b, k]


@numba.njit(**JIT_FLAGS)
def _drift(nb, active, pos, vel, quat, angmom, inertia, rot, lb, dt):
    for b in range(nb):
        if not active[b]:
            continue
        for k in range(3):
            pos[b, k] += dt * vel[b, k]
        r = rot[b]
        for k in range(3):
            lb[k] = r[0, k] * angmom[b, 0] + r[1, k] * angmom[b, 1] + r[2, k] * angmom[b, 2]
        free_rotor_step(quat[b], lb, inertia[b], dt)
        to_matrix(quat[b], rot[b])


@numba.njit(**JIT_FLAGS)
def compute_forces(
    ns,
    nb,
    x,
    radius,
    sbody,
    active,
    pos,
    vel,
    omega,
    mass,
    diameter,
    force,
    torque,
    par,
    pp_i,
    pp_j,
    pp_hist,
    pp_group,
    pp_delta,
    pp_n,
    grp_sum,
    grp_law,
    cnt,
    tri,
    f_start,
    f_count,
    f_wall,
    f_normal,
    f_offset,
    wall_vel,
    wall_disp,
    wall_mat,
    wp_i,
    wp_f,
    wp_hist,
    wp_delta,
    wp_n,
    wp_cp,
    wp_keep,
    facet_sum,
    hist_dt,
):
    """Gravity plus all contact forces and torques. Returns a status (overlap blow-up) and the
    number of sphere contacts carrying force (for the cost)."""
    E, mu, lim = par[P_E], par[P_MU], par[P_OVERLAP]
    for b in range(nb):
        for k in range(3):
            force[b, k] = mass[b] * par[P_GX + k]
            torque[b, k] = 0.0
    n_contacts = 0

    # Sphere pairs: geometry and the overlap sum of each body pair, then forces.
    n_pp = cnt[C_PP]
    for g in range(cnt[C_GROUPS]):
        grp_sum[g] = 0.0
    for p in range(n_pp):
        i, j = pp_i[p], pp_j[p]
        pp_delta[p] = -1.0
        if not (active[sbody[i]] and active[sbody[j]]):
            continue
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        d2 = dx * dx + dy * dy + dz * dz
        rs = radius[i] + radius[j]
        if d2 >= rs * rs:
            pp_hist[p, 0] = pp_hist[p, 1] = pp_hist[p, 2] = 0.0
            continue
        d = math.sqrt(d2)
        delta = rs - d
        if delta > lim * min(radius[i], radius[j]) or d == 0.0:
            cnt[C_BAD_BODY] = sbody[i]
            return STATUS_UNSTABLE_OVERLAP, n_contacts
        pp_delta[p] = delta
        pp_n[p, 0], pp_n[p, 1], pp_n[p, 2] = dx / d, dy / d, dz / d
        grp_sum[pp_group[p]] += share_weight(delta)
    for p in range(n_pp):
        delta = pp_delta[p]
        if delta <= 0.0:
            continue
        i, j = pp_i[p], pp_j[p]
        ba, bb = sbody[i], sbody[j]
        nx, ny, nz = pp_n[p, 0], pp_n[p, 1], pp_n[p, 2]
        reach = radius[j] - 0.5 * delta
        cx, cy, cz = x[j, 0] + nx * reach, x[j, 1] + ny * reach, x[j, 2] + nz * reach
        rax, ray, raz = cx - pos[ba, 0], cy - pos[ba, 1], cz - pos[ba, 2]
        rbx, rby, rbz = cx - pos[bb, 0], cy - pos[bb, 1], cz - pos[bb, 2]
        vx = (vel[ba, 0] + omega[ba, 1] * raz - omega[ba, 2] * ray) - (
            vel[bb, 0] + omega[bb, 1] * rbz - omega[bb, 2] * rby
        )
        vy = (vel[ba, 1] + omega[ba, 2] * rax - omega[ba, 0] * raz) - (
            vel[bb, 1] + omega[bb, 2] * rbx - omega[bb, 0] * rbz
        )
        vz = (vel[ba, 2] + omega[ba, 0] * ray - omega[ba, 1] * rax) - (
            vel[bb, 2] + omega[bb, 0] * rby - omega[bb, 1] * rbx
        )
        g = pp_group[p]
        weight = share_weight(delta) / grp_sum[g]
        fx, fy, fz, _ = sphere_contact_force(
            nx,
            ny,
            nz,
            delta,
            vx,
            vy,
            vz,
            weight,
            grp_law[g, G_KN],
            grp_law[g, G_CN],
            grp_law[g, G_KT],
            grp_law[g, G_CT],
            mu,
            pp_hist,
            p,
            hist_dt,
        )
        force[ba, 0] += fx
        force[ba, 1] += fy
        force[ba, 2] += fz
        force[bb, 0] -= fx
        force[bb, 1] -= fy
        force[bb, 2] -= fz
        torque[ba, 0] += ray * fz - raz * fy
        torque[ba, 1] += raz * fx - rax * fz
        torque[ba, 2] += rax * fy - ray * fx
        torque[bb, 0] -= rby * fz - rbz * fy
        torque[bb, 1] -= rbz * fx - rbx * fz
        torque[bb, 2] -= rbx * fy - rby * fx
        n_contacts += 1

    # Sphere-facet pairs: geometry, then the edge/vertex rule, then per body the overlap sum of
    # each facet, then forces.
    n_wp = cnt[C_WP]
    for p in range(n_wp):
        i, f = wp_i[p], wp_f[p]
        wp_delta[p] = -1.0
        wp_keep[p] = False
        if not active[sbody[i]]:
            continue
        w = f_wall[f]
        r2 = radius[i] * radius[i]
        s = plane_distance(
            x[i, 0],
            x[i, 1],
            x[i, 2],
            f_normal,
            f_offset,
            f,
            wall_disp[w, 0],
            wall_disp[w, 1],
            wall_disp[w, 2],
        )
        if s * s >= r2 * _PLANE_SLACK:
            continue
        d2, cx, cy, cz, is_face = closest_point_on_facet(
            x[i, 0],
            x[i, 1],
            x[i, 2],
            tri,
            f_start,
            f_count,
            f_normal,
            f_offset,
            f,
            wall_disp[w, 0],
            wall_disp[w, 1],
            wall_disp[w, 2],
        )
        if d2 >= r2:
            continue
        d = math.sqrt(d2)
        delta = radius[i] - d
        if delta > lim * radius[i] or d == 0.0:
            cnt[C_BAD_BODY] = sbody[i]
            return STATUS_UNSTABLE_OVERLAP, n_contacts
        wp_delta[p] = delta
        wp_n[p, 0], wp_n[p, 1], wp_n[p, 2] = (x[i, 0] - cx) / d, (x[i, 1] - cy) / d, (x[i, 2] - cz) / d
        wp_cp[p, 0], wp_cp[p, 1], wp_cp[p, 2] = cx, cy, cz
        wp_keep[p] = is_face  # face contacts always count; edge/vertex ones are checked next
    # Edge/vertex contacts (keep False, delta > 0): keep unless their point lies on another
    # touched facet of the same wall that is at least as close (see dem/walls.py).
    p = 0
    while p < n_wp:
        q_end = p
        while q_end < n_wp and wp_i[q_end] == wp_i[p]:
            q_end += 1
        i = wp_i[p]
        tol = 1e-9 + 1e-6 * radius[i]
        for a in range(p, q_end):
            if wp_delta[a] <= 0.0 or wp_keep[a]:
                continue
            dup = False
            for c in range(p, q_end):
                if c == a or wp_delta[c] <= 0.0 or f_wall[wp_f[c]] != f_wall[wp_f[a]]:
                    continue
                closer = wp_delta[c] > wp_delta[a] + tol
                tie = abs(wp_delta[c] - wp_delta[a]) <= tol and (wp_keep[c] or c < a)
                if not (closer or tie):
                    continue
                fc = wp_f[c]
                w = f_wall[fc]
                e2, _, _, _, _ = closest_point_on_facet(
                    wp_cp[a, 0],
                    wp_cp[a, 1],
                    wp_cp[a, 2],
                    tri,
                    f_start,
                    f_count,
                    f_normal,
                    f_offset,
                    fc,
                    wall_disp[w, 0],
                    wall_disp[w, 1],
                    wall_disp[w, 2],
                )
                if e2 <= tol * tol:
                    dup = True
                    break
            if dup:
                wp_delta[a] = -1.0
        for a in range(p, q_end):
            wp_keep[a] = wp_delta[a] > 0.0
            if not wp_keep[a]:
                wp_hist[a, 0] = wp_hist[a, 1] = wp_hist[a, 2] = 0.0
        p = q_end

    p = 0
    while p < n_wp:
        b = sbody[wp_i[p]]
        q_end = p
        while q_end < n_wp and sbody[wp_i[q_end]] == b:
            q_end += 1
        for a in range(p, q_end):
            facet_sum[wp_f[a]] = 0.0
        for a in range(p, q_end):
            if wp_keep[a]:
                facet_sum[wp_f[a]] += share_weight(wp_delta[a])
        # The law's constants depend on the body and the wall only: computed once per run of
        # contacts with the same wall.
        law_wall = -1
        k_n = k_t = c_n = c_t = 0.0
        for a in range(p, q_end):
            if not wp_keep[a]:
                continue
            f = wp_f[a]
            w = f_wall[f]
            if w != law_wall:
                e_w = wall_mat[w, W_E]
                k_n = diameter[b] * E * e_w / (E + e_w)
                k_t = wall_mat[w, W_KT] * k_n
                c_n = 2.0 * wall_mat[w, W_ZETA] * math.sqrt(k_n * mass[b])
                c_t = 2.0 * wall_mat[w, W_ZETA] * math.sqrt(k_t * mass[b])
                law_wall = w
            delta = wp_delta[a]
            nx, ny, nz = wp_n[a, 0], wp_n[a, 1], wp_n[a, 2]
            cx = wp_cp[a, 0] - 0.5 * delta * nx
            cy = wp_cp[a, 1] - 0.5 * delta * ny
            cz = wp_cp[a, 2] - 0.5 * delta * nz
            rax, ray, raz = cx - pos[b, 0], cy - pos[b, 1], cz - pos[b, 2]
            vx = vel[b, 0] + omega[b, 1] * raz - omega[b, 2] * ray - wall_vel[w, 0]
            vy = vel[b, 1] + omega[b, 2] * rax - omega[b, 0] * raz - wall_vel[w, 1]
            vz = vel[b, 2] + omega[b, 0] * ray - omega[b, 1] * rax - wall_vel[w, 2]
            weight = share_weight(delta) / facet_sum[f]
            fx, fy, fz, _ = sphere_contact_force(
                nx,
                ny,
                nz,
                delta,
                vx,
                vy,
                vz,
                weight,
                k_n,
                c_n,
                k_t,
                c_t,
                wall_mat[w, W_MU],
                wp_hist,
                a,
                hist_dt,
            )
            force[b, 0] += fx
            force[b, 1] += fy
            force[b, 2] += fz
            torque[b, 0] += ray * fz - raz * fy
            torque[b, 1] += raz * fx - rax * fz
            torque[b, 2] += rax * fy - ray * fx
            n_contacts += 1
        p = q_end
    return STATUS_OK, n_contacts


@numba.njit(**JIT_FLAGS)
def run_steps(
    n_steps,
    need_forces,
    resume,
    dt,
    clk,
    cnt,
    par,
    dims,
    ns,
    nb,
    pos,
    vel,
    quat,
    angmom,
    omega,
    rot,
    force,
    torque,
    mass,
    inertia,
    diameter,
    active,
    x,
    x_build,
    radius,
    offset,
    sbody,
    motion_rows,
    wall_disp,
    wall_vel,
    wall_mat,
    tri,
    f_start,
    f_count,
    f_wall,
    f_lo,
    f_hi,
    f_normal,
    f_offset,
    cell_start,
    cell_items,
    sphere_cell,
    tmp,
    lb,
    pp_i,
    pp_j,
    pp_hist,
    pp_group,
    pp_delta,
    pp_n,
    grp_sum,
    grp_law,
    new_i,
    new_j,
    new_hist,
    wp_i,
    wp_f,
    wp_hist,
    wp_delta,
    wp_n,
    wp_cp,
    wp_keep,
    facet_sum,
    new_wi,
    new_wf,
    new_whist,
    ev_body,
    ev_time,
):
    """Advance up to ``n_steps`` steps; returns a status. ``cnt[C_STEPS]`` counts steps done in
    this call, ``clk`` holds the time and the accumulated cost, left bodies go to ``ev_*``.

    ``need_forces``: forces are stale (bodies added or removed); rebuild and evaluate them at the
    current state without advancing history. ``resume``: the previous call stopped after the
    drift of a step for lack of list capacity; finish that step first.
    """
    half = 0.5 * dt
    vmax2 = par[P_VMAX] ** 2
    skin = par[P_SKIN]
    cnt[C_STEPS] = 0
    n_walls = motion_rows.shape[0]
    n_active_spheres = 0
    for s in range(ns):
        if active[sbody[s]]:
            n_active_spheres += 1
    force_rebuild = need_forces or resume
    if need_forces and not resume:
        for w in range(n_walls):
            evaluate_into(motion_rows[w], clk[K_T], wall_disp[w], wall_vel[w])
        update_spheres(ns, x, offset, sbody, active, pos, rot, x_build)
        update_omega(nb, active, rot, angmom, inertia, omega)
        if not rebuild_lists(
            ns,
            nb,
            x,
            radius,
            sbody,
            active,
            par,
            dims,
            cell_start,
            cell_items,
            sphere_cell,
            tmp,
            pp_i,
            pp_j,
            pp_hist,
            pp_group,
            grp_law,
            mass,
            diameter,
            new_i,
            new_j,
            new_hist,
            tri,
            f_start,
            f_count,
            f_wall,
            f_lo,
            f_hi,
            f_normal,
            f_offset,
            wall_disp,
            wp_i,
            wp_f,
            wp_hist,
            new_wi,
            new_wf,
            new_whist,
            x_build,
            motion_rows,
            cnt,
        ):
            cnt[C_MIDSTEP] = 0
            return STATUS_CAPACITY
        force_rebuild = False
        status, _ = compute_forces(
            ns,
            nb,
            x,
            radius,
            sbody,
            active,
            pos,
            vel,
            omega,
            mass,
            diameter,
            force,
            torque,
            par,
            pp_i,
            pp_j,
            pp_hist,
            pp_group,
            pp_delta,
            pp_n,
            grp_sum,
            grp_law,
            cnt,
            tri,
            f_start,
            f_count,
            f_wall,
            f_normal,
            f_offset,
            wall_vel,
            wall_disp,
            wall_mat,
            wp_i,
            wp_f,
            wp_hist,
            wp_delta,
            wp_n,
            wp_cp,
            wp_keep,
            facet_sum,
            0.0,
        )
        if status != STATUS_OK:
            return status

    step = 0
    while step < n_steps:
        if not resume:
            _kick(nb, active, vel, angmom, force, torque, mass, half)
            _drift(nb, active, pos, vel, quat, angmom, inertia, rot, lb, dt)
            clk[K_T] += dt
            for w in range(n_walls):
                evaluate_into(motion_rows[w], clk[K_T], wall_disp[w], wall_vel[w])
            sphere_move2 = update_spheres(ns, x, offset, sbody, active, pos, rot, x_build)
            update_omega(nb, active, rot, angmom, inertia, omega)
            sphere_move = math.sqrt(sphere_move2)
            if 2.0 * sphere_move > skin:
                force_rebuild = True
        resume = False
        if force_rebuild:
            if not rebuild_lists(
                ns,
                nb,
                x,
                radius,
                sbody,
                active,
                par,
                dims,
                cell_start,
                cell_items,
                sphere_cell,
                tmp,
                pp_i,
                pp_j,
                pp_hist,
                pp_group,
                grp_law,
                mass,
                diameter,
                new_i,
                new_j,
                new_hist,
                tri,
                f_start,
                f_count,
                f_wall,
                f_lo,
                f_hi,
                f_normal,
                f_offset,
                wall_disp,
                wp_i,
                wp_f,
                wp_hist,
                new_wi,
                new_wf,
                new_whist,
                x_build,
                motion_rows,
                cnt,
            ):
                cnt[C_MIDSTEP] = 1
                return STATUS_CAPACITY
            force_rebuild = False
        status, n_contacts = compute_forces(
            ns,
            nb,
            x,
            radius,
            sbody,
            active,
            pos,
            vel,
            omega,
            mass,
            diameter,
            force,
            torque,
            par,
            pp_i,
            pp_j,
            pp_hist,
            pp_group,
            pp_delta,
            pp_n,
            grp_sum,
            grp_law,
            cnt,
            tri,
            f_start,
            f_count,
            f_wall,
            f_normal,
            f_offset,
            wall_vel,
            wall_disp,
            wall_mat,
            wp_i,
            wp_f,
            wp_hist,
            wp_delta,
            wp_n,
            wp_cp,
            wp_keep,
            facet_sum,
            dt,
        )
        if status != STATUS_OK:
            return status
        _kick(nb, active, vel, angmom, force, torque, mass, half)
        step += 1
        cnt[C_STEPS] = step
        clk[K_COST] += n_active_spheres + n_contacts
        cnt[C_CONTACTS] = n_contacts
        for b in range(nb):
            if not active[b]:
                continue
            v2 = vel[b, 0] ** 2 + vel[b, 1] ** 2 + vel[b, 2] ** 2
            l2 = angmom[b, 0] ** 2 + angmom[b, 1] ** 2 + angmom[b, 2] ** 2
            if not (
                math.isfinite(v2) and math.isfinite(l2) and math.isfinite(pos[b, 0] + pos[b, 1] + pos[b, 2])
            ):
                cnt[C_BAD_BODY] = b
                return STATUS_UNSTABLE_NAN
            if v2 > vmax2:
                cnt[C_BAD_BODY] = b
                return STATUS_UNSTABLE_SPEED
            inside = True
            for k in range(3):
                if pos[b, k] < par[P_LO + k] or pos[b, k] > par[P_HI + k]:
                    inside = False
            if not inside:
                active[b] = False
                ev_body[cnt[C_EVENTS]] = b
                ev_time[cnt[C_EVENTS]] = clk[K_T]
                cnt[C_EVENTS] += 1
                n_active_spheres = 0
                for s in range(ns):
                    if active[sbody[s]]:
                        n_active_spheres += 1
                force_rebuild = True
    update_omega(nb, active, rot, angmom, inertia, omega)
    return STATUS_OK
