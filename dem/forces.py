"""Contact forces and torques on the bodies from the neighbour lists, plus gravity.

For every listed pair the geometry (overlap, normal, contact point) is computed here and the
force comes from ``dem.contact.sphere_contact_force``; this module applies the law's rules that
involve more than one sphere contact:

* the resolution rule: a body pair (or a body and a facet) with several simultaneous sphere
  contacts is one spring-dashpot in the Lehmer mean M of their overlaps, and each contact carries
  its share ``dM/d(delta_k)`` of the pair's force (``dem/contact.py``): the first pass over the
  contacts sums their ``share_sums`` per group, the second applies the forces;
* the facet rule of ``dem/walls.py``: an edge or vertex contact is dropped when its contact
  point also lies on another touched facet of the same wall that is at least as close.
* a lasting contact of a rounded piece (with a piece, a sphere or a facet) whose bodies have not
  moved relative to each other since its last full evaluation, by more than a thousandth of its
  overlap, is served from that evaluation (``dem/kept_contact.py``): a resting pile's contacts.

A row that is a rounded-polyhedron piece (``core_count > 0``) gets its overlap, normal, contact
point and patch from ``dem/rounded_contact.py`` instead of the sphere formulas (a plain sphere
meeting a piece is a one-vertex core), and its face contacts the patch's dampers
(``dem.contact.patch_damping``); the rest of the law is shared.

The contact-law constants of a body pair (K, C, K_t, C_t: two square roots) change only when
the lists are rebuilt, so ``body_pair_laws`` computes them once per build into the list's
``group_law``; against a wall they are computed once per body and wall in each step. A
sphere-facet pair whose distance from the facet's plane exceeds the sphere's radius is dismissed
before the closest-point test on each of its triangles.

Materials (``dem/materials.py``): every body and wall has a material index into the
simulation's table ``material`` (``MaterialArrays``): K from both moduli in series, damping ratio,
friction and K_t / K_n from the pair's row.

Kernels only, no allocation; a blow-up is reported as the offending body, never raised.
"""

from __future__ import annotations

import math

import numba

from dem.conf import JIT_FLAGS, STEP_FLAGS
from dem.contact import (
    N_SUMS,
    PairLaw,
    contact_share,
    pair_normal_force,
    patch_damping,
    share_sums,
    shared_overlap,
    sphere_contact_force,
)
from dem.convex import at_point, place_body
from dem.crown import crown_radius
from dem.facets import PLANE_SLACK, closest_point_on_facet, plane_distance
from dem.kept_contact import (
    K_FACE,
    K_M,
    WALL_FRAME,
    body_frame,
    keep_apart,
    keep_contact,
    kept_contact,
    moves_beyond,
)
from dem.materials import L_KT, L_MU, L_ZETA
from dem.neighbours import G_CN, G_CT, G_KN, G_KT, G_MU, N_PAIRS, N_WALKS
from dem.rounded_contact import WallFacet, box_extent, facet_axis_clears, facet_geometry, pair_geometry

# A piece's box clears a partner only by more than the rounding times this: the box and the
# core's vertices are placed by different sums, which may differ in the last bits.
BOX_SLACK = 1.0 + 1e-9
# A piece-facet pair's cached direction clears it only by more than the rounding times this:
# beyond the sums' last bits, the crowned distance the geometry would have found can lie below
# the cores' distance by the crown's rounding slack (2e-9 of its tolerance, under 1e-9 r).
FACET_AXIS_SLACK = 1.0 + 1e-6


@numba.njit(**JIT_FLAGS)
def pair_law(k_n, m_eff, row):
    """The ``PairLaw`` of two partners of normal stiffness ``k_n`` and effective mass ``m_eff``
    whose materials' pair row is ``row`` (``L_*`` columns): C = 2 zeta sqrt(K m*), K_t from the
    ratio, C_t = 2 zeta sqrt(K_t m*) (``dem/contact.py``)."""
    k_t = row[L_KT] * k_n
    return PairLaw(
        k_n,
        2.0 * row[L_ZETA] * math.sqrt(k_n * m_eff),
        k_t,
        2.0 * row[L_ZETA] * math.sqrt(k_t * m_eff),
        row[L_MU],
    )


@numba.njit(inline="always", **JIT_FLAGS)
def _group_law(grp_law, g):
    """The ``PairLaw`` stored for body pair group g by ``body_pair_laws``."""
    return PairLaw(grp_law[g, G_KN], grp_law[g, G_CN], grp_law[g, G_KT], grp_law[g, G_CT], grp_law[g, G_MU])


@numba.njit(inline="always", **JIT_FLAGS)
def _point_velocity(vel, omega, b, rx, ry, rz):
    """Velocity of body b's material point at lever r from its centre: v + omega x r."""
    return (
        vel[b, 0] + omega[b, 1] * rz - omega[b, 2] * ry,
        vel[b, 1] + omega[b, 2] * rx - omega[b, 0] * rz,
        vel[b, 2] + omega[b, 0] * ry - omega[b, 1] * rx,
    )


@numba.njit(inline="always", **JIT_FLAGS)
def _push(force, torque, b, fx, fy, fz, rx, ry, rz):
    """Adds the force f, applied at lever r from body b's centre, and its torque r x f."""
    force[b, 0] += fx
    force[b, 1] += fy
    force[b, 2] += fz
    torque[b, 0] += ry * fz - rz * fy
    torque[b, 1] += rz * fx - rx * fz
    torque[b, 2] += rx * fy - ry * fx


@numba.njit(inline="always", **JIT_FLAGS)
def _twist(torque, b, tx, ty, tz):
    """Adds the torque t (a couple: no force) to body b."""
    torque[b, 0] += tx
    torque[b, 1] += ty
    torque[b, 2] += tz


