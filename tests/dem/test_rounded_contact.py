"""Contact geometry of rounded shapes (dem/rounded_contact.py, dem/crown.py) against hand-worked
cases. The box's crown is ``phi(x) = kappa (|x|^2 - h^2)`` (``Polyhedron.crown``): zero at the foot of
its centre on its nearest face, kappa times the squared distance from that foot along the face."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.convex import SIMPLEX, gjk_distance, place, scratch, support
from dem.facets import build_facets
from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle, matrix
from dem.rounded_contact import WallFacet, _footprint, _inside_facet, facet_geometry, pair_geometry
from dem.walls import WallMesh

EYE = np.eye(3)
BOX = Polyhedron.box((0.04, 0.03, 0.01), 0.002, 1000.0)
CROWN = tuple(float(c) for c in BOX.crown(0))
KAPPA, KAPPA_H2, _ = CROWN


def floor():
    """A 1 m square floor: one facet of two triangles meeting along the diagonal."""
    facets = build_facets([WallMesh.plane((0, 0, 0), (0, 0, 1), 1.0)])
    assert facets.tri_count[0] == 2
    return facets


def on_floor(rot, pos):
    f = floor()
    facet = WallFacet(0, 2, (0.0, 0.0, 0.0), tuple(float(c) for c in f.normal[0]), float(f.offset[0]))
    core = place(0, 8, np.asarray(rot, float), np.asarray(pos, float))
    return facet_geometry(BOX.core, core, BOX.rounding, CROWN, f.tri.reshape(-1, 3), facet, scratch())


def test_a_box_lying_across_the_facet_diagonal_is_one_contact_below_its_centre():
    # The floor's diagonal runs through the origin; the box's face straddles it.
    delta, d, nx, ny, nz, cx, cy, cz, s_uu, s_uw, s_ww, is_face = on_floor(EYE, (0.004, -0.003, 0.0049))

    assert delta == pytest.approx(0.0001, rel=1e-9)
    assert d == pytest.approx(0.0049 - 0.003, rel=1e-12)
    assert (nx, ny, nz) == pytest.approx((0, 0, 1), abs=1e-9)
    assert (cx, cy) == pytest.approx((0.004, -0.003), abs=1e-9)
    assert cz == pytest.approx(0.5 * (0.0049 - 0.003), abs=1e-12)
    assert is_face
    # the patch is the core's 36 x 26 mm face: second moments side^2 / 12 per unit area
    assert sorted([s_uu, s_ww]) == pytest.approx(sorted([0.036**2 / 12, 0.026**2 / 12]), rel=1e-6)


def l_floor():
    """An L-shaped floor, one facet of six triangles: the squares (0, 0.1) x (0, 0.1), (0.1, 0.2)
    x (0, 0.1) and (0, 0.1) x (0.1, 0.2); its inner corner (0.1, 0.1) is reflex."""
    corners = [[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1], [0, 2], [1, 2]]
    vertices = 0.1 * np.array([[x, y, 0] for x, y in corners])
    faces = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7], [3, 7, 6]])
    facets = build_facets([WallMesh(vertices, faces)])
    assert facets.n == 1 and facets.tri_count[0] == 6
    return facets


@pytest.mark.parametrize(
    ("x", "y", "inside"),
    [
        (0.05, 0.05, True),  # inside one square, across its diagonal
        (0.1, 0.05, True),  # across the inner edge of two squares
        (0.05, 0.1, True),
        (0.09, 0.09, False),  # a corner of the face over the notch, the centre over the facet
        (0.05, 0.19, False),  # over the outer edge
        (0.15, 0.15, False),  # over the notch
    ],
)
def test_a_face_is_over_a_non_convex_facet_only_clear_of_its_boundary(x, y, inside):
    # The box's lower face (36 x 26 mm core) 2.9 mm above the floor: the facet is a plane for it
    # (dem.rounded_contact's fast path) only where no boundary edge of the facet meets it.
    f = l_floor()
    facet = WallFacet(0, 6, (0.0, 0.0, 0.0), tuple(float(c) for c in f.normal[0]), float(f.offset[0]))
    core = place(0, 8, EYE, np.array([x, y, 0.0059]))

    pts = np.zeros((8, 3))
    box, m = _footprint(BOX.core, core, facet, BOX.rounding, pts)

    assert _inside_facet(f.tri.reshape(-1, 3), facet, box, pts, m) == inside


@pytest.mark.parametrize(("c", "inside"), [(0.132, True), (0.14, False)])
def test_a_turned_face_beside_an_oblique_edge_is_over_the_facet_while_clear_of_it(c, inside):
    # A triangular floor, its hypotenuse x + y = 0.3 oblique to the plane's axes; the box turned by
    # 45 degrees about z, its lower face's nearest edge parallel to the hypotenuse, at distance
    # (0.3 - 2 c - 0.036 / sqrt(2)) / sqrt(2) (7.5 mm at c = 0.132, over it at 0.14). Its box in
    # the plane's axes reaches over the hypotenuse in both cases: the face's corners decide.
    facets = build_facets(
        [WallMesh(np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]], float), np.array([[0, 1, 2]]))]
    )
    facet = WallFacet(
        0, 1, (0.0, 0.0, 0.0), tuple(float(x) for x in facets.normal[0]), float(facets.offset[0])
    )
    core = place(0, 8, matrix(from_axis_angle((0, 0, 1), math.pi / 4)), np.array([c, c, 0.0059]))
    pts = np.zeros((8, 3))

    box, m = _footprint(BOX.core, core, facet, BOX.rounding, pts)

    tri = facets.tri.reshape(-1, 3)
    assert m == 4 and box[1] - box[2] > 0.3  # u = y, w = -x: the box's corner has x + y > 0.3
    assert _inside_facet(tri, facet, box, pts, m) == inside


def test_a_slightly_tilted_face_is_pressed_where_the_crowned_gap_is_least():
    # A tilt theta about y: the height above the floor grows like theta (x + a), the crown like
    # kappa x^2, so the contact point sits at x = -theta / (2 kappa) (to a relative theta^2 and
    # kappa h), moving continuously from the middle (theta = 0) to the lower edge.
    a = 0.018
    theta = 0.4 * 2 * KAPPA * a
    rot = matrix(from_axis_angle(np.array([0, 1.0, 0]), -theta))
    lowest = float(np.min((BOX.core @ rot.T)[:, 2]))
    delta, d, nx, ny, nz, cx, cy, cz, *_ = on_floor(rot, (0.0, 0.0, BOX.rounding - 1e-4 - lowest))

    assert cx == pytest.approx(-theta / (2 * KAPPA), rel=1e-3)
    assert cy == pytest.approx(0.0, abs=1e-12)
    assert 0 < 1e-4 - delta < theta * a


def test_a_face_tilted_past_the_crown_is_pressed_at_its_lower_edge():
    a, theta = 0.018, 4 * KAPPA * 0.018
    rot = matrix(from_axis_angle(np.array([0, 1.0, 0]), -theta))
    lowest = float(np.min((BOX.core @ rot.T)[:, 2]))
    delta, d, nx, ny, nz, cx, cy, cz, *_ = on_floor(rot, (0.0, 0.0, BOX.rounding - 1e-4 - lowest))

    placed = BOX.core @ rot.T
    lower_edge = placed[np.isclose(placed[:, 2], lowest)]
    assert len(lower_edge) == 2
    assert cx == pytest.approx(lower_edge[0, 0], abs=1e-12)
    assert 1e-4 - delta == pytest.approx(KAPPA * a * a, rel=0.01)


def test_a_box_standing_on_an_edge_touches_at_the_middle_of_the_edge():
    rot = matrix(from_axis_angle(np.array([1.0, 0, 0]), math.radians(30)))
    lowest = float(np.min((BOX.core @ rot.T)[:, 2]))
    delta, d, nx, ny, nz, cx, cy, cz, *_ = on_floor(rot, (0.01, 0.02, -lowest + 0.0015))

    edge = (BOX.core @ rot.T)[np.isclose((BOX.core @ rot.T)[:, 2], lowest)]
    assert len(edge) == 2
    middle = edge.mean(axis=0)
    assert delta == pytest.approx(0.0005 - (KAPPA * middle @ middle - KAPPA_H2), rel=1e-9)
    assert (cx, cy) == pytest.approx(tuple(middle[:2] + [0.01, 0.02]), abs=1e-12)


def test_a_box_above_the_facet_plane_is_rejected_before_gjk():
    delta, *_ = on_floor(EYE, (0, 0, 0.02))

    assert delta < 0


def pair(pos_a, rot_a, pos_b, rot_b, axis, simplex=None):
    a = place(0, 8, np.asarray(rot_a, float), np.asarray(pos_a, float))
    b = place(0, 8, np.asarray(rot_b, float), np.asarray(pos_b, float))
    simplex = np.zeros(SIMPLEX, np.int32) if simplex is None else simplex
    return pair_geometry(
        BOX.core, a, BOX.rounding, CROWN, BOX.core, b, BOX.rounding, CROWN, axis, simplex, scratch()
    )


def test_stacked_boxes_touch_midway_between_the_feet_of_their_centres():
    axis = np.zeros(3)
    delta, d, nx, ny, nz, cx, cy, cz, *_ = pair((0.01, 0.0, 0.0099), EYE, (0, 0, 0), EYE, axis)

    # kappa (x - 0.01)^2 + kappa x^2 is least at x = 0.005, inside the faces' overlap
    # [-0.008, 0.008]; each crown there is kappa 0.005^2, and its slope 2 kappa 0.005 tilts the
    # normal (the crowned faces push each other apart sideways).
    assert delta == pytest.approx(0.0001 - 2 * KAPPA * 0.005**2, rel=1e-9)
    slope = 2 * KAPPA * 0.005
    assert (nx, ny, nz) == pytest.approx(np.array([slope, 0, 1]) / math.hypot(slope, 1), abs=1e-12)
    assert (cx, cy, cz) == pytest.approx((0.005, 0.0, 0.00495), abs=1e-12)
    assert axis == pytest.approx([0, 0, 1])


def test_the_cached_separating_axis_gives_the_gjk_answer_for_pairs_apart():
    rot = matrix(from_axis_angle(np.array([1.0, 2.0, 3.0]), 0.7))
    axis = np.zeros(3)
    near = pair((0.0, 0.0, 0.03), rot, (0, 0, 0), EYE, axis)
    far_cached = pair((0.0, 0.0, 0.2), rot, (0, 0, 0), EYE, axis)
    far_fresh = pair((0.0, 0.0, 0.2), rot, (0, 0, 0), EYE, np.zeros(3))

    assert near[0] < 0 and far_cached[0] < 0
    # The gap along any direction is at most the distance: the cached test never misses a contact.
    assert far_fresh[0] - 1e-15 <= far_cached[0] < 0


def test_the_cached_simplex_holds_the_closest_features_of_stacked_boxes():
    simplex = np.zeros(SIMPLEX, np.int32)
    pair((0.01, 0.0, 0.0099), EYE, (0, 0, 0), EYE, np.zeros(3), simplex)

    k = simplex[0]
    assert 1 <= k <= 3
    rows_a, rows_b = simplex[1 : 1 + 2 * k : 2], simplex[2 : 2 + 2 * k : 2]
    # A's bottom face over B's top face: the simplex's points pair A's lower and B's upper corners.
    assert np.all(BOX.core[rows_a, 2] < 0) and np.all(BOX.core[rows_b, 2] > 0)


@pytest.mark.parametrize("seed", range(6))
def test_gjk_warm_started_from_any_cached_simplex_gives_the_cold_answer(seed):
    rng = np.random.default_rng(seed)
    rot_a = matrix(from_axis_angle(rng.normal(size=3), rng.uniform(0, math.pi)))
    rot_b = matrix(from_axis_angle(rng.normal(size=3), rng.uniform(0, math.pi)))
    pos_a = np.array([0.0, 0.0, 0.045]) + rng.uniform(-0.01, 0.01, 3)
    a, b = place(0, 8, rot_a, pos_a), place(0, 8, rot_b, np.zeros(3))
    cold = gjk_distance(BOX.core, a, BOX.core, b)
    # The simplex of this pair one step earlier, and simplices of other features, even points
    # furthest from the answer (A's highest corner against B's lowest), all valid starts.
    moved = place(0, 8, rot_a, pos_a + 1e-4)
    last = np.zeros(SIMPLEX, np.int32)
    gjk_distance(BOX.core, moved, BOX.core, b, last)
    far = np.array([3, 0, 0, 7, 1, 6, 2], np.int32)
    far[1::2] = [int(np.argmax(BOX.core @ rot_a.T[:, 2])), 0, 1]
    far[2::2] = [int(np.argmin(BOX.core @ rot_b.T[:, 2])), 7, 6]
    for start in (last, far, np.array([2, 0, 1, 2, 3, 0, 0], np.int32)):
        warm = gjk_distance(BOX.core, a, BOX.core, b, start.copy())
        assert warm[0] == pytest.approx(cold[0], rel=1e-12)
        # closest points: the same up to rounding, or others at the same distance (parallel faces)
        gap = np.array(warm[1:4]) - np.array(warm[4:7])
        assert np.linalg.norm(gap) == pytest.approx(cold[0], rel=1e-12)
        assert gap @ (np.array(cold[1:4]) - np.array(cold[4:7])) == pytest.approx(cold[0] ** 2, rel=1e-9)


def test_a_pair_that_touched_gives_the_same_answer_and_state_with_gjk_first():
    """``pair_geometry(..., touching=True)`` runs GJK before the cached-axis test (which a resting
    contact always passes) and takes the test only where GJK leaves the cores apart or nearly so:
    its answer, axis and simplex must be those of the test first, to the bit, for boxes pressed
    together, just touching, within the rounding of the axis test, and moved apart (whose cached
    axis then rejects them, the axis and simplex that GJK changed put back); a pair apart only
    by the margin, which the test first may take from the crowns' floor."""
    rng = np.random.default_rng(21)
    kinds = {"touching": 0, "apart, axis rejects": 0, "apart, gjk": 0}
    reach = 2.0 * BOX.rounding
    for _ in range(400):
        rot_a = matrix(from_axis_angle(rng.normal(size=3), rng.choice([0.0, 1e-3, rng.uniform(0, math.pi)])))
        rot_b = matrix(from_axis_angle(rng.normal(size=3), rng.choice([0.0, rng.uniform(0, math.pi)])))
        up = rng.normal(size=3) * np.array([0.3, 0.3, 1.0])
        up /= np.linalg.norm(up)
        a0, b = place(0, 8, rot_a, np.zeros(3)), place(0, 8, rot_b, np.zeros(3))
        far = np.asarray(support(BOX.core, b, *up)) - np.asarray(support(BOX.core, a0, *(-up)))
        # the last step: pressed together; now: moved along (and across) the normal by up to 2 reach
        pos_last = far + up * (reach - rng.uniform(0.0, 0.5) * BOX.rounding)
        axis, simplex = np.zeros(3), np.zeros(SIMPLEX, np.int32)
        pair(pos_last, rot_a, np.zeros(3), rot_b, axis, simplex)
        move = rng.choice([-1e-4, 1e-9, 0.6, 1.0, 2.0]) * BOX.rounding
        pos = pos_last + up * move + rng.normal(size=3) * rng.choice([0.0, 1e-4])
        results = []
        for touching in (False, True):
            ax, sx = axis.copy(), simplex.copy()
            a = place(0, 8, rot_a, pos)
            r = pair_geometry(
                BOX.core,
                a,
                BOX.rounding,
                CROWN,
                BOX.core,
                b,
                BOX.rounding,
                CROWN,
                ax,
                sx,
                scratch(),
                touching,
            )
            results.append((r, ax, sx))
        (first, ax0, sx0), (gjk_first, ax1, sx1) = results
        if first[0] > 0.0 or gjk_first[0] > 0.0:
            assert first == gjk_first
        else:
            # apart either way; a pair that did not touch may be told so by its crowns' floor,
            # whose margin is a lower bound of the crowned one (dem.crown.crown_floor)
            assert gjk_first[0] <= first[0] <= 0.0 and first[1:] == gjk_first[1:]
        assert np.array_equal(ax0, ax1) and np.array_equal(sx0, sx1)
        if first[0] > 0.0:
            kinds["touching"] += 1
        elif np.array_equal(ax0, axis) and np.array_equal(sx0, simplex):
            kinds["apart, axis rejects"] += 1
        else:
            kinds["apart, gjk"] += 1
    assert kinds["touching"] >= 100 and kinds["apart, axis rejects"] >= 100, kinds
    assert kinds["apart, gjk"] >= 5, kinds


