r"""The crowned contact point of two rounded shapes: where one force of ``K delta`` must act for
the contact to be conservative, also when two faces are (nearly) parallel.

The overlap of two rounded shapes is ``delta = r_a + r_b - D`` with D the crowned distance of
their cores (``benchmarks/README.md``, "crowned cores")::

    D = min over core points x of A, y of B of  |x - y| + phi_a(x) + phi_b(y),
    phi(x) = kappa (|x - p|^2 - h^2),   kappa = 1 / (2 R)

with p the body's centre of mass and h its distance from the nearest face plane of the piece's
core, so phi >= 0 on the core and vanishes at the foot of the centre on that face (a body resting
on it overlaps by m g / K exactly). phi is fixed in the body, so by the envelope theorem the
gradient of ``U = K delta^2 / 2`` is the force ``K delta`` along x* - y* acting at the minimiser
(x*, y*): the law is conservative. The crown makes every face strictly convex, so the minimiser
is unique and moves continuously across a face as it tilts (over tilts of about 8 eps / w, eps =
the crown's height at the face's edge, w its width) instead of jumping between its corners; a
resting face has the rocking stiffness of a rocker of radius R. ``dem/polyhedra.py`` chooses R.

The minimiser is sought on the features of both cores within ``tol`` of their supporting planes
across the GJK normal n (the faces, edges or corners that can hold it), with x and y paired
along n: the gap is linear on each feature (its plane, fitted to its vertices), phi quadratic,
so the problem is a two-dimensional convex quadratic program on the overlap of the features'
projections (the free minimum if inside, else the best point of its edges). Pairing along n
instead of the closest pair is exact where the features are parallel and off by the crown's
slope times the gap elsewhere. Pure numba, no allocation (the scratch of ``dem.convex``).
"""

from __future__ import annotations

import math

import numba

from dem.conf import JIT_FLAGS, STEP_FLAGS
from dem.convex import _clip, _copy_row, _parallel_segments, feature_hulls, plane_basis, support


@numba.njit(inline="always", **JIT_FLAGS)
def crown_radius(crown):
    """R = 1 / (2 kappa) of a crown (the radius of the sphere its face osculates where the
    minimiser lies inside the face); 0 for no crown (a plain sphere's point, a wall's plane)."""
    return 0.5 / crown[0] if crown[0] > 0.0 else 0.0


@numba.njit(inline="always", **JIT_FLAGS)
def flat_tolerance(tol):
    """How far a feature's vertices may lie off the plane fitted to them for it to count as flat
    (``_height_fit``): the crowned minimiser, on that plane, lies within this of the core."""
    return 1e-6 * tol + 1e-15


# Frank-Wolfe steps of ``crown_floor``: 2 clear about 58 % of a shaken pile's pairs held apart by
# their crowns alone, 3 about 62 %, 5 about 63 % (benchmarks/README.md, session 22).
FLOOR_STEPS = 2


