"""A sphere on a vertically vibrating plate (issue 3, test 9): it lifts off when A w^2 > g, at
the phase where the plate's downward acceleration reaches g."""

from __future__ import annotations

import math

import pytest

from dem.clump import Clump
from dem.contact import ContactParams
from dem.motion import SinusoidalTranslation
from dem.simulation import Simulation
from dem.walls import WallMesh

G = 9.81
FREQUENCY = 10.0


def ball(radius=0.005, density=2500.0) -> Clump:
    return Clump.solid_sphere(radius, density)


def first_free_flight(gamma: float, start: float = 0.05) -> tuple[float | None, float]:
    """Time after ``start`` at which the sphere first flies free on a plate moving as
    A (1 - cos(w t)) (at rest at its lowest point when it starts), gamma = A w^2 / g."""
    omega = 2 * math.pi * FREQUENCY
    amplitude = gamma * G / omega**2
    sim = Simulation(
        ContactParams(E=1e8, nu=0.3, e=0.5, mu=0.5), domain_min=(-1, -1, -1), domain_max=(1, 1, 1)
    )
    sim.add_wall(
        WallMesh.plane(
            (0, 0, 0),
            (0, 0, 1),
            0.2,
            motion=SinusoidalTranslation(
                (0, 0, 1), amplitude, FREQUENCY, start_time=start, phase=-math.pi / 2
            ),
        )
    )
    body = ball()
    sim.add_body(body, (0, 0, 0.005 - body.mass * G / (1e8 * 0.005)))
    sim.run(start)
    lift = []

    def each_step(s: Simulation) -> None:
        if not lift and s.n_contacts == 0:
            lift.append(s.t - start)

    sim.run(start + 1 / FREQUENCY, chunk_time=sim.dt, on_chunk=each_step)
    return (lift[0] if lift else None), 1 / FREQUENCY


@pytest.mark.parametrize("gamma", [1.5, 3.0])
def test_sphere_lifts_off_where_plate_deceleration_reaches_g(gamma):
    # Plate acceleration A w^2 cos(w t) reaches -g at w t = pi/2 + asin(1/gamma).
    expected = (math.pi / 2 + math.asin(1 / gamma)) / (2 * math.pi * FREQUENCY)

    lift_off, period = first_free_flight(gamma)

    assert lift_off is not None
    assert abs(lift_off - expected) < 0.02 * period


def test_sphere_stays_on_plate_below_one_g():
    lift_off, _ = first_free_flight(0.8)

    assert lift_off is None
