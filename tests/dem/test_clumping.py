"""Sphere clumps from meshes: mass properties from the mesh (issue 3, test 6), inscribed spheres,
the reported approximation error, resolution, cache."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from dem import clumping
from dem.clumping import _N_COVER_SAMPLES, ClumpError, clump_fit, deform_clump, make_clump, signed_distance


def _centres_in_mesh_frame(clump):
    return clump.com + clump.offset @ clump.axes.T


@pytest.fixture(scope="module")
def l_bracket():
    """An L-shaped, asymmetric solid in a random pose: no symmetry hides a wrong COM or tensor."""
    long_arm = trimesh.creation.box((0.08, 0.02, 0.015))
    short_arm = trimesh.creation.box((0.02, 0.05, 0.015))
    short_arm.apply_translation([0.03, 0.025, 0.0])
    solid = trimesh.boolean.union([long_arm, short_arm], engine="manifold")
    pose = trimesh.transformations.random_rotation_matrix(np.random.default_rng(7).random(3))
    pose[:3, 3] = [0.3, -0.1, 0.05]
    solid.apply_transform(pose)
    return solid


@pytest.fixture(scope="module")
def phone():
    return trimesh.creation.box((0.146, 0.071, 0.008))


def test_clump_mass_com_and_inertia_equal_trimesh_for_an_asymmetric_mesh(l_bracket):
    mass = 0.25

    clump = make_clump(l_bracket, mass=mass, n_spheres=10, cache_dir=False)

    reference = l_bracket.copy()
    reference.density = mass / reference.volume
    assert clump.mass == pytest.approx(mass)
    assert clump.volume == pytest.approx(reference.volume, rel=1e-12)
    np.testing.assert_allclose(clump.com, reference.center_mass, atol=1e-12)
    tensor = clump.axes @ np.diag(clump.inertia) @ clump.axes.T
    np.testing.assert_allclose(tensor, reference.moment_inertia, rtol=1e-9, atol=1e-14)
    assert np.linalg.det(clump.axes) == pytest.approx(1.0)


def test_signed_distance_equals_the_analytic_box_distance():
    half = np.array([0.05, 0.02, 0.01])
    box = trimesh.creation.box(2 * half)
    points = np.random.default_rng(0).uniform(-1.5, 1.5, (400, 3)) * half

    distance = signed_distance(box, points)

    inside = (np.abs(points) < half).all(axis=1)
    depth = (half - np.abs(points)).min(axis=1)
    outside = np.linalg.norm(np.maximum(np.abs(points) - half, 0.0), axis=1)
    np.testing.assert_allclose(distance[inside], depth[inside], atol=1e-12)
    np.testing.assert_allclose(distance[~inside], -outside[~inside], atol=1e-12)


def test_spheres_are_inscribed_in_the_mesh(l_bracket):
    clump = make_clump(l_bracket, density=1000.0, n_spheres=20, cache_dir=False)

    depth = signed_distance(l_bracket, _centres_in_mesh_frame(clump))

    assert np.all(depth >= clump.radius * (1.0 - 1e-5))


def test_one_sphere_in_a_cube_has_the_analytic_corner_gap():
    side = 0.04
    cube = trimesh.creation.box((side, side, side))

    clump = make_clump(cube, density=1000.0, n_spheres=1, cache_dir=False)

    assert clump.radius[0] == pytest.approx(side / 2, rel=1e-2)
    np.testing.assert_allclose(clump.offset[0], 0.0, atol=1e-3 * side)
    corner_gap = side * np.sqrt(3) / 2 - side / 2
    assert clump.max_error == pytest.approx(corner_gap, rel=0.02)


PHONE = (0.146, 0.071, 0.008)


def face_gap_lower_bound(n_spheres: int, length: float, width: float, thickness: float) -> float:
    """The smallest largest gap any n inscribed spheres can leave on a slab's face.

    A sphere of radius r_j <= t/2 whose centre lies h >= r_j below the face brings a face point
    at horizontal distance d within g of its surface only if sqrt(d^2 + h^2) <= r_j + g, i.e.
    d^2 <= g^2 + 2 g r_j <= g^2 + g t: a disc of area pi (g^2 + g t). n such discs must cover
    the face (area L W), so g >= sqrt(t^2/4 + L W / (n pi)) - t/2.
    """
    half = thickness / 2
    return float(np.sqrt(half**2 + length * width / (n_spheres * np.pi)) - half)


def measured_gap(mesh, clump, samples: int = 100_000) -> float:
    """The largest distance from the mesh surface to the spheres' envelope, on our own sample."""
    points = np.vstack([trimesh.sample.sample_surface(mesh, samples, seed=11)[0], mesh.vertices])
    centres = _centres_in_mesh_frame(clump)
    gaps = np.full(len(points), np.inf)
    for centre, radius in zip(centres, clump.radius, strict=True):
        gaps = np.minimum(gaps, np.linalg.norm(points - centre, axis=1) - radius)
    return float(gaps.max())