@numba.njit(inline="always", **JIT_FLAGS)
def _approach_rate(bodies, ba, bb, point, n):
    """d(delta)/dt of a contact at ``point`` (3-tuple) with normal n (3-tuple, b -> a) between
    bodies ba and bb: minus their relative velocity there along n."""
    pos, vel, omega = bodies.pos, bodies.vel, bodies.omega
    cx, cy, cz = point[0], point[1], point[2]
    vax, vay, vaz = _point_velocity(vel, omega, ba, cx - pos[ba, 0], cy - pos[ba, 1], cz - pos[ba, 2])
    vbx, vby, vbz = _point_velocity(vel, omega, bb, cx - pos[bb, 0], cy - pos[bb, 1], cz - pos[bb, 2])
    return -((vax - vbx) * n[0] + (vay - vby) * n[1] + (vaz - vbz) * n[2])


@numba.njit(inline="always", **JIT_FLAGS)
def _add_sums(sums, g, delta, rate):
    """Adds one touching contact (overlap ``delta``, ``rate`` = d(delta)/dt) to row g of a
    group's sums (``N_SUMS`` columns)."""
    a, b, c, d, e = share_sums(delta, rate)
    sums[g, 0] += a
    sums[g, 1] += b
    sums[g, 2] += c
    sums[g, 3] += d
    sums[g, 4] += e
    sums[g, 5] += 1.0


@numba.njit(inline="always", **JIT_FLAGS)
def _contact_normal_force(sums, g, single, delta, v, n, law):
    """(f_n, N, w) of one contact of group g: its normal force, its pair's net normal force (the Coulomb
    cap's) and its share of the tangential law. A contact alone in its group (``single``, or the only one
    touching) carries the whole law, ``K delta + C d(delta)/dt``; otherwise the pair is one spring-dashpot
    in the mean overlap of ``dem.contact.shared_overlap`` and the contact takes its ``contact_share``.
    ``v`` (3-tuple) is the first partner's velocity relative to the second along n (3-tuple)."""
    if single or sums[g, 5] == 1.0:
        rate = -(v[0] * n[0] + v[1] * n[1] + v[2] * n[2])
        f = pair_normal_force(delta, rate, law.k_n, law.c_n)
        return f, f, 1.0
    m, m_rate, net = shared_overlap((sums[g, 0], sums[g, 1], sums[g, 2], sums[g, 3], sums[g, 4]))
    f = pair_normal_force(m, m_rate, law.k_n, law.c_n)
    share, weight = contact_share(delta, m, sums[g, 1])
    return f * share, f * max(net, 0.0), weight


@numba.njit(**JIT_FLAGS)
def body_pair_laws(pairs, sbody, bodies, material):
    """Each body pair's contact-law constants (``G_*`` columns of ``pairs.group_law``) for the
    pairs just built: K = series(E_a D_a, E_b D_b), C = 2 zeta sqrt(K m*), zeta, mu and K_t / K_n
    of the pair of materials (``dem/contact.py``, ``dem/materials.py``)."""
    pp_i, pp_j, pp_group, grp_law = pairs.i, pairs.j, pairs.group, pairs.group_law
    diameter, mass, body_mat = bodies.diameter, bodies.mass, bodies.material
    for p in range(pairs.count[N_PAIRS]):
        if p > 0 and pp_group[p] == pp_group[p - 1]:
            continue
        ba, bb = sbody[pp_i[p]], sbody[pp_j[p]]
        ma, mb = body_mat[ba], body_mat[bb]
        e_a, e_b = material.E[ma], material.E[mb]
        if e_a == e_b:  # E D_a D_b / (D_a + D_b), the paper's form, to the last bit
            k_n = e_a * diameter[ba] * diameter[bb] / (diameter[ba] + diameter[bb])
        else:
            k_a, k_b = e_a * diameter[ba], e_b * diameter[bb]
            k_n = k_a * k_b / (k_a + k_b)
        m_eff = mass[ba] * mass[bb] / (mass[ba] + mass[bb])
        law = pair_law(k_n, m_eff, material.law[ma, mb])
        g = pp_group[p]
        grp_law[g, G_KN], grp_law[g, G_CN], grp_law[g, G_KT] = law.k_n, law.c_n, law.k_t
        grp_law[g, G_CT], grp_law[g, G_MU] = law.c_t, law.mu


@numba.njit(**STEP_FLAGS)
def compute_forces(bodies, spheres, material, walls, lists, gravity, overlap_limit, hist_dt):
    """Gravity plus all contact forces and torques.

    Returns (sphere contacts carrying force, for the cost; the body whose overlap exceeds
    ``overlap_limit`` of a sphere radius, or -1). ``hist_dt`` advances the tangential springs
    (0 re-evaluates forces without advancing them). Compiled without numba's runtime
    (``dem/conf.py``: ``STEP_FLAGS``): it must not allocate nor return an array.
    """
    force, torque, mass = bodies.force, bodies.torque, bodies.mass
    for b in range(mass.shape[0]):
        for k in range(3):
            force[b, k] = mass[b] * gravity[k]
            torque[b, k] = 0.0
    moved2 = lists.grid.moved2
    n_pairs, bad = _sphere_pair_forces(bodies, spheres, lists.pairs, moved2, overlap_limit, hist_dt)
    if bad >= 0:
        return n_pairs, bad
    n_walls, bad = _wall_forces(bodies, spheres, material, walls, lists, overlap_limit, hist_dt)
    return n_pairs + n_walls, bad