def test_a_pieces_box_holds_its_core_along_every_direction():
    """``box_extent`` is the kernels' first rejection: it must bound the core's placed vertices
    from outside along any direction (so a box clear of a partner by the rounding means the
    rounded piece is clear), for a piece whose core is not centred on the body's centre of mass."""
    from dem.bodies import Spheres
    from dem.quaternion import matrices
    from dem.rounded_contact import box_extent
    from dem.scenarios.feeder import make_items
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config("examples/feeder.toml")
    items = config.items.model_copy(update={"representation": "polyhedron", "counts": {"camera": 1}})
    camera = make_items(items, np.random.default_rng(0))[0].shape
    assert camera.n_pieces == 2  # body slab and lens barrel: neither piece is centred on the body
    rng = np.random.default_rng(7)
    for _ in range(200):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        rot = matrices(quat[None, :])[0]
        pos = rng.uniform(-1.0, 1.0, size=3)
        spheres = Spheres()
        spheres.append(0, camera, rot, pos)
        rows = spheres.arrays()
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        for k in range(camera.n_pieces):
            heights = (pos + camera.piece(k) @ rot.T) @ n

            low, high = box_extent(rows.x, rows.half, rot[None], k, 0, *n)

            assert low <= heights.min() + 1e-15 and high >= heights.max() - 1e-15


