"""The automatic time step (issue 3, test 8) and its effective-mass rule."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.clump import Clump
from dem.contact import ContactParams
from dem.simulation import Simulation
from dem.timestep import automatic_time_step, effective_mass
from dem.walls import WallMesh


def plate_clump() -> Clump:
    """A 146 x 71 x 8 mm plate (phone) of 170 g as 4 x 2 spheres of radius 4 mm at the corners."""
    a, b, c, m = 0.146, 0.071, 0.008, 0.170
    offset = np.array([[x, y, 0.0] for x in (-0.069, -0.023, 0.023, 0.069) for y in (-0.0315, 0.0315)])
    inertia = m / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    return Clump(radius=np.full(8, 0.004), offset=offset, mass=m, inertia=inertia, volume=a * b * c)


def test_automatic_step_scales_as_inverse_sqrt_of_youngs_modulus():
    clump = plate_clump()
    soft = ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5)
    stiff = ContactParams(E=4e6, nu=0.3, e=0.5, mu=0.5)

    dt_soft = automatic_time_step([clump], soft, [soft])
    dt_stiff = automatic_time_step([clump], stiff, [stiff])

    assert dt_stiff == pytest.approx(dt_soft / 2, rel=1e-12)


def test_simulation_uses_the_automatic_step_of_its_bodies_and_walls():
    params = ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5)
    sim = Simulation(params, domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt_fraction=0.05)
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 1.0))
    sim.add_body(plate_clump(), (0, 0, 0.1))

    assert sim.dt == pytest.approx(automatic_time_step([plate_clump()], params, [params], 0.05))


def test_thin_plate_hit_at_a_corner_is_lighter_than_its_mass():
    clump = plate_clump()
    # Corner sphere centre c and normal n along the thin axis: 1/m_eff = 1/m + (c x n)^T I^-1 (c x n).
    c = clump.offset[0]
    n = np.array([0.0, 0.0, 1.0])
    lever = np.cross(c, n)
    along_thin_axis = 1.0 / (1.0 / clump.mass + lever @ (lever / clump.inertia))

    m_eff = effective_mass(clump)

    assert m_eff <= along_thin_axis * (1 + 1e-12)
    assert m_eff < clump.mass / 5


def test_sphere_step_is_the_fraction_of_the_contact_duration():
    radius, E = 0.005, 1e7
    ball = Clump.solid_sphere(radius, 2500.0)
    mass = ball.mass
    params = ContactParams(E=E, nu=0.3, e=0.5, mu=0.5)

    dt = automatic_time_step([ball], params, [], fraction=1 / 20)

    # Two equal spheres: K = E D / 2, m* = m / 2.
    assert dt == pytest.approx(math.pi * math.sqrt((mass / 2) / (E * radius)) / 20, rel=1e-12)