def test_phone_at_default_resolution_is_a_modest_clump_with_its_thickness_and_outline(phone):
    clump = make_clump(phone, mass=0.17, cache_dir=False)

    # A gap this far from zero never stops the cover early: every allowed sphere is used.
    assert clump.n_spheres == clumping.DEFAULT_N_SPHERES
    assert clump.radius.max() == pytest.approx(0.004, rel=2e-3)
    low = (clump.offset - clump.radius[:, None]).min(axis=0)
    high = (clump.offset + clump.radius[:, None]).max(axis=0)
    envelope = np.sort(high - low)
    # Thickness is exact; the outline's extremes come within a few mm of the 146 x 71 mm edges.
    assert envelope[0] == pytest.approx(0.008, rel=2e-3)
    np.testing.assert_allclose(envelope[1:], [0.071, 0.146], atol=0.004)
    # The gap in the middle of the faces between spheres of radius 4 mm is what remains: no less
    # than geometry allows, and what an independent sample of the surface finds.
    assert clump.max_error >= face_gap_lower_bound(clump.n_spheres, *PHONE)
    assert clump.max_error == pytest.approx(measured_gap(phone, clump), abs=SAMPLE_SPACING)


# Our 100,000 surface samples of the phone (area 0.0242 m^2) lie about 0.5 mm apart; two
# independent samplings of the same largest gap agree to about twice that.
SAMPLE_SPACING = 1e-3


# The README: "a 146 x 71 x 8 mm phone has a largest gap of about 25 / 15 / 11 / 6 mm at
# 12 / 24 / 40 / 100 spheres" (quoted to the millimetre).
@pytest.mark.slow
@pytest.mark.parametrize(("n_spheres", "readme_gap_mm"), [(12, 25), (24, 15), (40, 11), (100, 6)])
def test_phone_gaps_are_those_the_readme_quotes(phone, n_spheres, readme_gap_mm):
    clump = make_clump(phone, mass=0.17, n_spheres=n_spheres, cache_dir=False)

    gap = measured_gap(phone, clump)

    assert gap * 1e3 == pytest.approx(readme_gap_mm, abs=0.5 + SAMPLE_SPACING * 1e3)
    assert clump.max_error == pytest.approx(gap, abs=SAMPLE_SPACING)
    assert gap >= face_gap_lower_bound(n_spheres, *PHONE)


def test_more_spheres_give_a_smaller_error(phone):
    errors = [make_clump(phone, mass=0.17, n_spheres=n, cache_dir=False).max_error for n in (8, 24, 60)]

    assert errors[0] > errors[1] > errors[2]
    assert errors[2] >= face_gap_lower_bound(60, *PHONE)


