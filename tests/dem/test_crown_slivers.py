"""Crowned contacts over features without area (``dem/crown.py``, commit a11dfa0): the feeder's
quick run with polyhedra once went invalid from a crowned distance of -13.9 m between two phone
cores, found by minimising the crowned gap off the features.

* Two boxes whose faces, seen along the normal, meet only at a corner: the clipped overlap of
  the faces is that corner (several coincident points, no area), so the crowned gap's minimiser is
  the corner, and the crowned distance is D = d + kappa_a |c - p_a|^2 + kappa_b |c - p_b|^2 with
  |c - p|^2 the corner's squared distance from the foot of each centre on its face (the crown
  ``phi = kappa (|x - p|^2 - h^2)``). A polygon without area taken for 'inside' gave the free
  minimum instead, outside both faces.
* A feature hull without area (collinear points, or a sliver whose vertices are not on one plane)
  gets no plane: a fit across its width extrapolates its height with a slope of height over width.
  Nor does a curved patch of vertices off one plane; a face gets its plane.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.convex import SIMPLEX, place, scratch
from dem.crown import _height_fit
from dem.polyhedra import Polyhedron
from dem.rounded_contact import pair_geometry

ROUNDING = 2.0**-9  # m; dyadic sizes, so that the cores' corners meet exactly in floating point
CORE_A, CORE_B = np.array([2.0**-5, 2.0**-6, 2.0**-8]), np.array([2.0**-6, 2.0**-7, 2.0**-8])  # half sides
GAP = 2.0**-10  # between the cores, less than the two roundings


def box(core_half: np.ndarray) -> Polyhedron:
    return Polyhedron.box(tuple(2 * (core_half + ROUNDING)), ROUNDING, 1000.0)


def test_boxes_whose_faces_meet_only_at_a_corner_touch_at_that_corner():
    a, b = box(CORE_A), box(CORE_B)
    assert np.array_equal(a.core.max(axis=0), CORE_A) and np.array_equal(b.core.max(axis=0), CORE_B)
    crown_a, crown_b = (tuple(float(c) for c in shape.crown(0)) for shape in (a, b))
    # A above B, shifted so that A's lower left corner stands on B's upper right one.
    pos_a = np.array([CORE_A[0] + CORE_B[0], CORE_A[1] + CORE_B[1], CORE_A[2] + CORE_B[2] + GAP])
    core_a = place(0, len(a.core), np.eye(3), pos_a)
    core_b = place(0, len(b.core), np.eye(3), np.zeros(3))

    delta, d, nx, ny, nz, cx, cy, cz, *_ = pair_geometry(
        a.core,
        core_a,
        a.rounding,
        crown_a,
        b.core,
        core_b,
        b.rounding,
        crown_b,
        np.zeros(3),
        np.zeros(SIMPLEX, np.int32),
        scratch(),
    )

    kappa_a, kappa_b = crown_a[0], crown_b[0]
    crowned = GAP + kappa_a * (CORE_A[0] ** 2 + CORE_A[1] ** 2) + kappa_b * (CORE_B[0] ** 2 + CORE_B[1] ** 2)
    assert d == GAP
    assert (cx, cy) == pytest.approx((CORE_B[0], CORE_B[1]), abs=1e-12)
    assert delta == pytest.approx(2 * ROUNDING - crowned, rel=1e-12)
    assert (nx, ny, nz) == pytest.approx((0.0, 0.0, 1.0), abs=1e-12)


TOL = 1e-4


def hull(points) -> np.ndarray:
    """A feature hull as ``dem.convex.feature_hulls`` leaves it: (u, w, tol - height)."""
    pts = np.zeros((8, 3))
    pts[: len(points)] = [(u, w, TOL - h) for u, w, h in points]
    return pts


@pytest.mark.parametrize(
    "points",
    [
        [(0.0, 0.0, 0.0), (0.01, 0.0, 2e-5), (0.02, 0.0, 1e-5)],  # collinear
        [(0.0, 0.0, 0.0), (0.01, -1e-9, 0.0), (0.02, 0.0, 0.0), (0.01, 1e-9, 1e-5)],  # a sliver
    ],
    ids=["collinear", "sliver"],
)
def test_a_feature_hull_without_area_is_not_fitted_with_a_plane(points):
    alpha, beta_u, beta_w, flat = _height_fit(hull(points), len(points), TOL)

    heights = [h for _, _, h in points]
    assert not flat  # the contact falls back to the closest points
    assert all(math.isfinite(v) for v in (alpha, beta_u, beta_w))
    # The fitted height a millimetre off the feature stays within its vertices' heights.
    for u, w in [(0.01, 1e-3), (0.01, -1e-3)]:
        assert min(heights) - 1e-12 <= alpha + beta_u * u + beta_w * w <= max(heights) + 1e-12


def test_a_face_gets_its_plane_and_a_curved_patch_is_not_flat():
    face = [(0.0, 0.0, 0.0), (0.01, 0.0, 1e-5), (0.01, 0.01, 3e-5), (0.0, 0.01, 2e-5)]  # h = u/1000 + w/500
    curved = [(0.0, 0.0, 0.0), (0.01, 0.0, 0.0), (0.01, 0.01, 0.0), (0.0, 0.01, 1e-5)]

    alpha, beta_u, beta_w, flat = _height_fit(hull(face), 4, TOL)
    assert flat and (alpha, beta_u, beta_w) == pytest.approx((0.0, 1e-3, 2e-3), abs=1e-12)
    assert not _height_fit(hull(curved), 4, TOL)[3]  # the contact falls back to the closest points
