r"""The contact law: every formula that turns an overlap into a force lives here, once.

Notation of the paper (Kawamura et al., Mater. Trans. 62 (2021) 551, eq. 1-2): E Young's modulus,
nu Poisson's ratio, e restitution coefficient, mu friction coefficient, D contact diameter,
S_n overlap (here ``delta``), m mass.

Normal force (paper eq. 1, linear spring-dashpot, Cundall & Strack 1979)::

    F_n = K delta + C d(delta)/dt,   F_n >= 0 (never attractive)

* Body stiffness ``k_i = E_i D_i``; two bodies in contact combine in series,
  ``K = k_a k_b / (k_a + k_b)``, so two identical spheres of diameter D give ``K = E D / 2``
  exactly as in eq. 1.
* Walls have no size of their own: a wall is the mirror image of the body that touches it
  (contact size = the body's ``D``) with the wall's own E, so ``K_wall = D E_b E_w / (E_b + E_w)``,
  which for the same material is the stiffness of two identical bodies, ``E D / 2``.
* Damping ``C = 2 zeta sqrt(K m*)`` with ``m* = m_a m_b / (m_a + m_b)`` (``m*`` = the body's mass
  against a wall). For two identical spheres this is the paper's ``eta sqrt(m E D)`` term.
  Without the no-attraction clamp the damping ratio giving restitution e is
  ``eta = -ln e / sqrt(pi^2 + ln^2 e)`` (Tsuji et al. 1992). With the clamp the body leaves the
  contact when the force (not the overlap) reaches zero, which raises the realised restitution
  (e = 0.1 would rebound with 0.25). ``damping_ratio(e)`` therefore solves
  ``restitution_with_clamp(zeta) = e`` on the closed-form solution of the damped oscillator
  (Schwager & Poeschel, Phys. Rev. E 75 (2007) 051304); below e = 0.135 this needs zeta > 1.

Tangential force (paper eq. 2 plus an elastic stage): an incremental spring with history
(Cundall & Strack 1979). The spring elongation ``xi`` is rotated into the current tangent plane
every step (keeping its length), incremented by ``v_t dt``, and::

    F_t = -K_t xi - C_t v_t,   |F_t| <= mu F_n (Coulomb; on sliding xi is reset to match),
    K_t / K_n = 2 (1 - nu) / (2 - nu)   (Mindlin's ratio; gives nu its physical role),
    C_t = 2 zeta sqrt(K_t m*).

Clumps (the resolution rule). A rigid body touches another body (or one planar wall facet)
through several of its spheres at once. The body's stiffness must not depend on how many spheres
represent it, so ``K`` and ``C`` above belong to the *body pair* (computed from the bodies'
contact diameters ``Clump.equivalent_diameter``), and the pair is one spring-dashpot in one
overlap of the pair, the Lehmer mean of its sphere contacts' overlaps::

    M = sum_k delta_k^3 / sum_k delta_k^2,      U = K M^2 / 2,
    F = K M + C dM/dt  (F >= 0),   f_k = F dM/d(delta_k) = F delta_k (3 delta_k - 2 M) / sum_j delta_j^2

``f_k`` is sphere contact k's normal force. For e = 1 (C = 0) it is exactly ``-dU/d(delta_k)``
and every ``delta_k`` is a function of the two bodies' poses, so the pair's forces and torques
are the gradient of one energy ``U(poses)``: the work done is path-independent and an elastic
collision conserves energy whatever the orientation (a sharing ``K delta_k w_k`` with weights
``w_k = delta_k^4 / sum delta^4``, used before, was not: +1.4 % for two box clumps meeting 1
deg off face-on with staggered rows). The damping is the Rayleigh dissipation ``C (dM/dt)^2 / 2``
of the same coordinate, and the no-attraction clamp acts on the pair's ``F``. A face landing flat
with n equal overlaps has ``M = delta`` and ``dM/d(delta_k) = 1 / n``: it carries ``K delta + C
d(delta)/dt`` in total, for any n, and rebounds with e. A new sphere contact enters with zero
force (``f_k ~ delta_k`` for small ``delta_k``) and zero share of U (``M`` ignores zero overlaps),
so forces and energy stay continuous. The price of exactness: a contact much shallower than the
others (``delta_k < 2 M / 3``) pulls (``f_k < 0``). It must: a resolution-independent energy of
the overlaps whose forces never pull is ``K max(delta)^2 / 2``, all force on the deepest sphere,
jumping between spheres of a flat face. The pull of one contact is at most ``F / 3`` and vanishes as
it enters; the pair's net normal force ``F sum_k dM/d(delta_k)`` could in principle turn negative
(one deep contact among many at a tenth of its depth). For the feeder's 12-sphere items on a
plane, with every overlap within ``OVERLAP_LIMIT`` of its radius, it stays above 0.1 F (0.105 F at
worst, a camera's large sphere at the limit with five small ones shallow; random poses stay above
0.19 F); between two clumps no positive bound holds in every pose (a sphere wedged between two of
the other's): ``tests/dem/test_clump_pair_normal_force.py``. A face resting on a plane
rocks with ``4 K <x^2>`` per radian (independent springs would give ``K <x^2>``).

Friction is shared with the non-negative weights ``w_k = delta_k^2 / sum delta_j^2`` (they sum
to 1): contact k's tangential spring and damper are ``w_k K_t`` and ``w_k C_t`` and its Coulomb
cap ``mu w_k N``, with N = F sum_k dM/d(delta_k) the pair's net normal force where the normals
are parallel (a face on a facet; F itself over-states it when the overlaps differ: a box sliding
down an incline, its front digging in, then slid 4 % too slowly), so the pair's total friction
is ``mu`` times its net normal force.

This module must not know about neighbour lists, bodies or walls: it maps one sphere contact's
kinematics to a force (``dem/forces.py`` applies it to every listed pair).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numba

from dem.conf import JIT_FLAGS
from dem.convex import plane_basis
from dem.parameters import PARAMETER_NAMES, range_problem

# The clamp-corrected damping ratio for e -> 0 grows without bound; past this the contact is a
# pure dashpot for all practical purposes (realised e ~ 1 / (4 zeta^2) = 2.5e-5).
_MAX_DAMPING_RATIO = 100.0


class ContactParamsError(ValueError):
    """A contact parameter is outside its physical range; the message names the field."""


@dataclass(frozen=True)
class ContactParams:
    """A material's contact parameters, the four numbers the calibration searches."""

    E: float  # Young's modulus, Pa
    nu: float  # Poisson's ratio
    e: float  # coefficient of restitution
    mu: float  # Coulomb friction coefficient

    def __post_init__(self) -> None:
        for name in PARAMETER_NAMES:
            problem = range_problem(name, getattr(self, name))
            if problem is not None:
                raise ContactParamsError(problem)

    @property
    def damping_ratio(self) -> float:
        """zeta that makes a binary impact rebound with ``e`` despite the no-attraction clamp."""
        return damping_ratio(self.e)

    @property
    def tangential_ratio(self) -> float:
        """K_t / K_n."""
        return tangential_stiffness_ratio(self.nu)

    def as_dict(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in PARAMETER_NAMES}