def _smartphone():
    from dem.scenarios.feeder import make_items
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config("examples/feeder.toml")
    items = config.items.model_copy(update={"representation": "polyhedron", "counts": {"smartphone": 1}})
    return make_items(items, np.random.default_rng(0))[0].shape


def test_a_touching_pairs_patch_moments_are_those_of_its_patch_taken_afresh():
    """The kernels take the patch's second moments (``patch_moments``) from the crowned contact's
    projections, and skip the hulls where a side has one vertex within the overlap: on phones
    resting face on face, tilted, edge or corner on face and pressed deeper than the crown's
    tolerance, they
    must be those of ``contact_patch`` taken from scratch, to the bit."""
    from dem.bodies import Spheres
    from dem.convex import contact_patch, patch_moments
    from dem.crown import crowned_contact
    from dem.quaternion import matrices

    phone = _smartphone()
    spheres = Spheres()
    spheres.append(0, phone, EYE, np.zeros(3))
    rows = spheres.arrays()
    va, start, count = rows.core, int(rows.core_start[0]), int(rows.core_count[0])
    r, crown = float(rows.rounding[0]), tuple(float(c) for c in rows.crown[0])
    tol = 8.0 * crown[2]
    b = place(start, count, EYE, np.zeros(3))
    rng = np.random.default_rng(11)
    kinds = {"single": 0, "polygon": 0, "deep": 0}
    for trial in range(450):
        tilt = rng.choice([0.0, 1e-5, 1e-3, 0.05]) * rng.normal(size=3)
        if trial % 3 == 0:  # on its long edge
            tilt += np.array([0.5 * math.pi, 0.0, 0.0])
        tilt[2] += rng.uniform(0.0, 2.0 * math.pi)
        angle = np.linalg.norm(tilt)
        quat = np.array([math.cos(angle / 2), *(math.sin(angle / 2) * tilt / angle)])
        if trial % 3 == 1:  # any way up: mostly on a corner
            quat = rng.normal(size=4)
        rot = matrices((quat / np.linalg.norm(quat))[None, :])[0]
        pos = np.array([*rng.uniform(-0.06, 0.06, size=2), 0.2])
        d = gjk_distance(va, place(start, count, rot, pos), va, b)[0]
        delta = 10.0 ** rng.uniform(-4.0 if trial % 3 == 1 else -7.0, math.log10(3.0 * r))
        pos[2] -= d - (2.0 * r - delta)  # pressed down to an overlap of about delta
        a = place(start, count, rot, pos)
        d, ax, ay, az, bx, by, bz = gjk_distance(va, a, va, b)
        if not 0.0 < d < 2.0 * r:
            continue
        work = scratch()
        crowned = crowned_contact(va, a, crown, va, b, crown, (ax, ay, az), (bx, by, bz), tol, work)[0]
        delta = 2.0 * r - crowned
        if delta <= 0.0:
            continue
        heights_a = (pos + phone.piece(0) @ rot.T)[:, 2]
        single = np.sum(heights_a <= heights_a.min() + delta) == 1
        kinds["single" if single else "polygon"] += 1
        kinds["deep"] += delta > tol

        moments = patch_moments(va, a, va, b, (ax, ay, az), (bx, by, bz), delta, tol, work)

        afresh = contact_patch(va, a, va, b, (ax, ay, az), (bx, by, bz), delta, scratch())[5:]
        assert moments == afresh
    assert min(kinds.values()) >= 10, kinds


