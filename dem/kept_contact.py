r"""A lasting contact of rounded pieces kept from its last evaluation while the pair has not moved
(a persistent contact, as Bullet's manifold keeps its points), and a pair kept apart: the geometry of
``dem.rounded_contact`` costs about a microsecond a touching pair, and in a resting pile (the
feeder's 30 items between insertion and vibration, 50 touching pairs) it gives the same answer
step after step.

At a full evaluation the pair's relative pose q0 (B's position and rotation in A's frame) is kept
with the result in the bodies' frames: the overlap delta0, the force direction e (in A's frame),
the contact point c as a point of A and as a point of B, and the patch's moments. While the pose
q has moved so little that every material point of B within ``reach`` of its centre has moved by
at most

    Delta = |p(q) - p(q0)| + reach ||R(q) - R(q0)||_F  <=  KEEP_FRACTION * delta0

relative to A, the contact is the two surfaces' osculating spheres at c: a crowned piece's of
radius R = 1 / (2 kappa) (``dem.crown.crown_radius``) about the centre C = c + R e (A) or c - R e
(B), fixed in its body. A side without a crown has R = 0: B is then its point c; A (a wall, or
a plain sphere as before) the plane through c across e, turned with it. Two pieces, and A's
plane with B's sphere:

    delta(q) = delta0 + R_a + R_b - |C_a(q) - C_b(q)|,    delta(q) = delta0 + e . (C_b(q) - c_A) + R_b,

the force along C_a - C_b (along e) acting where that line meets B's sphere. That is a function
of the relative pose, so the force it gives is exactly conservative and conserves linear and
angular momentum, and its value and first derivatives at q0 are the full geometry's (e is the
gradient of the crowned distance, ``dem.crown``; the line of the centres passes through c along
e). Why spheres and not B's point on A's plane (session 21): a face resting on a face is held
in its tilt by the crown's rolling, its contact moving by R per unit of tilt (about 2 m on a
phone); a point fixed in the body lacks that stiffness, and each refresh started a new
linearisation, so a box resting on a box kept rocking at 1e-6 to 1e-4 rad/s, in a cycle the
kept rows fed. The spheres carry the rolling to second order and the box comes to rest (1e-14
rad/s, as without kept rows; ``benchmarks/README.md``, session 23). At an edge or a corner,
whose core is sharp, the crown's sphere adds a rolling of the same second order.

The bound: the crowned distance is a minimum over pairs of points fixed in the bodies of a
1-Lipschitz function of their positions, so it moves by at most Delta; C_b lies within reach +
R_b of B's centre, so the kept overlap moves by at most Delta + R_b ||R(q) - R(q0)||_F, and the
two differ by at most their sum (the error is second order in the motion, far less in practice:
at most 2e-6 of the overlap in the feeder's resting pile). A pair that moves more (any
collision: 0.1 m/s is 3 um a step) is evaluated in full every step, as before; its row is not
even written when the bodies' velocities say the next step would not be served either
(``moves_beyond``), so the shaken feeder pays a comparison a contact. Nothing is served with
``KEEP_FRACTION = 0``, and the results are then those of the full geometry to the bit
(``benchmarks/README.md``, session 21).

A pair found apart is kept the same way, with minus its margin g (the crowned distance less the
roundings, or a lower bound of it from the cheaper tests, ``dem.rounded_contact``) as delta0: it
is apart while the motion is at most ``APART_FRACTION`` g, since the crowned distance moves by at
most the motion. That serves the pairs of a pile whose cores are within the roundings but whose
crowns keep them apart, which otherwise take GJK and the crowned contact every step; the answer,
apart, is the one the full geometry would give.

The kept row is keyed by the pair's two sphere rows, which never change for a piece
(``Simulation.remove_body`` keeps indices), so a row left by another pair after a list rebuild is
told apart, and a row of this pair left from any earlier step is as good as a fresh one if the
pose test passes: the test compares poses, not times. Pure numba, inlined into the force pass.
"""

from __future__ import annotations

import math

import numba

from dem.conf import JIT_FLAGS

# The largest material motion of B relative to A, as a fraction of the kept overlap, that the
# kept geometry serves: its overlap is then within twice this fraction of the full geometry's.
KEEP_FRACTION = 1e-3

# A pair found apart by a margin g (a lower bound of its crowned distance less the roundings) is
# served as apart while B moves relative to A by at most this fraction of g: the crowned distance
# moves by at most the motion, and the half left covers the geometry's pairing of its minimiser
# along the GJK normal (``dem.crown``), which is not the exact minimum.
APART_FRACTION = 0.5