@numba.njit(inline="always", **JIT_FLAGS)
def crown_floor(va, core, crown, q, nx, ny, nz, tol):
    """A lower bound of a shape's share ``g(x) = n . (x - q) + phi(x)`` of the crowned distance
    that ``crowned_contact`` returns, whatever its minimiser x: the shape (core ``core`` of the
    vertex array va, crown ``crown`` about ``core.pos``) has its closest point q on its
    supporting plane across the unit direction n, towards the other shape (it lies on the side
    n . x >= n . q). ``crowned_contact``'s value is d + g_a(x) + g_b(y), x and y within
    ``flat_tolerance`` of their cores; g is convex, so for any point x_k its tangent plane at
    x_k, least at a vertex, bounds it from below on the core (Frank-Wolfe's bound), and
    ``FLOOR_STEPS`` steps from q towards those vertices tighten it. At a corner or an edge across
    n the bound is about the crown's height there (tens of micrometres on a phone), with two
    support queries and no feature, hull or minimiser: the pairs of a shaken pile whose cores
    lie within the roundings but whose crowns hold them apart (``dem.rounded_contact``). Across
    a face, the centre's height over the plane gives the better bound (below)."""
    kappa, kappa_h2 = crown[0], crown[1]
    px, py, pz = core.pos
    qx, qy, qz = q
    eps = flat_tolerance(tol)
    # Across a face the tangent planes lean to its far corners; there the centre's height over
    # the plane bounds g: H = n . (p - q), x's height h = n . (x - q) >= -eps and
    # |x - p| >= |H - h|, so g >= h + kappa (H - h)^2 - kappa h_c^2, which rises with h while
    # 2 kappa (H - h) <= 1 (the crowns of dem/polyhedra.py: 2 kappa H <= 4 CROWN = 2e-3).
    height = nx * (px - qx) + ny * (py - qy) + nz * (pz - qz)
    best = -eps - kappa_h2
    if 2.0 * kappa * (height + eps) <= 1.0:
        best = -eps + kappa * (height + eps) ** 2 - kappa_h2
    xx, xy, xz = q
    off = 2.0 * eps  # x within eps of the core, and |grad g| <= 1 + 2 kappa |x - p| < 2
    for _ in range(FLOOR_STEPS):
        gx, gy, gz = nx + 2.0 * kappa * (xx - px), ny + 2.0 * kappa * (xy - py), nz + 2.0 * kappa * (xz - pz)
        value = nx * (xx - qx) + ny * (xy - qy) + nz * (xz - qz)
        value += kappa * ((xx - px) ** 2 + (xy - py) ** 2 + (xz - pz) ** 2) - kappa_h2
        sx, sy, sz = support(va, core, -gx, -gy, -gz)
        dx, dy, dz = sx - xx, sy - xy, sz - xz
        slope = gx * dx + gy * dy + gz * dz  # <= 0: s is the core's least along the gradient
        best = max(best, value + slope - off)
        # the step along x -> s that minimises g: g(x + t d) = g(x) + t slope + kappa t^2 |d|^2
        curve = kappa * (dx * dx + dy * dy + dz * dz)
        t = 1.0 if curve <= 0.0 else min(1.0, -0.5 * slope / curve)
        xx, xy, xz = xx + t * dx, xy + t * dy, xz + t * dz
    return best


@numba.njit(inline="always", **JIT_FLAGS)
def _height_fit(pts, m, tol):
    """(alpha, beta_u, beta_w, flat): the linear height above the supporting plane over a
    feature's hull pts[:m] (column 2 holds tol - height): a plane fitted to its vertices, a line
    along an edge, a constant at a corner. ``flat``: the vertices lie on that plane (to 1e-6 of
    tol), as a face's do; a curved patch of a mesh's outline does not."""
    if m == 1:
        return tol - pts[0, 2], 0.0, 0.0, True
    if m == 2:
        eu, ew = pts[1, 0] - pts[0, 0], pts[1, 1] - pts[0, 1]
        ll = eu * eu + ew * ew
        slope = ((tol - pts[1, 2]) - (tol - pts[0, 2])) / ll
        bu, bw = slope * eu, slope * ew
        return tol - pts[0, 2] - bu * pts[0, 0] - bw * pts[0, 1], bu, bw, True
    mu = mw = mh = 0.0
    for k in range(m):
        mu += pts[k, 0]
        mw += pts[k, 1]
        mh += tol - pts[k, 2]
    mu, mw, mh = mu / m, mw / m, mh / m
    suu = suw = sww = suh = swh = 0.0
    for k in range(m):
        du, dw, dh = pts[k, 0] - mu, pts[k, 1] - mw, (tol - pts[k, 2]) - mh
        suu += du * du
        suw += du * dw
        sww += dw * dw
        suh += du * dh
        swh += dw * dh
    det = suu * sww - suw * suw
    if not det > 1e-9 * (suu + sww) ** 2:
        return mh, 0.0, 0.0, False
    bu = (sww * suh - suw * swh) / det
    bw = (suu * swh - suw * suh) / det
    alpha = mh - bu * mu - bw * mw
    flat = True
    for k in range(m):
        if abs(alpha + bu * pts[k, 0] + bw * pts[k, 1] - (tol - pts[k, 2])) > flat_tolerance(tol):
            flat = False
    return alpha, bu, bw, flat


@numba.njit(inline="always", **JIT_FLAGS)
def _centre(p, s, n, u, w):
    """(t, pu, pw): a shape's centre p in the contact frame (n, u, w: 3-tuples), t = the
    supporting plane's height s above it along n."""
    return (
        s - (p[0] * n[0] + p[1] * n[1] + p[2] * n[2]),
        p[0] * u[0] + p[1] * u[1] + p[2] * u[2],
        p[0] * w[0] + p[1] * w[1] + p[2] * w[2],
    )


