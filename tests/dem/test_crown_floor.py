"""The crowns' floor (``dem.crown.crown_floor``): a lower bound of the crowned distance that
``crowned_contact`` returns, from the cores' closest points alone, with which ``pair_geometry``
takes a pair as apart without the crowned contact (a shaken pile's edges and corners within the
roundings of another piece but held apart by the crowns).

The bound is the crowned distance's own algebra: the minimiser's heights above the supporting
planes are at least -slack, and each crown is at least kappa times the squared height of the centre
over the minimiser (``H - h``), less kappa h_c^2. A box standing on its edge right above another's
face centre is the case where the bound is the crowned distance: the minimiser is the edge's middle
over the foot of the lower box's centre.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.convex import SIMPLEX, gjk_distance, place, scratch
from dem.crown import crown_floor, crowned_contact
from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle, matrix
from dem.rounded_contact import pair_geometry

BOX = Polyhedron.box((0.04, 0.03, 0.01), 0.002, 1000.0)


def crown_of(shape: Polyhedron) -> tuple[float, float, float]:
    return tuple(float(c) for c in shape.crown(0))


def smartphone() -> Polyhedron:
    from dem.scenarios.feeder import make_items
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config("examples/feeder.toml")
    items = config.items.model_copy(update={"representation": "polyhedron", "counts": {"smartphone": 1}})
    return make_items(items, np.random.default_rng(0))[0].shape


def floor_and_crowned(shape_a, rot_a, pos_a, shape_b, rot_b, pos_b):
    """(d, the crowns' floor, the crowned distance) of two cores apart."""
    a = place(0, len(shape_a.core), rot_a, pos_a)
    b = place(0, len(shape_b.core), rot_b, pos_b)
    d, ax, ay, az, bx, by, bz = gjk_distance(shape_a.core, a, shape_b.core, b)
    crown_a, crown_b = crown_of(shape_a), crown_of(shape_b)
    tol = 4.0 * (crown_a[2] + crown_b[2])
    n = np.array([ax - bx, ay - by, az - bz]) / d
    floor = (
        d
        + crown_floor(shape_a.core, a, crown_a, (ax, ay, az), *n, tol)
        + crown_floor(shape_b.core, b, crown_b, (bx, by, bz), *(-n), tol)
    )
    crowned = crowned_contact(
        shape_a.core, a, crown_a, shape_b.core, b, crown_b, (ax, ay, az), (bx, by, bz), tol, scratch()
    )[0]
    return d, floor, crowned


def test_a_square_bar_on_its_edge_above_a_face_centre_has_the_crowned_distance_as_its_floor():
    # A square bar turned 45 degrees about its long axis (x), its lower edge 0.1 mm above the
    # box's top face, right below A's centre and above B's: the minimiser is the edge's middle,
    # over the foot of B's centre, where B's crown is 0.
    bar = Polyhedron.box((0.04, 0.02, 0.02), 0.002, 1000.0)
    half = bar.core.max(axis=0)[1]  # the core's half side across the bar
    rot = matrix(from_axis_angle(np.array([1.0, 0.0, 0.0]), math.pi / 4))
    box_top = BOX.core.max(axis=0)[2]
    pos_a = np.array([0.0, 0.0, box_top + 1e-4 + half * math.sqrt(2.0)])
    d, floor, crowned = floor_and_crowned(bar, rot, pos_a, BOX, np.eye(3), np.zeros(3))

    kappa, kappa_h2, _ = crown_of(bar)
    assert kappa_h2 == pytest.approx(kappa * half**2, rel=1e-12)
    assert d == pytest.approx(1e-4, rel=1e-9)
    assert crowned == pytest.approx(1e-4 + kappa * (2.0 * half**2 - half**2), rel=1e-9)
    # tight but for the allowance for a flat feature's fitted plane (dem.crown.flat_tolerance)
    assert floor == pytest.approx(crowned, abs=1e-9)
    assert floor <= crowned + 1e-15


def test_a_face_across_the_normal_adds_nothing_to_the_floor():
    # stacked boxes, faces parallel: the centres' heights are the inradii, the floor is d
    d, floor, crowned = floor_and_crowned(
        BOX, np.eye(3), np.array([0.01, 0.0, 0.0061]), BOX, np.eye(3), np.zeros(3)
    )
    assert d == pytest.approx(1e-4, rel=1e-9)
    assert floor == pytest.approx(d, abs=1e-9)
    assert crowned > floor


def random_rotation(rng, near_identity: bool):
    angle = rng.uniform(0.0, 0.05) if near_identity else rng.uniform(0.0, math.pi)
    return matrix(from_axis_angle(rng.normal(size=3), angle))


@pytest.mark.parametrize("shapes", ["phones", "phone and box"])
def test_the_floor_never_exceeds_the_crowned_distance(shapes):
    """Poses of two pieces whose cores lie within the roundings (where the crowned contact decides):
    any orientation, and nearly face on face; for each, the floor is at most the crowned distance,
    and where it clears the reach, ``pair_geometry`` answers apart as the crowned contact would."""
    phone = smartphone()
    shape_a, shape_b = (phone, phone) if shapes == "phones" else (phone, BOX)
    reach = shape_a.rounding + shape_b.rounding
    rng = np.random.default_rng(5)
    cleared = held_apart = tight = 0
    poses = 0
    while poses < 300:
        near_identity = poses % 3 == 0
        rot_a, rot_b = random_rotation(rng, near_identity), random_rotation(rng, near_identity)
        direction = rng.normal(size=3) * (np.array([0.3, 0.3, 1.0]) if near_identity else 1.0)
        direction /= np.linalg.norm(direction)
        # A moved out along the direction until the cores' distance is a random part of the
        # reach, or (every other pose) within the crowns' heights of it, where the floor can clear
        want = reach * (rng.uniform(0.0, 1.0) if poses % 2 else 1.0 - rng.uniform(0.0, 0.05))
        lo, hi = 0.0, 0.3
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            a = place(0, len(shape_a.core), rot_a, mid * direction)
            b = place(0, len(shape_b.core), rot_b, np.zeros(3))
            lo, hi = (mid, hi) if gjk_distance(shape_a.core, a, shape_b.core, b)[0] < want else (lo, mid)
        pos_a = hi * direction
        d, floor, crowned = floor_and_crowned(shape_a, rot_a, pos_a, shape_b, rot_b, np.zeros(3))
        if not 0.0 < d < reach:
            continue
        poses += 1
        assert floor <= crowned + 1e-15, (poses, d, floor, crowned)
        tight += crowned - floor < 0.1 * (crowned - d + 1e-12)
        held_apart += crowned > reach
        if floor > reach:
            cleared += 1
            assert crowned >= reach
            a = place(0, len(shape_a.core), rot_a, pos_a)
            b = place(0, len(shape_b.core), rot_b, np.zeros(3))
            delta = pair_geometry(
                shape_a.core,
                a,
                shape_a.rounding,
                crown_of(shape_a),
                shape_b.core,
                b,
                shape_b.rounding,
                crown_of(shape_b),
                np.zeros(3),
                np.zeros(SIMPLEX, np.int32),
                scratch(),
            )[0]
            assert reach - crowned <= delta <= 0.0
    # the floor does the crowned contact's work for a good share of the pairs held apart
    assert cleared > 0.3 * held_apart and held_apart > 30, (cleared, held_apart)
    assert tight > 30
