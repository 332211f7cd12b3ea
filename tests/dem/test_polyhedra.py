"""Rounded polyhedra: core distances (GJK) and contact patches against geometry worked by hand,
cores shrunk exactly, mass properties from the mesh, convex decomposition of non-convex meshes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.optimize import minimize

from dem.convex import _REL_EPS, _hull2, _outline, contact_patch, gjk_distance, place, scratch
from dem.polyhedra import (
    CONVEX_TOLERANCE,
    ROUNDING_FRACTION,
    Polyhedron,
    PolyhedronError,
    convex_departure,
    convex_pieces,
    face_loop_order,
    make_polyhedron,
    shrink_convex,
    simplify_core,
    thinnest_dimension,
)
from dem.quaternion import from_axis_angle, matrix
from dem.scenarios.items import CATALOGUE

I3 = np.eye(3)
CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)


def core(verts, pos, rot=I3):
    return place(0, len(verts), np.asarray(rot, float), np.asarray(pos, float))


def gjk(a, pos_a, b, pos_b, rot_a=I3, rot_b=I3):
    return gjk_distance(a, core(a, pos_a, rot_a), b, core(b, pos_b, rot_b))


def test_gjk_distance_of_parallel_faces_is_the_gap():
    d, *_ = gjk(CUBE, (0, 0, 2.5), CUBE, (0.3, 0.2, 0))

    assert d == pytest.approx(0.5, rel=1e-12)


def test_gjk_distance_of_crossed_edges():
    # A cube turned 45 degrees about x above a cube turned 45 degrees about y: their edges cross
    # at right angles, each edge sqrt(2) from its centre.
    rot_a = matrix(from_axis_angle(np.array([1.0, 0, 0]), math.pi / 4))
    rot_b = matrix(from_axis_angle(np.array([0, 1.0, 0]), math.pi / 4))

    d, ax, ay, az, bx, by, bz = gjk(CUBE, (0, 0, 3), CUBE, (0, 0, 0), rot_a, rot_b)

    assert d == pytest.approx(3 - 2 * math.sqrt(2), rel=1e-12)
    assert (ax, ay, az) == pytest.approx((0, 0, 3 - math.sqrt(2)), abs=1e-12)
    assert (bx, by, bz) == pytest.approx((0, 0, math.sqrt(2)), abs=1e-12)


def test_gjk_distance_of_corner_to_face():
    corner_down = matrix(from_axis_angle(np.array([1.0, -1.0, 0]), math.acos(1 / math.sqrt(3))))
    d, *_ = gjk(CUBE, (0, 0, 4), CUBE, (0, 0, 0), corner_down, I3)

    assert d == pytest.approx(4 - math.sqrt(3) - 1, rel=1e-12)


def test_gjk_distance_matches_a_quadratic_program_on_random_hulls():
    rng = np.random.default_rng(7)
    for _ in range(20):
        a = rng.normal(size=(rng.integers(1, 10), 3))
        b = rng.normal(size=(rng.integers(1, 10), 3)) + 5 * rng.normal(size=3)
        na = len(a)

        def gap(x, a=a, b=b, na=na):
            diff = x[:na] @ a - x[na:] @ b
            return diff @ diff

        x0 = np.concatenate([np.full(na, 1 / na), np.full(len(b), 1 / len(b))])
        best = minimize(
            gap,
            x0,
            method="SLSQP",
            bounds=[(0, 1)] * len(x0),
            constraints=[
                {"type": "eq", "fun": lambda x, na=na: x[:na].sum() - 1},
                {"type": "eq", "fun": lambda x, na=na: x[na:].sum() - 1},
            ],
            options={"ftol": 1e-16, "maxiter": 1000},
        )
        d, *_ = gjk(a, (0, 0, 0), b, (0, 0, 0))
        # SLSQP may end a hair outside its equality constraints, below the true minimum; its
        # weights made feasible give a pair of hull points, whose gap bounds the distance above.
        x = np.clip(best.x, 0, None)
        x[:na] /= x[:na].sum()
        x[na:] /= x[na:].sum()
        qp = math.sqrt(gap(x))
        # GJK stops once |v|^2 - v.w <= eps |v|^2; as v.w/|v| <= distance, |v| <= distance/(1-eps).
        assert d == pytest.approx(qp, rel=1e-6)
        assert d <= qp / (1 - _REL_EPS) * (1 + 1e-14)


def test_gjk_reports_intersecting_hulls_as_distance_zero():
    d, *_ = gjk(CUBE, (0.5, 0.2, 1.0), CUBE, (0, 0, 0))

    assert d == 0.0


def patch(a, pos_a, b, pos_b, rot_a=I3, rot_b=I3):
    d, ax, ay, az, bx, by, bz = gjk(a, pos_a, b, pos_b, rot_a, rot_b)
    return contact_patch(
        a, core(a, pos_a, rot_a), b, core(b, pos_b, rot_b), (ax, ay, az), (bx, by, bz), 1e-3, scratch()
    )


def test_patch_of_offset_parallel_faces_is_the_overlap_rectangle_centroid():
    load, _, cx, cy, cz, s_uu, s_uw, s_ww = patch(CUBE, (0, 0, 2.5), CUBE, (0.3, 0.2, 0))

    assert load == pytest.approx(1.7 * 1.8 * 1e-3, rel=1e-9)  # area x uniform depth
    assert (cx, cy, cz) == pytest.approx((0.15, 0.1, 1.25), abs=1e-12)
    # second moments of the 1.7 x 1.8 rectangle per unit area: side^2 / 12 (axes may be swapped)
    assert sorted([s_uu, s_ww]) == pytest.approx(sorted([1.7**2 / 12, 1.8**2 / 12]), rel=1e-9)
    assert s_uw == pytest.approx(0.0, abs=1e-12)


def test_patch_of_an_edge_on_a_face_is_the_middle_of_the_edge_part_above_the_face():
    edge_down = matrix(from_axis_angle(np.array([1.0, 0, 0]), math.pi / 4))
    area, length, cx, cy, cz, *_ = patch(CUBE, (1.5, 0.0, 3.0), CUBE, (0, 0, 0), edge_down, I3)

    # The lower edge runs along x from 0.5 to 2.5; above the face (x <= 1) it is [0.5, 1].
    assert area == 0.0
    assert length == pytest.approx(0.5 * 1e-3, rel=1e-6)  # length x depth
    assert (cx, cy) == pytest.approx((0.75, 0.0), abs=1e-12)
    assert cz == pytest.approx(0.5 * (1 + 3 - math.sqrt(2)), abs=1e-12)


def test_patch_of_a_corner_on_a_face_is_the_corner():
    corner_down = matrix(from_axis_angle(np.array([1.0, -1.0, 0]), math.acos(1 / math.sqrt(3))))
    area, length, cx, cy, cz, *_ = patch(CUBE, (0.2, 0.1, 4), CUBE, (0, 0, 0), corner_down, I3)

    assert area == 0.0
    assert length == 0.0
    assert (cx, cy) == pytest.approx((0.2, 0.1), abs=1e-12)


def test_shrinking_a_box_moves_every_face_in_by_the_rounding():
    core = shrink_convex(CUBE * [0.07, 0.035, 0.004], 0.002)

    assert np.sort(np.abs(core), axis=0)[0] == pytest.approx([0.068, 0.033, 0.002], abs=1e-12)
    assert len(core) == 8


def test_a_rounding_thicker_than_the_piece_is_refused():
    with pytest.raises(PolyhedronError, match="smaller rounding"):
        shrink_convex(CUBE * [0.07, 0.035, 0.004], 0.004)


def test_mass_centre_and_inertia_equal_trimeshs():
    mesh = trimesh.creation.cylinder(radius=0.02, height=0.01, sections=24)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.4, [1, 2, 3]))
    mesh.apply_translation([0.1, -0.2, 0.3])
    density = 1500.0

    poly = make_polyhedron(mesh, density=density)

    reference = trimesh.Trimesh(mesh.vertices, mesh.faces)
    reference.density = density
    assert poly.mass == pytest.approx(reference.mass, rel=1e-12)
    assert poly.com == pytest.approx(reference.center_mass, abs=1e-15)
    tensor = poly.axes @ np.diag(poly.inertia) @ poly.axes.T
    assert tensor == pytest.approx(reference.moment_inertia, rel=1e-10, abs=1e-16)
    # The rounding defaults to a quarter of the thinnest dimension; the core lies r inside.
    assert poly.rounding == pytest.approx(0.0025, rel=1e-9)
    depth = trimesh.proximity.signed_distance(mesh, poly.com + poly.core @ poly.axes.T)
    assert depth.min() == pytest.approx(poly.rounding, rel=1e-6)


def distances_to_hull(points, vertices):
    """Each point's distance to the convex hull of vertices, from the hull's triangles (trimesh's
    closest point on a triangle; 0 inside), independently of GJK."""
    hull = trimesh.convex.convex_hull(vertices)
    triangles = hull.triangles
    pairs_t = np.repeat(triangles[None], len(points), axis=0).reshape(-1, 3, 3)
    pairs_p = np.repeat(points, len(triangles), axis=0)
    gaps = np.linalg.norm(trimesh.triangles.closest_point(pairs_t, pairs_p) - pairs_p, axis=1)
    gaps = gaps.reshape(len(points), len(triangles)).min(axis=1)
    offsets = np.sum(hull.face_normals * triangles[:, 0], axis=1)
    inside = (hull.face_normals @ points.T - offsets[:, None]).max(axis=0)
    return np.where(inside <= 0.0, 0.0, gaps)


def full_cores():
    """(name, full core, rounding) of every piece of the catalogue's items."""
    for kind, spec in CATALOGUE.items():
        hulls = [np.asarray(trimesh.convex.convex_hull(p.vertices).vertices) for p in spec.pieces()]
        rounding = ROUNDING_FRACTION * min(thinnest_dimension(h) for h in hulls)
        for k, hull in enumerate(hulls):
            yield f"{kind}-{k}", shrink_convex(hull, rounding), rounding