def body_stiffness(E: float, D: float) -> float:
    """k_i = E_i D_i: one body's share of the normal stiffness (N/m)."""
    return E * D


def series(k_a: float, k_b: float) -> float:
    """Two springs (or masses) in series: k_a k_b / (k_a + k_b)."""
    return k_a * k_b / (k_a + k_b)


def normal_stiffness(E_a: float, D_a: float, E_b: float, D_b: float) -> float:
    """K of a body pair; E D / 2 for identical bodies (paper eq. 1)."""
    return series(body_stiffness(E_a, D_a), body_stiffness(E_b, D_b))


def wall_stiffness(E_body: float, D_body: float, E_wall: float) -> float:
    """K of a body against a wall: the wall is the body's mirror image made of the wall's E."""
    return normal_stiffness(E_body, D_body, E_wall, D_body)


def tangential_stiffness_ratio(nu: float) -> float:
    """K_t / K_n = 2 (1 - nu) / (2 - nu) (Mindlin)."""
    return 2.0 * (1.0 - nu) / (2.0 - nu)


def damping_ratio_linear(e: float) -> float:
    """eta = -ln e / sqrt(pi^2 + ln^2 e): the ratio for restitution e when forces may attract."""
    if e >= 1.0:
        return 0.0
    log_e = math.log(e)
    return -log_e / math.sqrt(math.pi**2 + log_e**2)