@numba.njit(inline="always", **JIT_FLAGS)
def _sphere_pair_forces(bodies, spheres, pairs, moved2, lim, hist_dt):
    """Sphere-sphere contacts. Returns (contacts carrying force, offending body or -1).

    A scan without branches first lists the pairs that need work (touching, or holding a spring
    to clear) in ``pairs.touch``: about half of a settled packing's listed pairs touch, and
    deciding that inside the force loop cost a mispredicted jump a pair (10,140 settling spheres:
    883 -> 732 us a pass). In a group of several pairs (two clumps or pieces) the scan visits
    only the pairs whose gap at the build the moves of their bodies' spheres since then
    (``moved2``, squared, from ``dem.integrate.update_spheres``) could have closed:
    |x_i - x_j| >= d_build - |dx_i| - |dx_j|. In the shaken feeder about 2 % of the listed pairs
    touch and about 30 % are visited (``benchmarks/README.md``, engine speed session 10). A
    group of one pair is scanned as it is: walking it costs a sphere packing more than it saves
    (session 11). A body pair with one listed sphere pair (two plain
    spheres: every pair of a sphere packing) carries its whole law, so its force is applied in the
    first pass over those. The others need their group's sums first: the first pass keeps their
    geometry and adds their ``share_sums`` (and count) to the group's, the second applies their
    forces (skipped when there are none); a group with one touching contact carries the whole law
    there too. ``delta`` is kept for every pair (-1 when apart): ``Simulation.current_overlap``
    reads it.
    """
    x, radius, sbody = spheres.x, spheres.radius, spheres.body
    rounding, core_count = spheres.rounding, spheres.core_count
    core, core_start, crown, half, work, rot = (
        spheres.core,
        spheres.core_start,
        spheres.crown,
        spheres.half,
        spheres.work,
        bodies.rot,
    )
    active, pos, vel, omega, force, torque = (
        bodies.active,
        bodies.pos,
        bodies.vel,
        bodies.omega,
        bodies.force,
        bodies.torque,
    )
    pp_i, pp_j, pp_hist, pp_group = pairs.i, pairs.j, pairs.hist, pairs.group
    pp_delta, pp_n, grp_sum, grp_law = pairs.delta, pairs.normal, pairs.group_sum, pairs.group_law
    n_contacts = 0
    n_deferred = 0
    n_pp = pairs.count[N_PAIRS]
    # The pairs that need work: touching, or holding a spring to clear. Branch-free, so that a
    # packing's half-touching pairs cost no mispredicted jumps here.
    # The groups of several pairs (``walk``) lie between runs of lone pairs, which are scanned
    # as they are. A pair of such a group farther apart at the build than its bodies' spheres
    # have moved since neither touches nor holds a spring, and its overlap is still the -1 of the
    # build: the group's pairs are visited by their gap then (``by_gap``, ``gap``) only while a
    # move could have closed it, and the ones that need work put back in list order. The moves
    # only grow until the next build, so a pair once visited is visited at every step until then.
    touch, walk, by_gap, gap = pairs.touch, pairs.walk, pairs.by_gap, pairs.gap
    n_touch = 0
    p_lone = 0
    for w in range(pairs.count[N_WALKS] + 1):
        p_first, p_end = walk[w, 0], walk[w, 1]
        for p in range(p_lone, p_first):
            pp_delta[p] = -1.0
            touch[n_touch] = p
            n_touch += _needs_work(x, radius, pp_hist, pp_i[p], pp_j[p], p)
        p_lone = p_end
        if p_first == p_end:
            continue
        closable = math.sqrt(moved2[sbody[pp_i[p_first]]]) + math.sqrt(moved2[sbody[pp_j[p_first]]])
        t_first = n_touch
        for k in range(p_first, p_end):
            if gap[k] > closable:
                break
            p = by_gap[k]
            pp_delta[p] = -1.0
            touch[n_touch] = p
            n_touch += _needs_work(x, radius, pp_hist, pp_i[p], pp_j[p], p)
        for t_at in range(t_first + 1, n_touch):  # insertion sort: a few pairs a group
            p_at = touch[t_at]
            t_to = t_at - 1
            while t_to >= t_first and touch[t_to] > p_at:
                touch[t_to + 1] = touch[t_to]
                t_to -= 1
            touch[t_to + 1] = p_at
    zeroed = -1
    for t in range(n_touch):
        p = touch[t]
        i, j = pp_i[p], pp_j[p]
        g = pp_group[p]
        single = (p == 0 or pp_group[p - 1] != g) and (p == n_pp - 1 or pp_group[p + 1] != g)
        if not single and g != zeroed:
            for k in range(N_SUMS):
                grp_sum[g, k] = 0.0
            zeroed = g
        if not (active[sbody[i]] and active[sbody[j]]):
            continue
        dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        d2 = dx * dx + dy * dy + dz * dz
        rs = radius[i] + radius[j]
        if d2 >= rs * rs:
            # Only a spring that held something is reset: untouched memory stays clean.
            if pp_hist[p, 0] != 0.0 or pp_hist[p, 1] != 0.0 or pp_hist[p, 2] != 0.0:
                pp_hist[p, 0] = pp_hist[p, 1] = pp_hist[p, 2] = 0.0
            continue
        if core_count[i] > 0 or core_count[j] > 0:
            # The pieces' boxes along the cached axis first: they clear most pairs whose bounding
            # spheres overlap, as the cores would (``pair_geometry``'s first test), for less.
            sx, sy, sz = pairs.axis[p, 0], pairs.axis[p, 1], pairs.axis[p, 2]
            if sx != 0.0 or sy != 0.0 or sz != 0.0:
                low_a, _ = box_extent(x, half, rot, i, sbody[i], sx, sy, sz)
                _, high_b = box_extent(x, half, rot, j, sbody[j], sx, sy, sz)
                if low_a - high_b > (rounding[i] + rounding[j]) * BOX_SLACK:
                    pp_hist[p, 0] = pp_hist[p, 1] = pp_hist[p, 2] = 0.0
                    continue
            # A lasting contact whose bodies have not moved relative to each other is served from
            # its last full evaluation (``dem/kept_contact.py``): a resting pile's pairs.
            ba, bb = sbody[i], sbody[j]
            frame_a, frame_b = body_frame(rot, ba), body_frame(rot, bb)
            origin_a, origin_b = _row(pos, ba), _row(pos, bb)
            key = (i + 1.0, j + 1.0)
            served, delta, nx, ny, nz, cx, cy, cz = kept_contact(
                pairs.kept, p, key, frame_a, origin_a, frame_b, origin_b
            )
            if served and delta <= 0.0:  # kept apart: its spring was cleared when it was kept
                continue
            if served:
                if delta > lim * min(rounding[i], rounding[j]):
                    return n_contacts, ba
                _write_piece_contact(pairs, grp_sum, g, single, p, delta, (nx, ny, nz), (cx, cy, cz))
                pairs.moment[p, 0] = pairs.kept[p, K_M]
                pairs.moment[p, 1] = pairs.kept[p, K_M + 1]
                pairs.moment[p, 2] = pairs.kept[p, K_M + 2]
                _add_sums(grp_sum, g, delta, _approach_rate(bodies, ba, bb, pairs.point[p], (nx, ny, nz)))
                n_deferred += 1
                continue
            # The pieces' cores (a plain sphere is a one-vertex core at its centre), written out
            # here on the arrays at hand: a helper given arrays or the containers costs an atomic
            # reference count up and down for each (25 for Bodies and Spheres), which was a third
            # of a polyhedron step.
            if core_count[i] > 0:
                va, a = core, place_body(core_start[i], core_count[i], rot, pos, sbody[i])
            else:
                va, a = x, at_point(i)
            if core_count[j] > 0:
                vb, b = core, place_body(core_start[j], core_count[j], rot, pos, sbody[j])
            else:
                vb, b = x, at_point(j)
            delta, dist, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww = pair_geometry(
                va,
                a,
                rounding[i],
                _row(crown, i),
                vb,
                b,
                rounding[j],
                _row(crown, j),
                pairs.axis[p],
                pairs.simplex[p],
                work,
                pp_hist[p, 0] != 0.0 or pp_hist[p, 1] != 0.0 or pp_hist[p, 2] != 0.0,  # touched last step
            )
            # Kept for the next steps if the bodies move slowly enough for it to be served: a
            # contact, or a pair apart by a margin (``dem/kept_contact.py``). B's points that
            # matter lie within its row's reach and A's rounding of its centre.
            reach = spheres.reach[j] + rounding[i]
            still = delta != 0.0 and not moves_beyond(
                pairs.kept,
                p,
                hist_dt,
                _row(vel, ba),
                _row(omega, ba),
                origin_a,
                _row(vel, bb),
                _row(omega, bb),
                origin_b,
                reach,
                delta,
            )
            if delta <= 0.0:
                pp_hist[p, 0] = pp_hist[p, 1] = pp_hist[p, 2] = 0.0
                if still:
                    keep_apart(pairs.kept, p, key, reach, frame_a, origin_a, frame_b, origin_b, delta)
                continue
            if dist == 0.0 or delta > lim * min(rounding[i], rounding[j]):
                return n_contacts, sbody[i]
            # The middle of the overlap along n (as for spheres): the mid-plane point moved by
            # (r_b - r_a) / 2.
            shift = 0.5 * (rounding[j] - rounding[i])
            point = (cx + shift * nx, cy + shift * ny, cz + shift * nz)
            _write_piece_contact(pairs, grp_sum, g, single, p, delta, (nx, ny, nz), point)
            pairs.moment[p, 0], pairs.moment[p, 1], pairs.moment[p, 2] = s_uu, s_uw, s_ww
            if still:
                keep_contact(
                    pairs.kept,
                    p,
                    key,
                    reach,
                    frame_a,
                    origin_a,
                    frame_b,
                    origin_b,
                    delta,
                    (nx, ny, nz),
                    point,
                    (s_uu, s_uw, s_ww),
                    (crown_radius(_row(crown, i)), crown_radius(_row(crown, j))),
                )
            _add_sums(grp_sum, g, delta, _approach_rate(bodies, ba, bb, point, (nx, ny, nz)))
            n_deferred += 1
            continue
        d = math.sqrt(d2)
        delta = rs - d
        if delta > lim * min(radius[i], radius[j]) or d == 0.0:
            return n_contacts, sbody[i]
        nx, ny, nz = dx / d, dy / d, dz / d
        pp_delta[p] = delta
        if single:
            _sphere_pair_force(p, g, True, (i, j), (nx, ny, nz), delta, bodies, spheres, pairs, hist_dt)
            n_contacts += 1
            continue
        pp_n[p, 0], pp_n[p, 1], pp_n[p, 2] = nx, ny, nz
        reach = radius[j] - 0.5 * delta
        point = (x[j, 0] + nx * reach, x[j, 1] + ny * reach, x[j, 2] + nz * reach)
        _add_sums(grp_sum, g, delta, _approach_rate(bodies, sbody[i], sbody[j], point, (nx, ny, nz)))
        n_deferred += 1
    if n_deferred == 0:
        return n_contacts, -1
    for t in range(n_touch):
        p = touch[t]
        delta = pp_delta[p]
        if delta <= 0.0:
            continue
        i, j = pp_i[p], pp_j[p]
        g = pp_group[p]
        rounded = core_count[i] > 0 or core_count[j] > 0
        single = (p == 0 or pp_group[p - 1] != g) and (p == n_pp - 1 or pp_group[p + 1] != g)
        if single and not rounded:
            continue  # done in the first pass
        nx, ny, nz = pp_n[p, 0], pp_n[p, 1], pp_n[p, 2]
        if not rounded:  # not single: done in the first pass
            _sphere_pair_force(p, g, False, (i, j), (nx, ny, nz), delta, bodies, spheres, pairs, hist_dt)
            n_contacts += 1
            continue
        ba, bb = sbody[i], sbody[j]
        cx, cy, cz = pairs.point[p, 0], pairs.point[p, 1], pairs.point[p, 2]
        rax, ray, raz = cx - pos[ba, 0], cy - pos[ba, 1], cz - pos[ba, 2]
        rbx, rby, rbz = cx - pos[bb, 0], cy - pos[bb, 1], cz - pos[bb, 2]
        vax, vay, vaz = _point_velocity(vel, omega, ba, rax, ray, raz)
        vbx, vby, vbz = _point_velocity(vel, omega, bb, rbx, rby, rbz)
        law = _group_law(grp_law, g)
        v = (vax - vbx, vay - vby, vaz - vbz)
        f_n, f_pair, weight = _contact_normal_force(grp_sum, g, single, delta, v, (nx, ny, nz), law)
        fx, fy, fz = sphere_contact_force((nx, ny, nz), f_n, f_pair, v, weight, law, pp_hist, p, hist_dt)
        _push(force, torque, ba, fx, fy, fz, rax, ray, raz)
        _push(force, torque, bb, -fx, -fy, -fz, rbx, rby, rbz)
        moment = (pairs.moment[p, 0], pairs.moment[p, 1], pairs.moment[p, 2])
        spin = (omega[ba, 0] - omega[bb, 0], omega[ba, 1] - omega[bb, 1], omega[ba, 2] - omega[bb, 2])
        tx, ty, tz = patch_damping(
            (nx, ny, nz), moment, spin, weight * law.c_n, weight * law.c_t, law.mu * weight * f_pair
        )
        _twist(torque, ba, tx, ty, tz)
        _twist(torque, bb, -tx, -ty, -tz)
        n_contacts += 1
    return n_contacts, -1


