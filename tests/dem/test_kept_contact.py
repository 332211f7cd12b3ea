"""A lasting contact kept from its last full evaluation (dem/kept_contact.py): within its bound of
the full geometry, first-order exact, refused beyond its bound, and a resting stack served from
it at the analytic overlaps."""

from __future__ import annotations

import numpy as np
import pytest

from dem.contact import ContactParams, wall_stiffness
from dem.convex import SIMPLEX, place, scratch
from dem.crown import crown_radius
from dem.kept_contact import APART_FRACTION, KEEP_FRACTION, KEPT, keep_apart, keep_contact, kept_contact
from dem.neighbours import N_PAIRS
from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle, matrix
from dem.rounded_contact import pair_geometry
from dem.simulation import Simulation
from dem.walls import WallMesh

G = 9.81
SIZE = (0.04, 0.03, 0.01)
BOX = Polyhedron.box(SIZE, 0.002, 1000.0)
CROWN = tuple(float(c) for c in BOX.crown(0))
REACH = float(np.linalg.norm(BOX.core, axis=1).max()) + 2 * BOX.rounding
EYE = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
RADII = (crown_radius(CROWN), crown_radius(CROWN))  # the osculating spheres, as dem/forces.py keeps them


def full(rot_b, pos_b):
    """The full geometry of BOX B at (rot_b, pos_b) on BOX A at the origin: (delta, n, point),
    the point as the force pass takes it (equal roundings: the cores' midpoint)."""
    axis, simplex = np.zeros(3), np.zeros(SIMPLEX, dtype=np.int32)
    a = place(0, 8, np.eye(3), np.zeros(3))
    b = place(0, 8, rot_b, pos_b)
    r = BOX.rounding
    out = pair_geometry(BOX.core, a, r, CROWN, BOX.core, b, r, CROWN, axis, simplex, scratch())
    return out[0], np.array(out[2:5]), np.array(out[5:8])


# B above A (n from B to A points down), pressed 20 um into A's top face: face on face offset,
# a tilted face, an edge and a corner.
POSES = {
    "face-on-face": (np.eye(3), (0.011, -0.006)),
    "tilted-face": (matrix(from_axis_angle((1, 0.3, 0), 0.02)), (0.004, 0.002)),
    "edge-on-face": (matrix(from_axis_angle((1, 0, 0), np.pi / 4)), (0.0, 0.003)),
    "corner-on-face": (matrix(from_axis_angle((1, 1, 0.4), 0.9)), (0.003, -0.002)),
}


def resting_pose(name):
    """POSES[name] at the height of first touch (bisection) less 20 um."""
    rot, (x, y) = POSES[name]
    lo, hi = 0.0, 0.08
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if full(rot, np.array([x, y, mid]))[0] > 0 else (lo, mid)
    return np.asarray(rot, float), np.array([x, y, lo - 20e-6])


def kept_row(rot, pos):
    """A kept row of the full contact at (rot, pos), and that contact."""
    delta, n, point = full(rot, pos)
    assert delta > 0
    kept = np.zeros((1, KEPT))
    frame, origin = tuple(rot.ravel()), tuple(pos)
    n, point, moments = tuple(n), tuple(point), (0.0,) * 3
    keep_contact(kept, 0, (1.0, 2.0), REACH, EYE, (0.0,) * 3, frame, origin, delta, n, point, moments, RADII)
    return kept, delta


def moved(rot, pos, rng, size):
    """The pose moved by a random rigid motion whose bound (dem.kept_contact) is about ``size``:
    a translation of size / 2 and a turn that moves the reach by size / 2."""
    step = rng.normal(size=3)
    step *= 0.5 * size / np.linalg.norm(step)
    turn = matrix(from_axis_angle(rng.normal(size=3), 0.5 * size / REACH / np.sqrt(2)))
    return turn @ rot, pos + step


def bound(rot0, pos0, rot, pos):
    """dem.kept_contact's motion bound of B relative to A (A at rest at the origin)."""
    return np.linalg.norm(pos - pos0) + REACH * np.linalg.norm(rot - rot0)


@pytest.mark.parametrize("name", sorted(POSES))
def test_a_kept_contact_is_first_order_exact_and_within_twice_its_bound(name):
    rot0, pos0 = resting_pose(name)
    kept, delta0 = kept_row(rot0, pos0)
    allowed = KEEP_FRACTION * delta0
    rng = np.random.default_rng(7)
    for _ in range(60):
        rot, pos = moved(rot0, pos0, rng, 0.95 * allowed)
        motion = bound(rot0, pos0, rot, pos)
        assert motion <= allowed
        served, delta, nx, ny, nz, cx, cy, cz = kept_contact(
            kept, 0, (1.0, 2.0), EYE, (0.0, 0.0, 0.0), tuple(rot.ravel()), tuple(pos)
        )
        assert served
        exact, n, _ = full(rot, pos)
        # the stated bound (B's sphere centre turns with B at R_b beyond the reach), and first
        # order: an error of a sign or a frame is of the order of the motion itself
        assert abs(delta - exact) <= 2 * motion + RADII[1] * np.linalg.norm(rot - rot0)
        assert abs(delta - exact) <= 0.02 * motion
        assert np.dot((nx, ny, nz), n) > 1 - 1e-9