# Columns of a kept row (``SpherePairs.kept``).
K_I, K_J, K_DELTA, K_REACH = 0, 1, 2, 3  # sphere rows (+1; 0: empty), delta0, the reach it was kept with
K_P = 4  # B's centre in A's frame (3)
K_R = 7  # R_a^T R_b, row-major (9)
K_E = 16  # force direction in A's frame (3)
K_CA = 19  # A's sphere centre (the contact point where R_a = 0) in A's frame (3)
K_CB = 22  # B's sphere centre (the contact point where R_b = 0) in B's frame (3)
K_M = 25  # patch moments (3)
K_FACE = 28  # a wall contact's ``is_face`` (1.0 or 0.0; dem.rounded_contact.facet_geometry)
K_RA, K_RB = 29, 30  # the osculating spheres' radii R_a, R_b
KEPT = 31


@numba.njit(inline="always", **JIT_FLAGS)
def body_frame(rot, b):
    """Body b's rotation as a row-major 9-tuple (the frames' argument below)."""
    return (
        rot[b, 0, 0], rot[b, 0, 1], rot[b, 0, 2],
        rot[b, 1, 0], rot[b, 1, 1], rot[b, 1, 2],
        rot[b, 2, 0], rot[b, 2, 1], rot[b, 2, 2],
    )  # fmt: skip


WALL_FRAME = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)  # walls translate, never turn


@numba.njit(inline="always", **JIT_FLAGS)
def _into(r, x, y, z):
    """R^T (x, y, z): a world vector in the frame R (row-major 9-tuple)."""
    return (
        r[0] * x + r[3] * y + r[6] * z,
        r[1] * x + r[4] * y + r[7] * z,
        r[2] * x + r[5] * y + r[8] * z,
    )


@numba.njit(inline="always", **JIT_FLAGS)
def _out_of(r, x, y, z):
    """R (x, y, z): a vector of the frame R in the world."""
    return (
        r[0] * x + r[1] * y + r[2] * z,
        r[3] * x + r[4] * y + r[5] * z,
        r[6] * x + r[7] * y + r[8] * z,
    )


@numba.njit(inline="always", **JIT_FLAGS)
def _allowed(delta0):
    """How far B may move relative to A while row's result (overlap delta0 > 0, or apart by
    -delta0 > 0) is served; 0 for an empty row."""
    if delta0 > 0.0:
        return KEEP_FRACTION * delta0
    return -APART_FRACTION * delta0


@numba.njit(inline="always", **JIT_FLAGS)
def _turn(ra, rb, k):
    """Entry k (row-major) of R_a^T R_b: B's rotation in A's frame."""
    r, c = k // 3, k % 3
    return ra[r] * rb[c] + ra[3 + r] * rb[3 + c] + ra[6 + r] * rb[6 + c]


@numba.njit(inline="always", **JIT_FLAGS)
def _shift(ra, origin_a, origin_b):
    """B's centre in A's frame."""
    return _into(ra, origin_b[0] - origin_a[0], origin_b[1] - origin_a[1], origin_b[2] - origin_a[2])


@numba.njit(inline="always", **JIT_FLAGS)
def keep_apart(kept, p, key, reach, frame_a, origin_a, frame_b, origin_b, delta):
    """Row p of ``kept`` := its key, overlap ``delta`` (or minus a lower bound of the margin of a
    pair found apart: the crowned distance less the roundings), reach and the relative pose of
    A and B (as ``keep_contact``): all a pair kept apart needs."""
    kept[p, K_I], kept[p, K_J], kept[p, K_DELTA], kept[p, K_REACH] = key[0], key[1], delta, reach
    px, py, pz = _shift(frame_a, origin_a, origin_b)
    kept[p, K_P], kept[p, K_P + 1], kept[p, K_P + 2] = px, py, pz
    for k in range(9):
        kept[p, K_R + k] = _turn(frame_a, frame_b, k)


@numba.njit(inline="always", **JIT_FLAGS)
def keep_contact(kept, p, key, reach, frame_a, origin_a, frame_b, origin_b, delta, n, point, moment, radii):
    """Row p of ``kept`` := the contact just evaluated in full between A (rotation ``frame_a``,
    a row-major 9-tuple, and centre ``origin_a``) and B: overlap ``delta``, force direction n
    (B -> A), contact point and patch moments (3-tuples), with the relative pose; ``key`` (two
    numbers) names the pair, ``reach`` bounds B's material points that matter (its core and
    roundings) about ``origin_b``; ``radii`` = (R_a, R_b) of the osculating spheres (the module's
    docstring; R_a 0 for a wall)."""
    keep_apart(kept, p, key, reach, frame_a, origin_a, frame_b, origin_b, delta)
    ra, rb = frame_a, frame_b
    nx, ny, nz = n
    ex, ey, ez = _into(ra, nx, ny, nz)
    kept[p, K_E], kept[p, K_E + 1], kept[p, K_E + 2] = ex, ey, ez
    r_a, r_b = radii
    kept[p, K_RA], kept[p, K_RB] = r_a, r_b
    cx, cy, cz = point[0] + r_a * nx, point[1] + r_a * ny, point[2] + r_a * nz
    ax, ay, az = _into(ra, cx - origin_a[0], cy - origin_a[1], cz - origin_a[2])
    kept[p, K_CA], kept[p, K_CA + 1], kept[p, K_CA + 2] = ax, ay, az
    cx, cy, cz = point[0] - r_b * nx, point[1] - r_b * ny, point[2] - r_b * nz
    bx, by, bz = _into(rb, cx - origin_b[0], cy - origin_b[1], cz - origin_b[2])
    kept[p, K_CB], kept[p, K_CB + 1], kept[p, K_CB + 2] = bx, by, bz
    kept[p, K_M], kept[p, K_M + 1], kept[p, K_M + 2] = moment[0], moment[1], moment[2]