@numba.njit(inline="always", **JIT_FLAGS)
def _write_piece_contact(pairs, grp_sum, g, single, p, delta, n, point):
    """Writes a touching piece pair's overlap, normal and contact point for the second pass,
    and clears its group's sums if it is the group's only pair."""
    pairs.delta[p] = delta
    pairs.normal[p, 0], pairs.normal[p, 1], pairs.normal[p, 2] = n
    pairs.point[p, 0], pairs.point[p, 1], pairs.point[p, 2] = point
    if single:
        for k in range(N_SUMS):
            grp_sum[g, k] = 0.0


@numba.njit(inline="always", **JIT_FLAGS)
def _needs_work(x, radius, hist, i, j, p):
    """Whether listed pair p (spheres i and j) touches or holds a spring to clear, without
    branches."""
    dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
    rs = radius[i] + radius[j]
    return (
        (dx * dx + dy * dy + dz * dz < rs * rs)
        | (hist[p, 0] != 0.0)
        | (hist[p, 1] != 0.0)
        | (hist[p, 2] != 0.0)
    )


@numba.njit(inline="always", **JIT_FLAGS)
def _sphere_pair_force(p, g, single, rows, n, delta, bodies, spheres, pairs, hist_dt):
    """Applies the force of listed pair p, two plain spheres (``rows`` i and j) of group g
    touching with overlap ``delta`` along n (3-tuple, j -> i), at the middle of the overlap: the
    group's whole law if p is its only listed pair (``single``), else p's share of it
    (``pairs.group_sum`` holds the group's sums). Inlined: its three containers would cost more to
    pass than the force itself. ``single`` is the caller's constant, not re-read from the list:
    with it known, the first pass compiles without the shared-overlap branch, which halved the
    pass's cost per pair (57 -> 27 ns at 1,024 settling spheres, 76 -> 43 ns at 10,140)."""
    i, j = rows
    nx, ny, nz = n
    x, radius, sbody = spheres.x, spheres.radius, spheres.body
    pos, vel, omega, force, torque = bodies.pos, bodies.vel, bodies.omega, bodies.force, bodies.torque
    ba, bb = sbody[i], sbody[j]
    reach = radius[j] - 0.5 * delta
    cx, cy, cz = x[j, 0] + nx * reach, x[j, 1] + ny * reach, x[j, 2] + nz * reach
    rax, ray, raz = cx - pos[ba, 0], cy - pos[ba, 1], cz - pos[ba, 2]
    rbx, rby, rbz = cx - pos[bb, 0], cy - pos[bb, 1], cz - pos[bb, 2]
    vax, vay, vaz = _point_velocity(vel, omega, ba, rax, ray, raz)
    vbx, vby, vbz = _point_velocity(vel, omega, bb, rbx, rby, rbz)
    law = _group_law(pairs.group_law, g)
    v = (vax - vbx, vay - vby, vaz - vbz)
    f_n, f_pair, weight = _contact_normal_force(pairs.group_sum, g, single, delta, v, n, law)
    fx, fy, fz = sphere_contact_force(n, f_n, f_pair, v, weight, law, pairs.hist, p, hist_dt)
    _push(force, torque, ba, fx, fy, fz, rax, ray, raz)
    _push(force, torque, bb, -fx, -fy, -fz, rbx, rby, rbz)