def test_tolerance_mode_meets_the_tolerance_on_a_capsule_with_no_sphere_to_spare():
    radius, length, sections = 0.01, 0.06, 24
    capsule = trimesh.creation.capsule(height=length, radius=radius, count=[sections, sections])
    tolerance = 0.0005

    clump = make_clump(capsule, density=1000.0, tolerance=tolerance, cache_dir=False)
    one_fewer = make_clump(capsule, density=1000.0, n_spheres=clump.n_spheres - 1, cache_dir=False)

    # The cylinder is a 24-gon prism: corner lines at `radius`, faces at radius cos(pi/24), which
    # bounds every inscribed sphere. A sphere then brings a corner line within the tolerance over
    # an axial length of at most 2 sqrt((r_in + tol)^2 - radius^2) (5.8 mm): covering the 60 mm
    # of cylinder takes at least ceil(60 / 5.8) = 11 spheres.
    inscribed = radius * np.cos(np.pi / sections)
    reach = 2 * np.sqrt((inscribed + tolerance) ** 2 - radius**2)
    assert clump.n_spheres >= int(np.ceil(length / reach))
    # The cover stops at the first sphere count that meets the tolerance.
    assert one_fewer.max_error > tolerance
    # Between the fit's samples: a point's gap (distance to the spheres' envelope) changes no
    # faster than the point moves, so a surface point p has gap(p) <= tolerance + |p - q| with q
    # the nearest of the samples where the cover met the tolerance (dem.clumping's, seed 0).
    fitted = trimesh.sample.sample_surface(capsule, _N_COVER_SAMPLES, seed=0)[0]
    fitted = np.vstack([fitted, capsule.vertices])
    dense = trimesh.sample.sample_surface(capsule, 50_000, seed=7)[0]
    centres = clump.com + clump.offset @ clump.axes.T
    gap = np.maximum((cdist(dense, centres) - clump.radius).min(axis=1), 0.0)
    assert np.all(gap <= tolerance + cKDTree(fitted).query(dense)[0])


def test_impossible_tolerance_is_an_error_that_says_what_to_change(phone):
    with pytest.raises(ClumpError, match="larger tolerance"):
        make_clump(phone, mass=0.17, tolerance=1e-6, min_radius_fraction=0.9, cache_dir=False)


def test_resolution_arguments_are_checked(phone):
    with pytest.raises(ClumpError, match="not both"):
        make_clump(phone, mass=0.17, n_spheres=10, tolerance=0.001, cache_dir=False)
    with pytest.raises(ClumpError, match="n_spheres must be"):
        make_clump(phone, mass=0.17, n_spheres=0, cache_dir=False)


def test_cache_hit_returns_the_same_clump_without_fitting(phone, tmp_path, monkeypatch):
    # An empty memory cache first, so that the disk cache is written whatever ran before.
    monkeypatch.setattr(clumping, "_MEMORY_CACHE", {})
    first = make_clump(phone, mass=0.17, n_spheres=12, cache_dir=tmp_path, name="a")
    monkeypatch.setattr(clumping, "_MEMORY_CACHE", {})

    def refuse(*args, **kwargs):
        raise AssertionError("the clump was fitted again instead of read from the cache")

    monkeypatch.setattr(clumping, "_fit_spheres", refuse)

    second = make_clump(phone, mass=0.17, n_spheres=12, cache_dir=tmp_path, name="b")

    assert len(list(tmp_path.glob("*.npz"))) == 1
    np.testing.assert_array_equal(second.radius, first.radius)
    np.testing.assert_array_equal(second.offset, first.offset)
    assert second.max_error == first.max_error
    assert second.name == "b"


def test_cache_key_separates_resolution_and_mass(phone, tmp_path):
    make_clump(phone, mass=0.17, n_spheres=6, cache_dir=tmp_path)
    make_clump(phone, mass=0.17, n_spheres=7, cache_dir=tmp_path)
    heavier = make_clump(phone, mass=0.20, n_spheres=6, cache_dir=tmp_path)

    assert len(list(tmp_path.glob("*.npz"))) == 3
    assert heavier.mass == pytest.approx(0.20)


def test_deformed_clump_stays_inscribed_and_takes_the_new_mesh_mass_properties(l_bracket):
    clump = make_clump(l_bracket, mass=0.25, n_spheres=12, cache_dir=False)
    matrix = np.diag([1.03, 0.98, 1.01])
    stretched = l_bracket.copy()
    stretched.apply_transform(np.block([[matrix, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))

    variant = deform_clump(clump, matrix, stretched, mass=0.26)

    depth = signed_distance(stretched, _centres_in_mesh_frame(variant))
    assert np.all(depth >= variant.radius * (1.0 - 1e-5))
    reference = stretched.copy()
    reference.density = 0.26 / reference.volume
    np.testing.assert_allclose(variant.com, reference.center_mass, atol=1e-12)
    tensor = variant.axes @ np.diag(variant.inertia) @ variant.axes.T
    np.testing.assert_allclose(tensor, reference.moment_inertia, rtol=1e-9, atol=1e-14)
    fit = clump_fit(stretched, _centres_in_mesh_frame(variant), variant.radius)
    assert variant.max_error == pytest.approx(fit.max_error, rel=0.05)
