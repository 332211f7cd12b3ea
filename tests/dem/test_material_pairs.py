"""Per-material pair interactions in the engine (issue 12): e and mu of the pair, stiffness from
both moduli in series (``dem/materials.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.clump import Clump
from dem.contact import ContactParams, series
from dem.materials import Interaction, Material
from dem.simulation import Simulation
from dem.walls import WallMesh

RADIUS = 0.005
BALL = Clump.solid_sphere(RADIUS, 2500.0)
LIVELY = Material(E=1e7, nu=0.3, e=0.9, mu=0.5, name="lively")
DEAD = Material(E=1e7, nu=0.3, e=0.3, mu=0.5, name="dead")


def rebound_off_a_wall(interactions=None) -> float:
    sim = Simulation(
        LIVELY,
        gravity=(0, 0, 0),
        domain_min=(-1, -1, -1),
        domain_max=(1, 1, 1),
        dt_fraction=0.01,
        interactions=interactions,
    )
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 1.0, material=DEAD))
    sim.add_body(BALL, (0, 0, RADIUS + 1e-4), velocity=(0, 0, -1.0))
    report = sim.run(0.01)
    assert report.ok, report.message
    return sim.bodies.vel[0, 2]


def test_a_lively_particle_on_a_dead_wall_rebounds_with_the_pair_rule_restitution():
    # The default rule: e_pair = sqrt(e_particle e_wall) = sqrt(0.9 x 0.3).
    assert rebound_off_a_wall() == pytest.approx(math.sqrt(0.9 * 0.3), rel=0.02)


def test_an_explicit_pair_interaction_overrides_the_rule():
    assert rebound_off_a_wall({("dead", "lively"): Interaction(e=0.7, mu=0.2)}) == pytest.approx(
        0.7, rel=0.02
    )


def test_unlike_materials_impact_duration_follows_the_series_stiffness():
    soft = Material(E=1e7, nu=0.3, e=1.0, mu=0.0, name="soft")
    stiff = Material(E=4e7, nu=0.3, e=1.0, mu=0.0, name="stiff")
    sim = Simulation(
        soft, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt_fraction=0.005
    )
    sim.add_body(BALL, (-RADIUS - 1e-4, 0, 0), velocity=(0.5, 0, 0), material=soft)
    sim.add_body(BALL, (RADIUS + 1e-4, 0, 0), velocity=(-0.5, 0, 0), material=stiff)
    steps_in_contact = []
    sim.run(0.01, chunk_time=sim.dt, on_chunk=lambda s: steps_in_contact.append(s.n_contacts > 0))

    duration = sum(steps_in_contact) * sim.dt
    diameter = 2 * RADIUS
    k = series(soft.E * diameter, stiff.E * diameter)
    expected = math.pi * math.sqrt(series(BALL.mass, BALL.mass) / k)
    assert duration == pytest.approx(expected, rel=0.02)
    assert np.allclose(sim.bodies.vel[:, 0], [-0.5, 0.5], rtol=1e-3)  # elastic: velocities swap


def test_bodies_of_one_simulation_may_have_different_materials():
    sim = Simulation(
        ContactParams(E=1e7, nu=0.3, e=0.5, mu=0.5), domain_min=(-1, -1, -1), domain_max=(1, 1, 1)
    )
    a = sim.add_body(BALL, (0, 0, 0), material=LIVELY)
    b = sim.add_body(BALL, (0.1, 0, 0))

    assert sim.bodies.material[a] != sim.bodies.material[b]
    assert sim.materials.materials[sim.bodies.material[a]].name == "lively"
