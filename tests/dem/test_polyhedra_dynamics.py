"""Rounded-polyhedron bodies against analytic mechanics (issue 12's verification tests).

The box is ``Polyhedron.box``: 40 x 30 x 10 mm, edges rounded by 2 mm, the sharp box's mass
properties. Its contact with a wall or another body is one contact of the body pair's stiffness
K (``dem/contact.py``), whatever the orientation.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from dem.clump import Clump
from dem.contact import ContactParams, wall_stiffness
from dem.polyhedra import Polyhedron, make_polyhedron
from dem.quaternion import from_axis_angle, matrix
from dem.simulation import Simulation
from dem.walls import WallMesh
from tests.dem.collisions import assert_collision_conserves_energy_and_momenta

G = 9.81
SIZE = (0.04, 0.03, 0.01)
ROUNDING = 0.002
BOX = Polyhedron.box(SIZE, ROUNDING, 1000.0)
HALF = 0.5 * SIZE[2]


def floor_sim(params, gravity=(0, 0, -G), **kwargs) -> Simulation:
    sim = Simulation(params, gravity=gravity, domain_min=(-1, -1, -0.5), domain_max=(1, 1, 1), **kwargs)
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 2.0))
    return sim


def test_rounded_box_resting_flat_overlaps_m_g_over_K_face():
    params = ContactParams(E=1e6, nu=0.3, e=0.3, mu=0.5)
    sim = floor_sim(params)
    sim.add_body(BOX, (0.013, -0.007, HALF + 0.001))

    report = sim.run(0.6)

    assert report.ok, report.message
    overlap = HALF - sim.bodies.pos[0, 2]
    k_face = wall_stiffness(params.E, BOX.equivalent_diameter, params.E)
    assert overlap == pytest.approx(BOX.mass * G / k_face, rel=0.02)
    # It rests on its face: the face stays within 5 % of the overlap of parallel to the floor.
    tilt = math.acos(min(1.0, abs(matrix(sim.bodies.quat[0])[2, 2])))
    assert tilt * 0.5 * SIZE[0] < 0.05 * overlap


def test_rounded_box_dropped_flat_rebounds_with_e():
    e = 0.6
    sim = floor_sim(ContactParams(E=1e6, nu=0.3, e=e, mu=0.0), gravity=(0, 0, 0), dt_fraction=0.01)
    sim.add_body(BOX, (0, 0, HALF + 1e-4), velocity=(0, 0, -0.5))

    report = sim.run(0.02)

    assert report.ok, report.message
    assert sim.bodies.vel[0, 2] == pytest.approx(0.5 * e, rel=0.02)
    assert np.abs(sim.bodies.omega[0]).max() < 1e-6


@pytest.mark.parametrize("angle_deg", [15.0, 25.0])
def test_rounded_box_on_incline_below_friction_angle_sticks(angle_deg):
    mu, angle = 0.5, math.radians(angle_deg)
    assert math.tan(angle) < mu
    sim = floor_sim(
        ContactParams(E=1e7, nu=0.3, e=0.3, mu=mu), gravity=(G * math.sin(angle), 0, -G * math.cos(angle))
    )
    sim.add_body(BOX, (0, 0, HALF))
    sim.run(0.1)
    x0 = sim.bodies.pos[0, 0]

    report = sim.run(1.1)

    assert report.ok, report.message
    assert abs(sim.bodies.pos[0, 0] - x0) < 1e-4


@pytest.mark.parametrize("angle_deg", [32.0, 40.0])
def test_rounded_box_on_incline_above_friction_angle_slides_with_coulomb_acceleration(angle_deg):
    mu, angle = 0.5, math.radians(angle_deg)
    sim = floor_sim(
        ContactParams(E=1e7, nu=0.3, e=0.3, mu=mu), gravity=(G * math.sin(angle), 0, -G * math.cos(angle))
    )
    sim.add_body(BOX, (-0.5, 0, HALF))
    sim.run(0.1)
    v0, t0 = sim.bodies.vel[0, 0], sim.t

    report = sim.run(0.5)

    assert report.ok, report.message
    measured = (sim.bodies.vel[0, 0] - v0) / (sim.t - t0)
    assert measured == pytest.approx(G * (math.sin(angle) - mu * math.cos(angle)), rel=0.03)


ORIENTATIONS = {
    # face-on with the faces offset (the case a clump with staggered rows fails)
    "face-on": ((1.0, 0.0, 0.0), 0.0, (0.0, 0.004, 0.003)),
    "edge-on": ((0.0, 0.0, 1.0), math.pi / 4, (0.0, 0.002, -0.001)),
    "corner-on": ((1.0, -1.0, 0.5), 0.9, (0.0, -0.003, 0.002)),
    "slightly tilted": ((0.0, 1.0, 0.2), 0.05, (0.0, 0.001, 0.0)),
}


def elastic_sim() -> Simulation:
    return Simulation(
        ContactParams(E=1e7, nu=0.3, e=1.0, mu=0.0),
        gravity=(0, 0, 0),
        domain_min=(-1, -1, -1),
        domain_max=(1, 1, 1),
    )


@pytest.mark.parametrize("case", list(ORIENTATIONS))
def test_elastic_frictionless_box_collisions_conserve_energy_and_momenta(case):
    axis, angle, offset = ORIENTATIONS[case]
    sim = elastic_sim()
    sim.add_body(BOX, (-0.04, 0, 0), velocity=(0.6, 0.05, 0), omega=(0, 0, 3.0))
    sim.add_body(
        BOX,
        (0.04 + offset[0], offset[1], offset[2]),
        quaternion=from_axis_angle(axis, angle),
        velocity=(-0.4, 0, 0.02),
    )

    assert_collision_conserves_energy_and_momenta(sim)


@pytest.mark.parametrize(
    ("axis", "shift"),
    [
        ((0.491, -0.591, 0.64), (0.0008, -0.0038)),
        ((-0.972, -0.09, -0.217), (-0.0054, 0.0038)),
        ((-0.694, 0.674, 0.251), (-0.0056, 0.0026)),
    ],
)
def test_nearly_face_on_elastic_box_collisions_conserve_energy_and_momenta(axis, shift):
    # Faces 1 deg from parallel meet head-on (the three 1 deg cases of
    # benchmarks/polyhedra_energy.py): the contact point crosses the face while it rocks.
    sim = elastic_sim()
    sim.add_body(BOX, (-0.025, 0, 0), velocity=(0.5, 0, 0))
    sim.add_body(
        BOX, (0.03, *shift), quaternion=from_axis_angle(axis, math.radians(1.0)), velocity=(-0.5, 0, 0)
    )

    assert_collision_conserves_energy_and_momenta(sim)


def test_elastic_frictionless_box_against_a_clump_conserves_energy_and_momenta():
    clump = Clump(
        radius=np.full(3, 0.006),
        offset=np.array([[-0.01, 0, 0], [0, 0, 0], [0.01, 0, 0]]),
        mass=0.01,
        inertia=np.array([1.5e-7, 4e-7, 4e-7]),
        volume=1e-5,
    )
    sim = elastic_sim()
    sim.add_body(BOX, (-0.035, 0, 0), quaternion=from_axis_angle((0, 1, 1), 0.4), velocity=(0.5, 0, 0))
    sim.add_body(
        clump, (0.03, 0.004, -0.002), quaternion=from_axis_angle((0, 0, 1), 0.5), velocity=(-0.5, 0, 0)
    )

    assert_collision_conserves_energy_and_momenta(sim)


def test_tumbling_rounded_box_in_free_flight_conserves_energy():
    sim = Simulation(
        ContactParams(E=1e7, nu=0.3, e=0.5, mu=0.5),
        gravity=(0, 0, 0),
        domain_min=(-1, -1, -1),
        domain_max=(1, 1, 1),
        dt=1e-4,
    )
    sim.add_body(BOX, (0, 0, 0), quaternion=from_axis_angle((0.3, -0.5, 0.8), 1.1), omega=(3.0, 40.0, 2.0))
    e0 = sim.kinetic_energy()

    report = sim.run(2.0, chunk_time=0.5)

    assert report.ok
    assert sim.kinetic_energy() == pytest.approx(e0, rel=1e-6)


def test_a_decomposed_non_convex_item_lands_and_rests_on_its_pieces():
    # An L-shaped bracket (a user mesh): CoACD splits it, each convex piece touches the floor.
    a = trimesh.creation.box((0.06, 0.02, 0.01))
    b = trimesh.creation.box((0.02, 0.06, 0.01))
    b.apply_translation([0.02, 0.02, 0])
    bracket = make_polyhedron(trimesh.boolean.union([a, b], engine="manifold"), mass=0.02)
    assert bracket.n_pieces >= 2
    params = ContactParams(E=1e6, nu=0.3, e=0.3, mu=0.5)
    sim = floor_sim(params)
    lowest = float(np.min(bracket.core[:, 2])) - bracket.rounding
    sim.add_body(bracket, (0, 0, -lowest + 0.005))

    report = sim.run(0.8)

    assert report.ok, report.message
    assert np.abs(sim.bodies.vel[0]).max() < 1e-3
    # it lies flat on its 10 mm thickness: every piece's lowest point on the floor
    height = sim.bodies.pos[0, 2] + lowest
    k = wall_stiffness(params.E, bracket.equivalent_diameter, params.E)
    assert abs(height) < 5 * bracket.mass * G / k