@numba.njit(inline="always", **JIT_FLAGS)
def _gap(u, w, c):
    """Crowned gap at (u, w): c = (d, alpha_a, bu_a, bw_a, t_a, pu_a, pw_a, kappa_a, same for b)
    (t = offset of the feature's height from the centre's along n; see ``crowned_contact``)."""
    ha = c[1] + c[2] * u + c[3] * w
    hb = c[8] + c[9] * u + c[10] * w
    za = c[4] + ha
    zb = c[11] - hb
    phi_a = c[7] * ((u - c[5]) ** 2 + (w - c[6]) ** 2 + za * za)
    phi_b = c[14] * ((u - c[12]) ** 2 + (w - c[13]) ** 2 + zb * zb)
    return c[0] + ha + hb + phi_a + phi_b


@numba.njit(inline="always", **JIT_FLAGS)
def _gradient(u, w, c):
    """Gradient of ``_gap`` at (u, w), and its (constant) Hessian (q_uu, q_uw, q_ww)."""
    za = c[4] + c[1] + c[2] * u + c[3] * w
    zb = c[11] - (c[8] + c[9] * u + c[10] * w)
    gu = c[2] + c[9] + 2.0 * c[7] * ((u - c[5]) + za * c[2]) + 2.0 * c[14] * ((u - c[12]) - zb * c[9])
    gw = c[3] + c[10] + 2.0 * c[7] * ((w - c[6]) + za * c[3]) + 2.0 * c[14] * ((w - c[13]) - zb * c[10])
    quu = 2.0 * c[7] * (1.0 + c[2] * c[2]) + 2.0 * c[14] * (1.0 + c[9] * c[9])
    quw = 2.0 * c[7] * c[2] * c[3] + 2.0 * c[14] * c[9] * c[10]
    qww = 2.0 * c[7] * (1.0 + c[3] * c[3]) + 2.0 * c[14] * (1.0 + c[10] * c[10])
    return gu, gw, quu, quw, qww


@numba.njit(inline="always", **JIT_FLAGS)
def _free_minimum(c):
    """(u, w, bowl): the stationary point of ``_gap``; bowl: it is its minimum (the Hessian is
    positive definite)."""
    gu, gw, quu, quw, qww = _gradient(0.0, 0.0, c)
    det = quu * qww - quw * quw
    if not det > 0.0:
        return 0.0, 0.0, False
    return -(qww * gu - quw * gw) / det, -(quu * gw - quw * gu) / det, True


@numba.njit(inline="always", **JIT_FLAGS)
def _holds(poly, m, u, w):
    """Whether the counter-clockwise polygon poly[:m] (m >= 3) holds (u, w) strictly (a polygon
    without area holds nothing)."""
    for a in range(m):
        b = (a + 1) % m
        if (poly[b, 0] - poly[a, 0]) * (w - poly[a, 1]) - (poly[b, 1] - poly[a, 1]) * (u - poly[a, 0]) <= 0.0:
            return False
    return True


@numba.njit(**STEP_FLAGS)
def _minimise(poly, m, c):
    """(u, w) minimising the convex quadratic ``_gap`` on the convex polygon (segment, point)
    poly[:m], counter-clockwise."""
    if m == 1:
        return poly[0, 0], poly[0, 1]
    u, w, bowl = _free_minimum(c)
    if m >= 3 and bowl and _holds(poly, m, u, w):
        return u, w
    best = math.inf
    bu = poly[0, 0]
    bw = poly[0, 1]
    edges = m if m > 2 else 1
    for a in range(edges):
        b = (a + 1) % m
        u0, w0 = poly[a, 0], poly[a, 1]
        eu, ew = poly[b, 0] - u0, poly[b, 1] - w0
        gu, gw, quu, quw, qww = _gradient(u0, w0, c)
        curv = quu * eu * eu + 2.0 * quw * eu * ew + qww * ew * ew
        slope = gu * eu + gw * ew
        t = 0.0 if curv <= 0.0 else min(1.0, max(0.0, -slope / curv))
        if curv <= 0.0 and slope < 0.0:
            t = 1.0
        u, w = u0 + t * eu, w0 + t * ew
        value = _gap(u, w, c)
        if value < best:
            best, bu, bw = value, u, w
    return bu, bw


