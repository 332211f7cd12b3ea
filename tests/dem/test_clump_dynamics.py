"""Rigid clump bodies against analytic mechanics (issue 3, tests 3, 4, 5 and 7).

The box clumps are built here: a regular grid of equal spheres whose envelope is the box, with
the box's analytic mass and inertia (the engine must take those, never the spheres').
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.clump import Clump
from dem.contact import ContactParams
from dem.motion import SinusoidalTranslation
from dem.quaternion import from_axis_angle, matrix
from dem.simulation import Simulation
from dem.walls import WallMesh
from tests.dem.collisions import assert_collision_conserves_energy_and_momenta

G = 9.81


def box_clump(size, radius: float, density: float = 1000.0) -> Clump:
    """Spheres of ``radius`` on a grid filling a box of ``size`` (each side a multiple of 2 r)."""
    size = np.asarray(size, dtype=float)
    counts = np.rint(size / (2 * radius)).astype(int)
    assert np.allclose(counts * 2 * radius, size), "box sides must be multiples of the sphere diameter"
    axes = [(np.arange(n) - (n - 1) / 2) * 2 * radius for n in counts]
    offset = np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T
    volume = float(np.prod(size))
    mass = density * volume
    a, b, c = size
    inertia = mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    return Clump(
        radius=np.full(len(offset), radius), offset=offset, mass=mass, inertia=inertia, volume=volume
    )


def floor_sim(params, gravity=(0, 0, -G), **kwargs) -> Simulation:
    sim = Simulation(params, gravity=gravity, domain_min=(-1, -1, -0.5), domain_max=(1, 1, 1), **kwargs)
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 2.0))
    return sim


@pytest.mark.parametrize("angle_deg", [15.0, 22.0])
def test_box_on_incline_below_friction_angle_stays(angle_deg):
    mu, angle = 0.5, math.radians(angle_deg)
    assert math.tan(angle) < mu
    # The incline is the floor with gravity turned by the slope angle (same mechanics).
    sim = floor_sim(
        ContactParams(E=1e7, nu=0.3, e=0.3, mu=mu), gravity=(G * math.sin(angle), 0, -G * math.cos(angle))
    )
    box = box_clump((0.04, 0.03, 0.01), 0.005)
    sim.add_body(box, (0, 0, 0.005))
    sim.run(0.1)  # settle onto the slope
    x0 = sim.bodies.pos[0, 0]

    report = sim.run(1.1)

    assert report.ok
    assert abs(sim.bodies.pos[0, 0] - x0) < 1e-4


@pytest.mark.parametrize("angle_deg", [32.0, 40.0])
def test_box_on_incline_above_friction_angle_slides_with_coulomb_acceleration(angle_deg):
    mu, angle = 0.5, math.radians(angle_deg)
    assert math.tan(angle) > mu
    sim = floor_sim(
        ContactParams(E=1e7, nu=0.3, e=0.3, mu=mu), gravity=(G * math.sin(angle), 0, -G * math.cos(angle))
    )
    sim.add_body(box_clump((0.04, 0.03, 0.01), 0.005), (-0.5, 0, 0.005))
    sim.run(0.1)
    v0, t0 = sim.bodies.vel[0, 0], sim.t

    sim.run(0.5)

    measured = (sim.bodies.vel[0, 0] - v0) / (sim.t - t0)
    assert measured == pytest.approx(G * (math.sin(angle) - mu * math.cos(angle)), rel=0.03)


def test_tumbling_clump_in_closed_box_conserves_energy_when_elastic_and_frictionless():
    params = ContactParams(E=1e7, nu=0.3, e=1.0, mu=0.0)
    sim = Simulation(params, domain_min=(-0.2, -0.2, -0.2), domain_max=(0.2, 0.2, 0.2))
    sim.add_wall(WallMesh.box((-0.1, -0.1, -0.1), (0.1, 0.1, 0.1), open_top=False))
    body = box_clump((0.04, 0.02, 0.01), 0.005)
    sim.add_body(
        body,
        (0.01, -0.02, 0.03),
        quaternion=from_axis_angle((1, 2, 3), 0.7),
        velocity=(0.8, 0.5, -0.3),
        omega=(20.0, -35.0, 15.0),
    )
    e0 = sim.kinetic_energy() + sim.potential_energy()
    energies = []

    def between_contacts(s: Simulation) -> None:
        if s.n_contacts == 0:  # in contact part of the energy is in the springs
            energies.append(s.kinetic_energy() + s.potential_energy())

    report = sim.run(1.5, chunk_time=10 * sim.dt, on_chunk=between_contacts)

    assert report.ok
    assert len(energies) > 0.05 * report.steps
    assert np.max(np.abs(np.array(energies) - e0)) < 0.005 * e0


def test_torque_free_asymmetric_body_keeps_angular_momentum():
    params = ContactParams(E=1e7, nu=0.3, e=0.5, mu=0.5)
    inertia = np.array([1.0e-6, 2.0e-6, 3.5e-6])
    body = Clump(radius=np.array([0.01]), offset=np.zeros((1, 3)), mass=0.01, inertia=inertia, volume=4e-6)
    omega = np.array([3.0, 40.0, 2.0])  # near the unstable intermediate axis: a demanding case
    sim = Simulation(params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt=1e-4)
    q0 = from_axis_angle((0.3, -0.5, 0.8), 1.1)
    sim.add_body(body, (0, 0, 0), quaternion=q0, omega=omega)

    def angular_momentum(s: Simulation) -> np.ndarray:
        r = matrix(s.bodies.quat[0])
        return r @ (inertia * (r.T @ s.bodies.omega[0]))

    l0 = angular_momentum(sim)
    energy0 = 0.5 * omega @ l0

    report = sim.run(10.0, chunk_time=1.0)

    assert report.steps == 100_000
    l1 = angular_momentum(sim)
    assert np.linalg.norm(l1 - l0) <= 1e-6 * np.linalg.norm(l0)
    assert 0.5 * sim.bodies.omega[0] @ l1 == pytest.approx(energy0, rel=1e-3)


def test_torque_free_sphere_turns_about_its_angular_momentum_at_omega():
    params = ContactParams(E=1e7, nu=0.3, e=0.5, mu=0.5)
    ball = Clump.solid_sphere(0.005, 2500.0)
    omega = np.array([-30.0, 70.0, 45.0])  # a half angle of 4.6e-4 rad per step: the series branch
    sim = Simulation(params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt=1e-5)
    q0 = from_axis_angle((0.3, -0.5, 0.8), 1.1)
    sim.add_body(ball, (0, 0, 0), quaternion=q0, omega=omega)
    steps = 20_000

    report = sim.run(steps * 1e-5, chunk_time=0.05)

    assert report.steps == steps
    expected = matrix(from_axis_angle(omega, np.linalg.norm(omega) * steps * 1e-5)) @ matrix(q0)
    assert np.abs(matrix(sim.bodies.quat[0]) - expected).max() < 1e-11
    assert np.abs(sim.bodies.omega[0] - omega).max() < 1e-12 * np.linalg.norm(omega)


def drop_flat(box: Clump, height: float, params: ContactParams):
    """Static overlap and first rebound height of a box dropped flat from ``height``."""
    sim = floor_sim(params)
    half = 0.005
    sim.add_body(box, (0, 0, half + height))
    heights = []
    sim.run(1.0, chunk_time=2e-4, on_chunk=lambda s: heights.append(s.bodies.pos[0, 2] - half))
    heights = np.array(heights)
    first_landing = np.argmax(heights < 0)
    rebound = heights[first_landing:][: np.argmax(heights[first_landing:] > 1e-3) + 200].max()
    overlap = -(sim.bodies.pos[0, 2] - half)
    return overlap, rebound


def test_box_landing_flat_is_independent_of_clump_resolution():
    params = ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5)
    coarse = box_clump((0.06, 0.04, 0.01), 0.005)  # 24 spheres
    fine = box_clump((0.06, 0.04, 0.01), 0.0025)  # 192 spheres
    assert coarse.n_spheres == 24 and fine.n_spheres == 192
    height = 0.05

    overlap_coarse, rebound_coarse = drop_flat(coarse, height, params)
    overlap_fine, rebound_fine = drop_flat(fine, height, params)

    static = coarse.mass * G / (params.E * coarse.equivalent_diameter / 2)
    assert overlap_coarse == pytest.approx(static, rel=0.02)
    assert overlap_fine == pytest.approx(overlap_coarse, rel=0.10)
    assert rebound_coarse == pytest.approx(params.e**2 * height, rel=0.10)
    assert rebound_fine == pytest.approx(rebound_coarse, rel=0.10)


@pytest.mark.parametrize("angle_deg", [0.0, 1.0, 5.0])
def test_elastic_frictionless_clumps_with_staggered_rows_conserve_energy_and_momenta(angle_deg):
    # Two 40 mm cubes of 4 x 4 x 4 spheres (benchmarks/shape_fidelity.py) meet face-on, one
    # turned about z and shifted by half a sphere spacing, so that each sphere of one face rests
    # between spheres of the other: issue 12 asks energy within 0.5 % (the delta^4 sharing gave
    # +1.44 % at 1 deg and +1.26 % at 5 deg) and momenta to 1e-10.
    cube = box_clump((0.04, 0.04, 0.04), 0.005)
    shift = 0.005
    elastic = ContactParams(E=1e7, nu=0.3, e=1.0, mu=0.0)
    sim = Simulation(elastic, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_body(cube, (-0.04, 0, 0), velocity=(0.5, 0, 0))
    sim.add_body(
        cube,
        (0.04, shift, 0.5 * shift),
        quaternion=from_axis_angle((0, 0, 1), math.radians(angle_deg)),
        velocity=(-0.5, 0, 0),
    )
    assert_collision_conserves_energy_and_momenta(sim, duration=0.2)


def test_clump_contacts_do_not_depend_on_the_verlet_skin():
    # The neighbour lists only save work: lists built rarely with a wide skin, whose force pass
    # passes over the pairs that the bodies' moves (and the floor's travel) since the build cannot
    # have brought into contact, must find every contact at the step lists rebuilt almost every
    # step find it (ignoring the floor's travel fails here). Three
    # tumbling box clumps fall onto each other and onto a shaken floor. Only the order in which a
    # body's forces are summed may differ (a body pair's lone listed sphere pair is applied in the
    # first pass), so the two runs agree to rounding; a contact found one step late would not.
    params = ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5)
    shaking = SinusoidalTranslation((0.4, 0, 0.9), 1e-3, 40.0)
    shaken = WallMesh.plane((0, 0, 0), (0, 0, 1), 0.4, motion=shaking)
    box = box_clump((0.03, 0.02, 0.01), 0.005)

    def run(skin: float) -> Simulation:
        sim = Simulation(params, domain_min=(-0.5, -0.5, -0.2), domain_max=(0.5, 0.5, 0.5), skin=skin)
        sim.add_wall(shaken)
        for k in range(3):
            sim.add_body(
                box,
                (0.004 * k, -0.003 * k, 0.01 + 0.022 * k),
                quaternion=from_axis_angle((1, 2 - k, 3), 0.4 + 0.5 * k),
                velocity=(0.1 * (k - 1), 0.05, -0.2),
                omega=(10.0 * k, -5.0, 8.0),
            )
        assert sim.run(0.15).ok
        return sim

    wide, tight = run(0.02), run(1e-5)

    assert wide.n_builds * 20 < tight.n_builds
    scale = np.abs(tight.bodies.vel).max()
    assert scale > 0.01
    assert np.abs(wide.bodies.vel - tight.bodies.vel).max() < 1e-9 * scale
    assert np.abs(wide.bodies.pos - tight.bodies.pos).max() < 1e-12