@pytest.mark.parametrize("name", sorted(POSES))
def test_a_pair_moved_beyond_the_bound_or_another_pair_is_not_served(name):
    rot0, pos0 = resting_pose(name)
    kept, delta0 = kept_row(rot0, pos0)
    allowed = KEEP_FRACTION * delta0
    frame0 = tuple(rot0.ravel())
    rng = np.random.default_rng(3)
    for _ in range(20):
        rot, pos = moved(rot0, pos0, rng, 2.5 * allowed)
        assert bound(rot0, pos0, rot, pos) > allowed
        assert not kept_contact(kept, 0, (1.0, 2.0), EYE, (0.0, 0.0, 0.0), tuple(rot.ravel()), tuple(pos))[0]
    assert kept_contact(kept, 0, (1.0, 2.0), EYE, (0.0, 0.0, 0.0), frame0, tuple(pos0))[0]
    assert not kept_contact(kept, 0, (1.0, 3.0), EYE, (0.0, 0.0, 0.0), frame0, tuple(pos0))[0]


def kept_rows_used(sim, steps):
    """(served, full) touching piece contacts over ``steps`` single steps: a kept row unchanged by
    a step was served, a rewritten one evaluated in full."""
    served = evaluated = 0
    for _ in range(steps):
        lists = sim._lists
        before = [lists.pairs.kept.copy(), lists.wall_pairs.kept.copy()]
        sim.run(sim.t + sim.dt, chunk_time=sim.dt)
        for old, pairs in zip(before, (sim._lists.pairs, sim._lists.wall_pairs), strict=True):
            for p in range(pairs.count[N_PAIRS]):
                if pairs.delta[p] > 0:
                    same = np.array_equal(old[p], pairs.kept[p])
                    served += same
                    evaluated += not same
    return served, evaluated


def stacked_boxes(params, offset, gap):
    """BOX flat on the floor and another above it, ``offset`` off its centre along x and ``gap``
    above its top face."""
    sim = Simulation(params, gravity=(0, 0, -G), domain_min=(-1, -1, -0.5), domain_max=(1, 1, 1))
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 2.0))
    half = 0.5 * SIZE[2]
    sim.add_body(BOX, (0.0, 0.0, half))
    sim.add_body(BOX, (offset, 0.0, 3 * half + gap))
    return sim


def test_a_resting_stack_is_served_from_kept_contacts_at_the_analytic_overlaps():
    # Two boxes stacked flat on the floor, the top one 6 mm off centre, at rest: their contact
    # carries m g (K = E D / 2 between like bodies), the floor 2 m g. (The crown lowers an
    # off-centre box by its phi at the contact, so the overlaps are read from the contacts.)
    params = ContactParams(E=1e6, nu=0.3, e=0.3, mu=0.5)
    sim = stacked_boxes(params, 0.006, 0.0001)

    report = sim.run(0.8)

    assert report.ok, report.message
    served, evaluated = kept_rows_used(sim, 200)
    assert served + evaluated == 2 * 200
    assert served >= 0.9 * (served + evaluated)
    k_wall = wall_stiffness(params.E, BOX.equivalent_diameter, params.E)
    k_pair = params.E * BOX.equivalent_diameter / 2
    (between,) = [d for d in sim._lists.pairs.delta[: sim._lists.pairs.count[N_PAIRS]] if d > 0]
    (bottom,) = [d for d in sim._lists.wall_pairs.delta[: sim._lists.wall_pairs.count[N_PAIRS]] if d > 0]
    assert between == pytest.approx(BOX.mass * G / k_pair, rel=0.02)
    assert bottom == pytest.approx(2 * BOX.mass * G / k_wall, rel=0.02)


@pytest.mark.parametrize("E", [1e6, 1e7])
def test_a_box_dropped_on_a_box_comes_to_rest_while_its_contacts_are_kept(E):
    # A box dropped 2 mm onto a box on the floor, 0.5 mm off centre. Served as B's point on A's
    # plane (session 21) the top box kept rocking at 1e-6 to 1e-4 rad/s, fed by the refreshes:
    # the fixed point lacked the crown's rolling, which gives a resting face its stiffness in
    # tilt. With the osculating spheres it comes to rest as the full geometry does (1e-15).
    sim = stacked_boxes(ContactParams(E=E, nu=0.3, e=0.3, mu=0.5), 0.0005, 0.002)
    spins = []
    for t in (0.6, 0.8, 1.0):
        assert sim.run(t).ok
        spins.append(float(np.linalg.norm(sim.bodies.omega[1])))
    served, evaluated = kept_rows_used(sim, 100)
    assert served >= 0.9 * (served + evaluated)
    assert max(spins) < 1e-10, spins