@numba.njit(inline="always", **JIT_FLAGS)
def kept_contact(kept, p, key, frame_a, origin_a, frame_b, origin_b):
    """(served, delta, nx, ny, nz, cx, cy, cz): the contact of A and B (as ``keep_contact``) from
    row p of ``kept`` if the row is theirs (``key``) and their relative pose lies within the
    bound of the module's docstring; delta < 0 (the rest zero) for a pair kept apart. Else served
    is False and the rest is zero."""
    delta0 = kept[p, K_DELTA]
    if not (delta0 != 0.0 and kept[p, K_I] == key[0] and kept[p, K_J] == key[1]):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ra, rb = frame_a, frame_b
    px, py, pz = _shift(ra, origin_a, origin_b)
    moved = math.sqrt((px - kept[p, K_P]) ** 2 + (py - kept[p, K_P + 1]) ** 2 + (pz - kept[p, K_P + 2]) ** 2)
    allowed = _allowed(delta0)
    if moved > allowed:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    turned2 = 0.0
    for k in range(9):
        turned2 += (_turn(ra, rb, k) - kept[p, K_R + k]) ** 2
    if moved + kept[p, K_REACH] * math.sqrt(turned2) > allowed:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if delta0 < 0.0:
        return True, delta0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ax, ay, az = _out_of(ra, kept[p, K_CA], kept[p, K_CA + 1], kept[p, K_CA + 2])
    bx, by, bz = _out_of(rb, kept[p, K_CB], kept[p, K_CB + 1], kept[p, K_CB + 2])
    ax, ay, az = ax + origin_a[0], ay + origin_a[1], az + origin_a[2]
    bx, by, bz = bx + origin_b[0], by + origin_b[1], bz + origin_b[2]
    r_a, r_b = kept[p, K_RA], kept[p, K_RB]
    if r_a > 0.0:  # two spheres (B's may be a point)
        vx, vy, vz = ax - bx, ay - by, az - bz
        length = math.sqrt(vx * vx + vy * vy + vz * vz)
        nx, ny, nz = vx / length, vy / length, vz / length
        delta = delta0 + r_a + r_b - length
    else:  # A's plane, B's sphere (or point): the kept direction turned with A
        nx, ny, nz = _out_of(ra, kept[p, K_E], kept[p, K_E + 1], kept[p, K_E + 2])
        delta = delta0 + nx * (bx - ax) + ny * (by - ay) + nz * (bz - az) + r_b
    return True, delta, nx, ny, nz, bx + r_b * nx, by + r_b * ny, bz + r_b * nz


@numba.njit(inline="always", **JIT_FLAGS)
def moves_beyond(kept, p, step, vel_a, omega_a, origin_a, vel_b, omega_b, origin_b, reach, delta):
    """Whether B's material points (within ``reach`` of ``origin_b``) move relative to A by more
    than a row of ``delta`` would serve (``_allowed``) in one step of ``step``
    seconds at the bodies' velocities and spins (3-tuples): then the next step would not be served
    either, and row p is emptied instead of written (a collision's or the shaking's contacts pay
    one comparison a step, not a kept row's writing). A cost decision only: whether a row is
    served is decided by its pose test. ``step`` 0 (forces re-evaluated) never keeps."""
    if step == 0.0:
        kept[p, K_DELTA] = 0.0
        return True
    rx, ry, rz = origin_b[0] - origin_a[0], origin_b[1] - origin_a[1], origin_b[2] - origin_a[2]
    # d/dt of B's centre in A's frame, and B's spin relative to A
    vx = vel_b[0] - vel_a[0] - (omega_a[1] * rz - omega_a[2] * ry)
    vy = vel_b[1] - vel_a[1] - (omega_a[2] * rx - omega_a[0] * rz)
    vz = vel_b[2] - vel_a[2] - (omega_a[0] * ry - omega_a[1] * rx)
    wx, wy, wz = omega_b[0] - omega_a[0], omega_b[1] - omega_a[1], omega_b[2] - omega_a[2]
    speed = math.sqrt(vx * vx + vy * vy + vz * vz) + reach * math.sqrt(wx * wx + wy * wy + wz * wz)
    if speed * step > _allowed(delta):
        kept[p, K_DELTA] = 0.0
        return True
    return False