def restitution_with_clamp(zeta: float) -> float:
    """Restitution of a linear spring-dashpot impact that ends when the force reaches zero.

    Closed form of x'' + 2 zeta x' + x = 0, x(0) = 0, x'(0) = 1 (unit frequency and speed): the
    contact ends at t* where x'' = 0 and e = -x'(t*).
    """
    if zeta <= 0.0:
        return 1.0
    if abs(zeta - 1.0) < 1e-7:
        zeta = 1.0 - 1e-7  # the critical case is the continuous limit of both branches
    if zeta < 1.0:
        wd = math.sqrt(1.0 - zeta * zeta)
        phase = math.pi - math.atan2(2.0 * zeta * wd, 1.0 - 2.0 * zeta * zeta)
        return math.exp(-zeta * phase / wd) * (zeta / wd * math.sin(phase) - math.cos(phase))
    root = math.sqrt(zeta * zeta - 1.0)
    r1, r2 = -zeta + root, -zeta - root
    t_end = 2.0 * math.log(r2 / r1) / (r1 - r2)
    return -(r1 * math.exp(r1 * t_end) - r2 * math.exp(r2 * t_end)) / (r1 - r2)


@lru_cache(maxsize=1024)
def damping_ratio(e: float) -> float:
    """zeta with ``restitution_with_clamp(zeta) == e``, by bisection (the map is monotone)."""
    if e >= 1.0:
        return 0.0
    if e <= restitution_with_clamp(_MAX_DAMPING_RATIO):
        return _MAX_DAMPING_RATIO
    lo, hi = 0.0, _MAX_DAMPING_RATIO
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if restitution_with_clamp(mid) > e:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-15 * max(hi, 1.0):
            break
    return 0.5 * (lo + hi)


# Columns of a group's sums in the force pass (``dem/forces.py``): ``share_sums``'s five and the
# number of touching contacts.
N_SUMS = 6


@numba.njit(**JIT_FLAGS)
def share_sums(delta, rate):
    """Sphere contact k's terms of its pair's sums: (delta^3, delta^2, delta^2 d(delta)/dt,
    delta d(delta)/dt, delta), from which ``shared_overlap`` makes M, dM/dt and sum_k dM/d(delta_k)."""
    d2 = delta * delta
    return d2 * delta, d2, d2 * rate, delta * rate, delta


@numba.njit(**JIT_FLAGS)
def shared_overlap(sums):
    """(M, dM/dt, sum_k dM/d(delta_k)) of a body pair from its contacts' summed ``share_sums`` (a
    5-sequence). The last is the pair's net normal force per unit F where the normals are
    parallel (a face on a facet): the Coulomb cap's normal force."""
    m = sums[0] / sums[1]
    return m, (3.0 * sums[2] - 2.0 * m * sums[3]) / sums[1], 3.0 - 2.0 * m * sums[4] / sums[1]


@numba.njit(**JIT_FLAGS)
def contact_share(delta, m, sum_d2):
    """(dM/d(delta_k), w_k): sphere contact k's share of its pair's normal force F (negative for
    a contact shallower than 2 M / 3) and of its tangential law (``delta_k^2 / sum delta^2``)."""
    w = delta * delta / sum_d2
    return w * (3.0 - 2.0 * m / delta), w


@numba.njit(inline="always", **JIT_FLAGS)
def pair_normal_force(overlap, rate, k_n, c_n):
    """F = K delta + C d(delta)/dt of a pair in its overlap coordinate, never attractive."""
    f = k_n * overlap + c_n * rate
    return f if f > 0.0 else 0.0


class PairLaw(NamedTuple):
    """The law's constants of one pair of touching bodies (or a body and a wall): what a contact
    needs of the two materials and sizes, built once per pair (``dem/forces.py``)."""

    k_n: float  # normal stiffness K, N/m
    c_n: float  # normal damping C, N s/m
    k_t: float  # tangential stiffness K_t, N/m
    c_t: float  # tangential damping C_t, N s/m
    mu: float  # friction coefficient of the pair