@numba.njit(inline="always", **JIT_FLAGS)
def _inside(poly, m, u, w, eps):
    """Whether (u, w) lies inside the counter-clockwise polygon poly[:m] by more than eps."""
    if m < 3:
        return False
    for a in range(m):
        b = (a + 1) % m
        eu, ew = poly[b, 0] - poly[a, 0], poly[b, 1] - poly[a, 1]
        if eu * (w - poly[a, 1]) - ew * (u - poly[a, 0]) <= eps * math.sqrt(eu * eu + ew * ew):
            return False
    return True


@numba.njit(inline="always", **JIT_FLAGS)
def _along(seg, u, w, eps):
    """(eu, ew, inside): unit direction of segment seg[:2] and whether (u, w) projects inside it
    by more than eps."""
    eu, ew = seg[1, 0] - seg[0, 0], seg[1, 1] - seg[0, 1]
    length = math.sqrt(eu * eu + ew * ew)
    eu, ew = eu / length, ew / length
    t = (u - seg[0, 0]) * eu + (w - seg[0, 1]) * ew
    return eu, ew, eps < t < length - eps


@numba.njit(**STEP_FLAGS)
def _tilt(hull_a, ha, hull_b, hb, u, w, c, eps):
    """Tangential part tau of the direction x* - y* of the exact minimiser (KKT): where y* can
    move inside a face of B, tau = grad phi_b there; inside a face of A, tau = -grad phi_a; along
    an edge only, the component of that along the edge (two crossing edges fix both components).
    The normal tilted by tau carries the crown's share of the gradient of D."""
    gau, gaw = -2.0 * c[7] * (u - c[5]), -2.0 * c[7] * (w - c[6])  # -grad phi_a
    gbu, gbw = 2.0 * c[14] * (u - c[12]), 2.0 * c[14] * (w - c[13])  # grad phi_b
    in_a = _inside(hull_a, ha, u, w, eps)
    in_b = _inside(hull_b, hb, u, w, eps)
    if in_a and in_b:
        return 0.5 * (gau + gbu), 0.5 * (gaw + gbw)
    if in_b:
        return gbu, gbw
    if in_a:
        return gau, gaw
    # conditions tau . e = g . e from edges
    n_cond = 0
    e1u = e1w = r1 = e2u = e2w = r2 = 0.0
    if ha == 2:
        eu, ew, inside = _along(hull_a, u, w, eps)
        if inside:
            e1u, e1w, r1 = eu, ew, gau * eu + gaw * ew
            n_cond = 1
    if hb == 2:
        eu, ew, inside = _along(hull_b, u, w, eps)
        if inside:
            if n_cond == 0:
                e1u, e1w, r1 = eu, ew, gbu * eu + gbw * ew
            else:
                e2u, e2w, r2 = eu, ew, gbu * eu + gbw * ew
            n_cond += 1
    if n_cond == 2:
        det = e1u * e2w - e1w * e2u
        if abs(det) > 1e-6:
            return (r1 * e2w - r2 * e1w) / det, (e1u * r2 - e2u * r1) / det
        n_cond = 1  # parallel edges: along them only
    if n_cond == 1:
        return r1 * e1u, r1 * e1w
    return 0.0, 0.0