def _clipped(poly, clip):
    """Sutherland-Hodgman as ``dem.convex._clip`` writes it, with every edge taken."""
    poly = [tuple(p) for p in poly]
    for e in range(len(clip)):
        (ex0, ey0), (ex1, ey1) = clip[e][:2], clip[(e + 1) % len(clip)][:2]
        out = []
        m = len(poly)
        for a in range(m if m > 2 else 1):
            (px, py, pd), (qx, qy, qd) = poly[a], poly[(a + 1) % m]
            sp = (ex1 - ex0) * (py - ey0) - (ey1 - ey0) * (px - ex0)
            sq = (ex1 - ex0) * (qy - ey0) - (ey1 - ey0) * (qx - ex0)
            if sp >= 0.0:
                out.append(poly[a])
            if m > 1 and (sp >= 0.0) != (sq >= 0.0):
                t = sp / (sp - sq)
                out.append((px + t * (qx - px), py + t * (qy - py), pd + t * (qd - pd)))
            if m == 2 and sq >= 0.0:
                out.append(poly[1])
        poly = out
        if not poly:
            return []
    return poly


def test_clipping_passes_over_only_edges_that_keep_every_point():
    """``_clip`` passes over a clip edge whose inner side holds the polygon's box: the result must
    be that of taking every edge, to the bit, also for polygons that touch or cross the edges
    (points near a large offset, as world coordinates are)."""
    from scipy.spatial import ConvexHull

    from dem.convex import _clip

    rng = np.random.default_rng(5)
    passed_over = 0
    for _ in range(400):
        centre = rng.uniform(-0.5, 0.5, size=2)
        clip_pts = centre + rng.uniform(-0.05, 0.05, size=(12, 2))
        clip = clip_pts[ConvexHull(clip_pts).vertices]  # counter-clockwise
        size = rng.choice([0.002, 0.02, 0.08])
        pts = centre + rng.uniform(-0.05, 0.05, size=2) + rng.uniform(-size, size, size=(6, 2))
        corners = pts[ConvexHull(pts).vertices]
        poly = np.column_stack([corners, rng.uniform(0.0, 1e-4, size=len(corners))])  # depths ride along
        m = len(poly)
        work = np.zeros((3, 64, 3))
        work[0, :m] = poly
        work[1, : len(clip), :2] = clip
        expected = _clipped(poly, clip)

        n = _clip(work[0], m, work[1], len(clip), work[2])

        assert [tuple(row) for row in work[0, :n]] == expected
        passed_over += n == m and expected == [tuple(p) for p in poly]
    assert passed_over >= 20