@numba.njit(inline="always", **JIT_FLAGS)
def _row(table, i):
    """Row i of an (n, 3) table as a 3-tuple: a body's centre, velocity or spin, a sphere row's
    crown (``dem/crown.py``)."""
    return table[i, 0], table[i, 1], table[i, 2]


@numba.njit(inline="always", **JIT_FLAGS)
def _wall_approach_rate(bodies, b, wall_v, point, delta, n):
    """d(delta)/dt of body b's wall contact of overlap ``delta`` and normal n (3-tuple, facet ->
    body) whose facet point is ``point`` (row of ``wall_pairs.point``; the force acts half the
    overlap inside, as in ``_wall_forces``), against a wall moving with ``wall_v``."""
    pos = bodies.pos
    cx = point[0] - 0.5 * delta * n[0]
    cy = point[1] - 0.5 * delta * n[1]
    cz = point[2] - 0.5 * delta * n[2]
    vx, vy, vz = _point_velocity(bodies.vel, bodies.omega, b, cx - pos[b, 0], cy - pos[b, 1], cz - pos[b, 2])
    return -((vx - wall_v[0]) * n[0] + (vy - wall_v[1]) * n[1] + (vz - wall_v[2]) * n[2])


@numba.njit(inline="always", **JIT_FLAGS)
def _write_facet_contact(wall_pairs, p, delta, n, point):
    """Writes a touching piece-facet pair's overlap, normal (facet -> piece) and the patch centre
    on the facet, half the overlap outside the point where the force acts (``point``)."""
    wall_pairs.delta[p] = delta
    wall_pairs.normal[p, 0], wall_pairs.normal[p, 1], wall_pairs.normal[p, 2] = n
    for k in range(3):
        wall_pairs.point[p, k] = point[k] + 0.5 * delta * n[k]