@pytest.mark.parametrize("fraction", [0.1, 0.2, 0.3])
def test_a_simplified_core_lies_within_its_tolerance_of_the_full_core(fraction):
    rng = np.random.default_rng(7)
    clouds = []  # scanned-like cores without symmetry: 300 points on a random ellipsoid
    for k in range(3):
        points = rng.normal(size=(300, 3))
        points *= rng.uniform(0.01, 0.05, size=3) / np.linalg.norm(points, axis=1)[:, None]
        clouds.append((f"cloud-{k}", np.asarray(trimesh.convex.convex_hull(points).vertices), 0.05))
    for name, full, rounding in [*full_cores(), *clouds]:
        rows = simplify_core(full, fraction * rounding)

        kept = full[rows]
        assert len(np.unique(rows)) == len(rows) <= 48, name
        # The kept vertices are the core's own, so their hull lies inside it, and the Hausdorff
        # distance is the furthest full-core vertex's distance from the kept hull.
        hausdorff = distances_to_hull(full, kept).max()
        assert hausdorff <= fraction * rounding * (1 + 1e-9), name
        assert len(rows) < 48, name  # the tolerance binds, not the most vertices kept
    # A phone's 104 core vertices come down to 40 at 0.1 r (24 at 0.3 r), its top and bottom
    # outlines alike (the faces stay flat and parallel).
    name, full, rounding = next(full_cores())
    kept = full[simplify_core(full, fraction * rounding)]
    assert len(full) == 104
    assert len(kept) == {0.1: 40, 0.2: 40, 0.3: 24}[fraction]
    top, bottom = kept[kept[:, 2] > 0], kept[kept[:, 2] < 0]
    assert len(top) == len(bottom)
    np.testing.assert_allclose(np.sort(top[:, :2], axis=0), np.sort(bottom[:, :2], axis=0), atol=1e-12)