@pytest.mark.parametrize("name", sorted(POSES))
def test_a_kept_contact_moves_with_the_pair_as_a_whole(name):
    # Kept with A at the origin, asked with both bodies carried by one rigid motion (and moved
    # within the bound relative to each other): the same overlap, the normal and the point carried.
    rot0, pos0 = resting_pose(name)
    kept, delta0 = kept_row(rot0, pos0)
    rng = np.random.default_rng(11)
    for _ in range(20):
        rot, pos = moved(rot0, pos0, rng, 0.9 * KEEP_FRACTION * delta0)
        turn = matrix(from_axis_angle(rng.normal(size=3), rng.uniform(0, np.pi)))
        shift = rng.normal(size=3)
        here = kept_contact(kept, 0, (1.0, 2.0), EYE, (0.0,) * 3, tuple(rot.ravel()), tuple(pos))
        there = kept_contact(
            kept,
            0,
            (1.0, 2.0),
            tuple(turn.ravel()),
            tuple(shift),
            tuple((turn @ rot).ravel()),
            tuple(turn @ pos + shift),
        )
        assert here[0] and there[0]
        assert there[1] == pytest.approx(here[1], rel=1e-9)
        assert np.array(there[2:5]) == pytest.approx(turn @ np.array(here[2:5]), abs=1e-12)
        assert np.array(there[5:8]) == pytest.approx(turn @ np.array(here[5:8]) + shift, abs=1e-12)


@pytest.mark.parametrize("name", sorted(POSES))
@pytest.mark.parametrize("margin", [1e-6, 1e-4])
def test_a_pair_kept_apart_is_served_only_while_it_cannot_touch(name, margin):
    # B lifted off A by a margin, kept apart: every motion the row serves leaves the full geometry
    # apart too (the crowned distance moves by at most the motion), and larger motions are not
    # served.
    rot0, pos0 = resting_pose(name)
    pos0 = pos0 + (0.0, 0.0, 20e-6 + margin)
    delta0, _, _ = full(rot0, pos0)
    # the margin found, or a lower bound of it (the crowns' floor, dem.crown.crown_floor)
    assert -1.5 * margin < delta0 < 0.0
    kept = np.zeros((1, KEPT))
    keep_apart(kept, 0, (1.0, 2.0), REACH, EYE, (0.0,) * 3, tuple(rot0.ravel()), tuple(pos0), delta0)
    allowed = APART_FRACTION * -delta0
    rng = np.random.default_rng(5)
    for size, served in ((0.95 * allowed, True), (2.5 * allowed, False)):
        for _ in range(30):
            rot, pos = moved(rot0, pos0, rng, size)
            answer = kept_contact(kept, 0, (1.0, 2.0), EYE, (0.0,) * 3, tuple(rot.ravel()), tuple(pos))
            assert answer[0] == served
            if served:
                assert answer[1] == delta0
                assert full(rot, pos)[0] < 0


@pytest.mark.parametrize("representation", ["polyhedron", "clump"])
def test_a_rows_reach_holds_every_material_point_of_it(representation):
    # The kept rows' motion bound turns each row by its reach (dem/bodies.py): every point of a
    # camera's pieces (slab and lens barrel: pieces whose centres are not the body's) or of its
    # clump's spheres lies within it of the body's centre, and some point reaches it.
    from dem.bodies import Spheres
    from dem.scenarios.items import default_items

    (camera,) = default_items(np.random.default_rng(3), {"camera": 1}, representation=representation)
    spheres = Spheres()
    spheres.append(0, camera.shape, np.eye(3), np.zeros(3))
    rows = spheres.arrays()
    rng = np.random.default_rng(8)
    directions = rng.normal(size=(200, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    for i in range(len(rows.radius)):
        if rows.core_count[i] > 0:
            core = rows.core[rows.core_start[i] : rows.core_start[i] + rows.core_count[i]]
            r = rows.rounding[i]
        else:
            core, r = rows.offset[i][None, :], rows.radius[i]
        # the rounded surface: a core vertex plus r along any direction, the farthest at r along
        # the vertex's own direction
        points = (core[:, None, :] + r * directions[None, :, :]).reshape(-1, 3)
        far = core + r * core / np.linalg.norm(core, axis=1)[:, None]
        assert np.linalg.norm(points, axis=1).max() <= rows.reach[i] * (1 + 1e-12)
        assert np.linalg.norm(far, axis=1).max() == pytest.approx(rows.reach[i], rel=1e-12)