def test_a_facet_pair_cleared_along_any_direction_is_apart():
    """``facet_axis_clears`` lets the force pass skip a piece-facet pair's geometry along its
    cached direction (``dem.forces``): wherever it clears a pose by the rounding, the geometry must
    find the pair apart. Poses of the smartphone around the end of a 1 m floor (the triangles one by
    one), tried along the direction its geometry wrote at a nearby pose (the cache's use: many of
    these clear) and along random directions; the floor moved, as a shaken wall is."""
    from dem.bodies import Spheres
    from dem.quaternion import matrices
    from dem.rounded_contact import facet_axis_clears

    phone = _smartphone()
    f = floor()
    tri = f.tri.reshape(-1, 3)
    disp = (0.0, 0.002, 0.01)
    facet = WallFacet(0, 2, disp, tuple(float(c) for c in f.normal[0]), float(f.offset[0]))
    r = phone.rounding
    crown = tuple(float(c) for c in phone.crown(0))
    rng = np.random.default_rng(11)
    work = scratch()
    cleared_near = touching = 0
    for trial in range(600):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        rot = matrices(quat[None, :])[0]
        # centres around the floor's edge x = 0.5, from beside it to over it, from below its
        # plane to above
        pos = np.array(
            [0.5 + rng.uniform(-0.02, 0.1), rng.uniform(-0.3, 0.3), 0.01 + rng.uniform(-0.08, 0.08)]
        )
        core = place(0, len(phone.core), rot, pos)
        axis = np.zeros(3)
        facet_geometry(phone.core, core, r, crown, tri, facet, work, axis)
        if trial % 2 == 0 or not axis.any():
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            near = False
        else:
            near = True
        # the pose a step later: moved by up to 0.1 r, turned by up to 0.01 rad
        rot2 = matrices(np.append(1.0, rng.uniform(-0.005, 0.005, size=3))[None, :])[0] @ rot
        pos2 = pos + rng.uniform(-0.1, 0.1, size=3) * r
        spheres = Spheres()
        spheres.append(0, phone, rot2, pos2)
        rows = spheres.arrays()
        core2 = place(0, len(phone.core), rot2, pos2)
        delta = facet_geometry(phone.core, core2, r, crown, tri, facet, work)[0]
        touching += delta > 0.0
        clears = facet_axis_clears(
            rows.x, rows.half, rot2[None], 0, 0, phone.core, core2, r, tri, 0, 2, disp, *axis
        )
        if clears:
            assert delta <= 0.0, (trial, pos2, axis)
            cleared_near += near
    assert touching > 50 and cleared_near > 50