def test_a_tolerance_that_needs_more_than_48_vertices_keeps_at_most_48_symmetric_ones():
    for name, full, rounding in full_cores():
        rows = simplify_core(full, 1e-3 * rounding)

        assert len(rows) <= 48, name
        kept = full[rows]
        if name == "smartphone-0":  # the next group of 16 (4 corners, 2 faces, 2 sides) would not fit
            assert len(kept) == 40
            assert np.sum(kept[:, 2] > 0) == np.sum(kept[:, 2] < 0) == 20


def test_a_simplified_core_keeps_the_mesh_mass_properties_and_rounding():
    spec = CATALOGUE["camera"]
    full = make_polyhedron(spec.mesh(), mass=spec.mass, pieces=spec.pieces(), core_tolerance=0.0)
    simple = make_polyhedron(spec.mesh(), mass=spec.mass, pieces=spec.pieces(), core_tolerance=0.1)

    assert list(full.piece_count) == [48, 48]
    assert list(simple.piece_count) == [8, 32]
    for key in ("mass", "volume", "rounding"):
        assert getattr(simple, key) == getattr(full, key), key
    for key in ("inertia", "com", "axes"):
        np.testing.assert_array_equal(getattr(simple, key), getattr(full, key), err_msg=key)


def test_a_non_convex_mesh_is_decomposed_into_convex_pieces_of_its_volume():
    # An L made of two boxes (a manifold union): CoACD must split it.
    a = trimesh.creation.box((0.06, 0.02, 0.02))
    b = trimesh.creation.box((0.02, 0.06, 0.02))
    b.apply_translation([0.02, 0.02, 0])
    mesh = trimesh.boolean.union([a, b], engine="manifold")

    pieces = convex_pieces(mesh)

    assert len(pieces) >= 2
    assert all(p.is_convex for p in pieces)
    assert sum(p.volume for p in pieces) == pytest.approx(mesh.volume, rel=0.02)