@numba.njit(inline="always", **JIT_FLAGS)
def _facet_pair_geometry(p, bodies, spheres, walls, wall_pairs, lim, tri_flat, step):
    """Listed sphere-facet pair p's overlap, normal and contact point (``wall_pairs.delta``,
    ``normal``, ``point``, ``keep`` for a face contact), its spring cleared when apart. Returns
    (it touches, offending body or -1)."""
    x, radius, sbody = spheres.x, spheres.radius, spheres.body
    active, pos = bodies.active, bodies.pos
    facets, wall_disp = walls.facets, walls.disp
    f_wall = facets.wall
    wp_i, wp_f, wp_hist = wall_pairs.i, wall_pairs.f, wall_pairs.hist
    wp_delta, wp_n, wp_cp, wp_keep = wall_pairs.delta, wall_pairs.normal, wall_pairs.point, wall_pairs.keep
    i, f = wp_i[p], wp_f[p]
    wp_delta[p] = -1.0
    wp_keep[p] = False
    w = f_wall[f]
    apart = not active[sbody[i]]
    if not apart:
        s = plane_distance(
            x[i, 0], x[i, 1], x[i, 2], facets, f, wall_disp[w, 0], wall_disp[w, 1], wall_disp[w, 2]
        )
        apart = s * s >= radius[i] * radius[i] * PLANE_SLACK
    if not apart and spheres.core_count[i] > 0:
        # The piece's box against the facet's plane first (``facet_geometry``'s first test
        # on the core's vertices, for less).
        nx, ny, nz = facets.normal[f, 0], facets.normal[f, 1], facets.normal[f, 2]
        plane = facets.offset[f] + nx * wall_disp[w, 0] + ny * wall_disp[w, 1] + nz * wall_disp[w, 2]
        low, high = box_extent(x, spheres.half, bodies.rot, i, sbody[i], nx, ny, nz)
        reach = spheres.rounding[i] * BOX_SLACK
        apart = low - plane > reach or plane - high > reach
    if not apart and spheres.core_count[i] > 0:
        b = sbody[i]
        # A lasting contact whose body has not moved relative to the wall is served from its
        # last full evaluation (``dem/kept_contact.py``: A the wall, B the piece, so the kept
        # direction is the facet's normal turned round): a resting pile on the tray's floor.
        frame_b = body_frame(bodies.rot, b)
        origin_a, origin_b = _row(wall_disp, w), _row(pos, b)
        key = (i + 1.0, f + 1.0)
        served, delta, nx, ny, nz, cx, cy, cz = kept_contact(
            wall_pairs.kept, p, key, WALL_FRAME, origin_a, frame_b, origin_b
        )
        if served and delta > 0.0:
            if delta > lim * spheres.rounding[i]:
                return False, b
            _write_facet_contact(wall_pairs, p, delta, (-nx, -ny, -nz), (cx, cy, cz))
            for k in range(3):
                wall_pairs.moment[p, k] = wall_pairs.kept[p, K_M + k]
            wp_keep[p] = wall_pairs.kept[p, K_FACE] != 0.0
            return True, -1
        apart = served  # kept apart
        core = place_body(spheres.core_start[i], spheres.core_count[i], bodies.rot, pos, b)
        # The pair's cached direction (the facet's closest points to the core when its triangles
        # were last taken one by one, ``facet_geometry``): the piece's box, then its core, further
        # from the facet's vertices along it than the rounding means the pair is apart, the
        # answer the geometry would give (the crowned distance is at least the cores' distance),
        # without the triangles' GJK queries: a piece over a facet's boundary or beyond a wall's
        # end in the shaking. A pair that touched at the last step (its spring set) would not
        # pass; it skips the test.
        sx, sy, sz = wall_pairs.axis[p, 0], wall_pairs.axis[p, 1], wall_pairs.axis[p, 2]
        if (not apart and (sx != 0.0 or sy != 0.0 or sz != 0.0)) and (
            wp_hist[p, 0] == 0.0 and wp_hist[p, 1] == 0.0 and wp_hist[p, 2] == 0.0
        ):
            apart = facet_axis_clears(
                x,
                spheres.half,
                bodies.rot,
                i,
                b,
                spheres.core,
                core,
                spheres.rounding[i] * FACET_AXIS_SLACK,
                tri_flat,
                facets.tri_start[f],
                facets.tri_count[f],
                _row(wall_disp, w),
                sx,
                sy,
                sz,
            )
        if not apart:
            normal = facets.normal
            facet = WallFacet(
                facets.tri_start[f],
                facets.tri_count[f],
                _row(wall_disp, w),
                (normal[f, 0], normal[f, 1], normal[f, 2]),
                facets.offset[f],
            )
            delta, dist, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face = facet_geometry(
                spheres.core,
                core,
                spheres.rounding[i],
                _row(spheres.crown, i),
                tri_flat,
                facet,
                spheres.work,
                wall_pairs.axis[p],
            )
            # Kept for the next steps if the piece moves slowly enough for it to be served (as
            # for piece pairs).
            reach = spheres.reach[i]
            still = delta != 0.0 and not moves_beyond(
                wall_pairs.kept,
                p,
                step,
                _row(walls.vel, w),
                (0.0, 0.0, 0.0),
                origin_a,
                _row(bodies.vel, b),
                _row(bodies.omega, b),
                origin_b,
                reach,
                delta,
            )
            if delta > 0.0:
                if dist == 0.0 or delta > lim * spheres.rounding[i]:
                    return False, b
                wp_delta[p] = delta
                wp_n[p, 0], wp_n[p, 1], wp_n[p, 2] = nx, ny, nz
                # The patch centre on the facet (the mid-plane point moved back by d / 2).
                wp_cp[p, 0] = cx - 0.5 * dist * nx
                wp_cp[p, 1] = cy - 0.5 * dist * ny
                wp_cp[p, 2] = cz - 0.5 * dist * nz
                wall_pairs.moment[p, 0], wall_pairs.moment[p, 1], wall_pairs.moment[p, 2] = s_uu, s_uw, s_ww
                wp_keep[p] = is_face
                if still:
                    # The force acts half the overlap inside the patch centre (``_wall_forces``).
                    point = (
                        wp_cp[p, 0] - 0.5 * delta * nx,
                        wp_cp[p, 1] - 0.5 * delta * ny,
                        wp_cp[p, 2] - 0.5 * delta * nz,
                    )
                    keep_contact(
                        wall_pairs.kept,
                        p,
                        key,
                        reach,
                        WALL_FRAME,
                        origin_a,
                        frame_b,
                        origin_b,
                        delta,
                        (-nx, -ny, -nz),
                        point,
                        (s_uu, s_uw, s_ww),
                        (0.0, crown_radius(_row(spheres.crown, i))),
                    )
                    wall_pairs.kept[p, K_FACE] = 1.0 if is_face else 0.0
                return True, -1
            if still:
                keep_apart(wall_pairs.kept, p, key, reach, WALL_FRAME, origin_a, frame_b, origin_b, delta)
            apart = True
    if not apart:
        d2, cx, cy, cz, is_face = closest_point_on_facet(
            x[i, 0], x[i, 1], x[i, 2], facets, f, wall_disp[w, 0], wall_disp[w, 1], wall_disp[w, 2]
        )
        if d2 < radius[i] * radius[i]:
            d = math.sqrt(d2)
            delta = radius[i] - d
            if delta > lim * radius[i] or d == 0.0:
                return False, sbody[i]
            wp_delta[p] = delta
            wp_n[p, 0] = (x[i, 0] - cx) / d
            wp_n[p, 1] = (x[i, 1] - cy) / d
            wp_n[p, 2] = (x[i, 2] - cz) / d
            wp_cp[p, 0], wp_cp[p, 1], wp_cp[p, 2] = cx, cy, cz
            wp_keep[p] = is_face  # face contacts always count; edge/vertex ones are checked next
            return True, -1
    # Only a spring that held something is reset: untouched memory stays clean.
    if wp_hist[p, 0] != 0.0 or wp_hist[p, 1] != 0.0 or wp_hist[p, 2] != 0.0:
        wp_hist[p, 0] = wp_hist[p, 1] = wp_hist[p, 2] = 0.0
    return False, -1