@numba.njit(inline="always", **JIT_FLAGS)
def sphere_contact_force(n, f_n, f_pair, v, weight, law, hist, h, hist_dt):
    """Force on the first partner of one sphere contact; returns (fx, fy, fz).

    ``n`` (a 3-tuple) points from the second partner to the first, ``f_n`` is the contact's normal force
    (its share of its pair's, ``f_k`` in the module docstring), ``f_pair`` the pair's net normal force
    (the Coulomb cap is ``mu weight f_pair``), ``v`` the first partner's velocity relative to the second
    at the contact point, ``weight`` the contact's share ``w_k`` of the pair's tangential ``law``
    (``PairLaw``). A lone contact has ``f_n = f_pair`` and weight 1. ``hist[h]`` is the tangential spring
    elongation, updated in place with the time increment ``hist_dt`` (0 re-evaluates forces without
    advancing history).
    """
    nx, ny, nz = n
    vx, vy, vz = v
    _, _, k_t, c_t, mu = law
    v_n = vx * nx + vy * ny + vz * nz

    vtx = vx - v_n * nx
    vty = vy - v_n * ny
    vtz = vz - v_n * nz
    # Rotate the stored elongation into the current tangent plane, keeping its length.
    sx = hist[h, 0]
    sy = hist[h, 1]
    sz = hist[h, 2]
    old_len2 = sx * sx + sy * sy + sz * sz
    if old_len2 > 0.0:
        s_n = sx * nx + sy * ny + sz * nz
        sx -= s_n * nx
        sy -= s_n * ny
        sz -= s_n * nz
        new_len2 = sx * sx + sy * sy + sz * sz
        if new_len2 > 0.0:
            scale = math.sqrt(old_len2 / new_len2)
            sx *= scale
            sy *= scale
            sz *= scale
    sx += vtx * hist_dt
    sy += vty * hist_dt
    sz += vtz * hist_dt

    kt = weight * k_t
    ct = weight * c_t
    ftx = -kt * sx - ct * vtx
    fty = -kt * sy - ct * vty
    ftz = -kt * sz - ct * vtz
    ft2 = ftx * ftx + fty * fty + ftz * ftz
    f_max = mu * weight * f_pair
    if ft2 > f_max * f_max:
        if ft2 > 0.0:
            scale = f_max / math.sqrt(ft2)
            ftx *= scale
            fty *= scale
            ftz *= scale
        # Sliding: the spring holds exactly the elongation that the capped force implies.
        if kt > 0.0:
            sx = -(ftx + ct * vtx) / kt
            sy = -(fty + ct * vty) / kt
            sz = -(ftz + ct * vtz) / kt
    hist[h, 0] = sx
    hist[h, 1] = sy
    hist[h, 2] = sz
    return f_n * nx + ftx, f_n * ny + fty, f_n * nz + ftz


@numba.njit(**JIT_FLAGS)
def patch_damping(n, moment, omega, c_n, c_t, max_spin):
    """Torque on the first partner of a face contact from the dampers spread over its patch.

    A rounded polyhedron's face contact is one force at one point (``dem/crown.py``), whose
    normal damper cannot resist rocking or spinning about that
    point. The law's dampers belong to the whole patch (a Winkler foundation): normal dampers of
    total ``c_n`` spread over it resist the relative rocking ``omega`` with ``-c_n M omega``,
    ``M = s_ww u u^T - s_uw (u w^T + w u^T) + s_uu w w^T`` from the patch's second moments per unit
    area (``s_uu = <u^2>`` about the centre, ``plane_basis(n)``), so rocking is damped like the
    normal motion; tangential dampers resist spinning about n with ``-c_t (s_uu + s_ww) omega_n``,
    capped at ``max_spin sqrt(s_uu + s_ww)`` (Coulomb: ``mu F_n`` times the patch's radius of
    gyration). ``n``, ``moment = (s_uu, s_uw, s_ww)`` and the relative spin ``omega`` are
    3-tuples. Only dissipates; zero for a point contact (all moments 0).
    """
    nx, ny, nz = n
    s_uu, s_uw, s_ww = moment
    wx, wy, wz = omega
    ux, uy, uz, vx, vy, vz = plane_basis(nx, ny, nz)
    om_u = ux * wx + uy * wy + uz * wz
    om_w = vx * wx + vy * wy + vz * wz
    om_n = nx * wx + ny * wy + nz * wz
    t_u = -c_n * (s_ww * om_u - s_uw * om_w)
    t_w = -c_n * (s_uu * om_w - s_uw * om_u)
    polar = s_uu + s_ww
    t_n = -c_t * polar * om_n
    cap = max_spin * math.sqrt(max(polar, 0.0))
    if t_n > cap:
        t_n = cap
    elif t_n < -cap:
        t_n = -cap
    return (
        t_u * ux + t_w * vx + t_n * nx,
        t_u * uy + t_w * vy + t_n * ny,
        t_u * uz + t_w * vz + t_n * nz,
    )