def test_a_scanned_convex_item_stays_one_piece_and_a_camera_does_not():
    # Scan noise (0.05 mm on a 146 mm phone) makes the mesh non-convex by a quarter of a millimetre,
    # far inside CONVEX_TOLERANCE; the camera's corner beside its lens barrel is 8 mm deep.
    phone = CATALOGUE["smartphone"].mesh().subdivide().subdivide()
    phone.vertices += np.random.default_rng(0).normal(scale=0.05e-3, size=phone.vertices.shape)
    size = float(np.linalg.norm(phone.extents))
    assert not phone.is_convex
    assert 0 < convex_departure(phone) < 0.25 * CONVEX_TOLERANCE * size

    assert convex_pieces(phone) == [phone]
    camera = CATALOGUE["camera"].mesh()
    assert convex_departure(camera) > 5 * CONVEX_TOLERANCE * float(np.linalg.norm(camera.extents))
    assert len(convex_pieces(camera)) >= 2


def test_rounded_box_core_and_reach():
    box = Polyhedron.box((0.04, 0.03, 0.01), 0.002, 1000.0)

    assert box.core.max(axis=0) == pytest.approx([0.018, 0.013, 0.003])
    assert box.piece_reach(0) == pytest.approx(math.sqrt(0.018**2 + 0.013**2 + 0.003**2) + 0.002)
    assert box.mass == pytest.approx(1000 * 0.04 * 0.03 * 0.01)


def test_a_phones_top_and_bottom_faces_are_runs_of_rows_going_round_them():
    spec = CATALOGUE["smartphone"]
    phone = make_polyhedron(spec.mesh(), mass=spec.mass, pieces=spec.pieces())
    core = phone.core

    assert len(core) == 40
    for rows, outward in ((range(0, 20), -1.0), (range(20, 40), 1.0)):
        face = core[list(rows)]
        assert np.ptp(face[:, 2]) < 1e-12  # one face ...
        for k in range(20):  # ... gone round counter-clockwise about its outward normal
            a, b, c = face[k - 1], face[k], face[(k + 1) % 20]
            assert outward * np.cross(b - a, c - b)[2] > 0.0


def test_a_cores_row_order_keeps_its_vertices():
    rng = np.random.default_rng(3)
    for points in (CUBE, rng.normal(size=(30, 3)), np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])):
        order = face_loop_order(points)
        assert sorted(order.tolist()) == list(range(len(points)))
    cube = face_loop_order(CUBE)  # two opposite faces of four, each gone round
    for face in (CUBE[cube[:4]], CUBE[cube[4:]]):
        normal = np.cross(face[1] - face[0], face[2] - face[1])
        assert np.all(np.abs((face - face[0]) @ normal) < 1e-12)
        for k in range(4):
            assert np.dot(np.cross(face[k] - face[k - 1], face[(k + 1) % 4] - face[k]), normal) > 0.0


def test_an_outlines_hull_is_the_sorted_hull_bit_for_bit():
    """``_hull2`` of points given as a convex outline (either way round, from any corner) takes
    them as they are (``_outline``) and equals the sorted chain's hull of the same points
    shuffled, to the bit; a star or a dent goes to the chain."""
    rng = np.random.default_rng(11)
    taken = 0
    for trial in range(300):
        m = int(rng.integers(3, 25))
        angles = np.sort(rng.uniform(0.0, 2 * np.pi, m))
        if np.min(np.diff(np.r_[angles, angles[0] + 2 * np.pi])) < 0.05:
            continue
        centre = rng.uniform(-0.5, 0.5, 2)
        radii = rng.uniform(1e-3, 5e-2, 2)
        pts = np.zeros((128, 3))
        pts[:m, 0] = centre[0] + radii[0] * np.cos(angles)
        pts[:m, 1] = centre[1] + radii[1] * np.sin(angles)
        pts[:m, 2] = rng.uniform(0.0, 1e-4, m)
        if trial % 2:
            pts[:m] = pts[:m][::-1]
        pts[:m] = np.roll(pts[:m], int(rng.integers(m)), axis=0)
        eps = 1e-12
        shuffled = pts.copy()
        shuffled[:m] = pts[rng.permutation(m)]
        sorted_hull = np.zeros((128, 3))
        h = _hull2(shuffled, m, sorted_hull, eps)
        outline = np.zeros((128, 3))
        assert _outline(pts.copy(), m, outline, eps) == m
        assert h == m
        np.testing.assert_array_equal(outline[:m], sorted_hull[:m])
        taken += 1
    assert taken > 100
    star = np.zeros((128, 3))  # a pentagram's corners: every turn the same way, twice round
    star[:5, :2] = [[np.cos(a), np.sin(a)] for a in 4 * np.pi / 5 * np.arange(5)]
    assert _outline(star, 5, np.zeros((128, 3)), 1e-12) == 0
    dent = np.zeros((128, 3))
    dent[:4, :2] = [[0, 0], [1, 0], [0.2, 0.2], [0, 1]]
    assert _outline(dent, 4, np.zeros((128, 3)), 1e-12) == 0
    assert _hull2(dent, 4, np.zeros((128, 3)), 1e-12) == 3