@numba.njit(inline="always", **JIT_FLAGS)
def _wall_forces(bodies, spheres, material, walls, lists, lim, hist_dt):
    """Sphere-facet contacts: geometry, then the edge/vertex rule, then per body the overlap sum
    of each facet, then forces with the law of the body's and the wall's materials. Returns
    (contacts carrying force, offending body or -1).

    The geometry pass lists the touching pairs (``wall_pairs.touching``, in list order) and
    clears the springs of the others; the rule and the forces run over that list only: most
    listed pairs of a moving wall (found with twice its amplitude as margin) do not touch. Of a
    body's pairs that hold several of its spheres (a clump's), it examines only those whose gap
    at the build the body's move (``Grid.moved2``) and the walls' largest travel
    (``Grid.wall_moved2``) since then could have closed, as the sphere-pair scan does: in the
    shaken feeder 12 of 297 listed pairs touch and 136 could (``benchmarks/README.md``, engine
    speed session 11)."""
    radius, sbody = spheres.radius, spheres.body
    mass, diameter = bodies.mass, bodies.diameter
    pos, vel, omega, force, torque = bodies.pos, bodies.vel, bodies.omega, bodies.force, bodies.torque
    facets, wall_disp, wall_vel, wall_mat, facet_sum = (
        walls.facets,
        walls.disp,
        walls.vel,
        walls.material,
        walls.facet_sum,
    )
    f_wall = facets.wall
    wall_pairs, moved2, wall_moved2 = lists.wall_pairs, lists.grid.moved2, lists.grid.wall_moved2
    wp_i, wp_f, wp_hist = wall_pairs.i, wall_pairs.f, wall_pairs.hist
    wp_delta, wp_n, wp_cp, wp_keep = wall_pairs.delta, wall_pairs.normal, wall_pairs.point, wall_pairs.keep
    touching, walk, gap = wall_pairs.touching, wall_pairs.walk, wall_pairs.gap
    n_contacts = 0
    n_touch = 0
    tri_flat = facets.tri.reshape((-1, 3))
    wall_travel2 = 0.0
    for w in range(wall_moved2.shape[0]):
        wall_travel2 = max(wall_travel2, wall_moved2[w])
    wall_travel = math.sqrt(wall_travel2)
    # A pair of a body's run of several spheres (``walk``) farther apart at the build than the
    # body's and the walls' moves since is still apart, with the build's overlap -1 and no
    # spring: it is passed over. The moves only grow until the next build, so a pair once
    # examined is examined at every step until then. A test in list order, not a walk by gap as
    # for sphere pairs: putting the visited pairs back in list order cost more than it saved
    # (the feeder's pass 2.5 -> 3.7 us; 2.0 us tested in order).
    p_lone = 0
    for g in range(wall_pairs.count[N_WALKS] + 1):
        p_first, p_end = walk[g, 0], walk[g, 1]
        for p in range(p_lone, p_first):
            hit, bad = _facet_pair_geometry(p, bodies, spheres, walls, wall_pairs, lim, tri_flat, hist_dt)
            if bad >= 0:
                return 0, bad
            touching[n_touch] = p
            n_touch += hit
        p_lone = p_end
        if p_first == p_end:
            continue
        closable = math.sqrt(moved2[sbody[wp_i[p_first]]]) + wall_travel
        for p in range(p_first, p_end):
            if gap[p] > closable:
                continue
            hit, bad = _facet_pair_geometry(p, bodies, spheres, walls, wall_pairs, lim, tri_flat, hist_dt)
            if bad >= 0:
                return 0, bad
            touching[n_touch] = p
            n_touch += hit
    # Edge/vertex contacts (keep False, delta > 0): keep unless their point lies on another
    # touched facet of the same wall that is at least as close (see dem/walls.py).
    t = 0
    while t < n_touch:
        t_end = t
        while t_end < n_touch and wp_i[touching[t_end]] == wp_i[touching[t]]:
            t_end += 1
        i = wp_i[touching[t]]
        tol = 1e-9 + 1e-6 * radius[i]
        for ta in range(t, t_end):
            a = touching[ta]
            if wp_keep[a]:
                continue
            dup = False
            for tc in range(t, t_end):
                c = touching[tc]
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
                    facets,
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
        for ta in range(t, t_end):
            a = touching[ta]
            wp_keep[a] = wp_delta[a] > 0.0
            if not wp_keep[a]:
                wp_hist[a, 0] = wp_hist[a, 1] = wp_hist[a, 2] = 0.0
        t = t_end

    # The law's constants depend on the body's and the wall's materials and the body's size and
    # mass only: computed when these change from one contact to the next (two square roots).
    law_mb = law_mw = -1
    law_d = law_m = -1.0
    law = PairLaw(0.0, 0.0, 0.0, 0.0, 0.0)
    t = 0
    while t < n_touch:
        b = sbody[wp_i[touching[t]]]
        t_end = t
        while t_end < n_touch and sbody[wp_i[touching[t_end]]] == b:
            t_end += 1
        # One sphere's pairs have distinct facets: each facet's group is that one contact, which
        # carries the whole law (``_contact_normal_force``), so its sums are not needed.
        single = wp_i[touching[t]] == wp_i[touching[t_end - 1]]
        if not single:
            for ta in range(t, t_end):
                for k in range(N_SUMS):
                    facet_sum[wp_f[touching[ta]], k] = 0.0
            for ta in range(t, t_end):
                a = touching[ta]
                if wp_keep[a]:
                    nx, ny, nz = wp_n[a, 0], wp_n[a, 1], wp_n[a, 2]
                    w_v = wall_vel[f_wall[wp_f[a]]]
                    rate = _wall_approach_rate(bodies, b, w_v, wp_cp[a], wp_delta[a], (nx, ny, nz))
                    _add_sums(facet_sum, wp_f[a], wp_delta[a], rate)
        for ta in range(t, t_end):
            a = touching[ta]
            if not wp_keep[a]:
                continue
            f = wp_f[a]
            w = f_wall[f]
            mb, mw = bodies.material[b], wall_mat[w]
            if mb != law_mb or mw != law_mw or diameter[b] != law_d or mass[b] != law_m:
                e_b, e_w = material.E[mb], material.E[mw]
                law = pair_law(diameter[b] * e_b * e_w / (e_b + e_w), mass[b], material.law[mb, mw])
                law_mb, law_mw, law_d, law_m = mb, mw, diameter[b], mass[b]
            delta = wp_delta[a]
            nx, ny, nz = wp_n[a, 0], wp_n[a, 1], wp_n[a, 2]
            cx = wp_cp[a, 0] - 0.5 * delta * nx
            cy = wp_cp[a, 1] - 0.5 * delta * ny
            cz = wp_cp[a, 2] - 0.5 * delta * nz
            rax, ray, raz = cx - pos[b, 0], cy - pos[b, 1], cz - pos[b, 2]
            vbx, vby, vbz = _point_velocity(vel, omega, b, rax, ray, raz)
            v = (vbx - wall_vel[w, 0], vby - wall_vel[w, 1], vbz - wall_vel[w, 2])
            # ``single`` passed as a constant: the lone contact's law compiles without the
            # shared-overlap branch (as in ``_sphere_pair_force``).
            if single:
                f_n, f_pair, weight = _contact_normal_force(facet_sum, f, True, delta, v, (nx, ny, nz), law)
            else:
                f_n, f_pair, weight = _contact_normal_force(facet_sum, f, False, delta, v, (nx, ny, nz), law)
            fx, fy, fz = sphere_contact_force((nx, ny, nz), f_n, f_pair, v, weight, law, wp_hist, a, hist_dt)
            _push(force, torque, b, fx, fy, fz, rax, ray, raz)
            if spheres.core_count[wp_i[a]] > 0:
                moment = (wall_pairs.moment[a, 0], wall_pairs.moment[a, 1], wall_pairs.moment[a, 2])
                spin = _row(omega, b)
                tx, ty, tz = patch_damping(
                    (nx, ny, nz), moment, spin, weight * law.c_n, weight * law.c_t, law.mu * weight * f_pair
                )
                _twist(torque, b, tx, ty, tz)
            n_contacts += 1
        t = t_end
    return n_contacts, -1