@numba.njit(**STEP_FLAGS)
def crowned_contact(va, a, crown_a, vb, b, crown_b, p_a, p_b, tol, work):
    """Crowned distance D of two separated convex shapes ``a`` and ``b`` (``dem.convex.Core``s of
    the vertex arrays va, vb) whose closest points (``gjk_distance``, 3-tuples) are p_a and p_b,
    its minimiser and the direction of the force: ``(D, xx, xy, xz, yx, yy, yz, ex, ey, ez)``,
    x* on A, y* on B, e the unit gradient of D with respect to A's position.

    ``crown_*`` = (kappa, kappa h^2, ...) of each shape about its centre, the core's position
    (kappa 0: not crowned, as a sphere or a wall); ``tol`` bounds how far above its supporting
    plane the minimiser can lie (the crown's variation over the pieces)."""
    ax, ay, az = p_a
    bx, by, bz = p_b
    pa, pb = a.pos, b.pos
    nx, ny, nz = ax - bx, ay - by, az - bz
    d = math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx / d, ny / d, nz / d
    ux, uy, uz, wx, wy, wz = plane_basis(nx, ny, nz)
    n, u, w = (nx, ny, nz), (ux, uy, uz), (wx, wy, wz)
    ha, hb, eps = feature_hulls(va, a, vb, b, d, n, tol, work)
    alpha_a, bua, bwa, flat_a = _height_fit(work[0], ha, tol)
    alpha_b, bub, bwb, flat_b = _height_fit(work[1], hb, tol)
    s_a = ax * nx + ay * ny + az * nz  # A's supporting plane along n
    s_b = bx * nx + by * ny + bz * nz
    ka, kb = crown_a[0], crown_b[0]
    ta, pua, pwa = _centre(pa, s_a, n, u, w)
    tb, pub, pwb = _centre(pb, s_b, n, u, w)
    c = (d, alpha_a, bua, bwa, ta, pua, pwa, ka, alpha_b, bub, bwb, tb, pub, pwb, kb)
    # Two faces whose crowned gap is least inside both: that point is the minimiser on their
    # overlap, which needs no clipping (the usual case of a face resting on a face).
    fu, fw, bowl = _free_minimum(c)
    free = flat_a and flat_b and ha >= 3 and hb >= 3 and bowl
    free = free and _holds(work[0], ha, fu, fw) and _holds(work[1], hb, fu, fw)
    # Keep the hull that the clipping overwrites (in work[2]) for the tilt of the normal below.
    if not (flat_a and flat_b):  # curved features: their closest points
        m = 0
        poly, hull_a, hull_b = work[0], work[0], work[1]
    elif free:
        m = -1
        poly, hull_a, hull_b = work[0], work[0], work[1]
    elif hb >= 3:
        for k in range(ha):
            _copy_row(work[2], k, work[0], k)
        m = _clip(work[0], ha, work[1], hb, work[3])
        poly, hull_a, hull_b = work[0], work[2], work[1]
    elif ha >= 3:
        for k in range(hb):
            _copy_row(work[2], k, work[1], k)
        m = _clip(work[1], hb, work[0], ha, work[3])
        poly, hull_a, hull_b = work[1], work[0], work[2]
    else:
        m = 0
        poly, hull_a, hull_b = work[0], work[0], work[1]
        if ha == 2 and hb == 2:
            m = _parallel_segments(work[0], work[1], eps)
    ha_c = hb_c = -1.0
    if m != 0:
        cu, cw = (fu, fw) if m < 0 else _minimise(poly, m, c)
        ha_c = alpha_a + bua * cu + bwa * cw
        hb_c = alpha_b + bub * cu + bwb * cw
    slack = 1e-9 * tol + 1e-15
    if ha_c < -slack or hb_c < -slack:
        # crossing edges, a single pair of closest points (no freedom), or features whose
        # overlap has no area: the closest points
        cu = 0.5 * ((ax + bx) * ux + (ay + by) * uy + (az + bz) * uz)
        cw = 0.5 * ((ax + bx) * wx + (ay + by) * wy + (az + bz) * wz)
        ha_c = hb_c = 0.0
    za = s_a + ha_c
    zb = s_b - hb_c
    xx, xy, xz = cu * ux + cw * wx + za * nx, cu * uy + cw * wy + za * ny, cu * uz + cw * wz + za * nz
    yx, yy, yz = cu * ux + cw * wx + zb * nx, cu * uy + cw * wy + zb * ny, cu * uz + cw * wz + zb * nz
    phi_a = ka * ((xx - pa[0]) ** 2 + (xy - pa[1]) ** 2 + (xz - pa[2]) ** 2) - crown_a[1]
    phi_b = kb * ((yx - pb[0]) ** 2 + (yy - pb[1]) ** 2 + (yz - pb[2]) ** 2) - crown_b[1]
    tu, tw = _tilt(hull_a, ha, hull_b, hb, cu, cw, c, eps)
    ex, ey, ez = nx + tu * ux + tw * wx, ny + tu * uy + tw * wy, nz + tu * uz + tw * wz
    norm = math.sqrt(ex * ex + ey * ey + ez * ez)
    return za - zb + phi_a + phi_b, xx, xy, xz, yx, yy, yz, ex / norm, ey / norm, ez / norm
