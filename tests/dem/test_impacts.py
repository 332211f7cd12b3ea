"""Binary impacts against the analytic solution of the linear spring-dashpot (issue 3, tests 1-2).

The analytic values are computed here from the oscillator m* x'' + C x' + K x = 0 with
K = E D_a D_b / (D_a + D_b) (a wall: the body's mirror image) and the damping ratio the engine
uses for e, so the checks are: the engine realises e, the clamped contact duration and the peak
overlap of that oscillator, and conserves momentum.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.clump import Clump
from dem.contact import ContactParams, damping_ratio
from dem.simulation import Simulation
from dem.walls import WallMesh

DENSITY = 2500.0
STEP_FRACTION = 1.0 / 100.0  # fine steps: the checks below resolve the contact to 1 %


def ball(radius: float, density: float = DENSITY) -> Clump:
    return Clump.solid_sphere(radius, density)


def clamped_oscillator(k: float, m: float, zeta: float, v0: float) -> tuple[float, float]:
    """(duration until the force vanishes, peak overlap) of the clamped linear contact."""
    w0 = math.sqrt(k / m)
    if zeta < 1.0:
        wd = math.sqrt(1 - zeta**2)
        t_end = (math.pi - math.atan2(2 * zeta * wd, 1 - 2 * zeta**2)) / wd
        t_peak = math.atan2(wd, zeta) / wd
        x_peak = math.exp(-zeta * t_peak) * math.sin(wd * t_peak) / wd
    else:
        s = math.sqrt(zeta**2 - 1)
        r1, r2 = -zeta + s, -zeta - s
        t_end = 2 * math.log(r2 / r1) / (r1 - r2)
        t_peak = math.log(r2 / r1) / (r1 - r2)
        x_peak = (math.exp(r1 * t_peak) - math.exp(r2 * t_peak)) / (r1 - r2)
    return t_end / w0, x_peak * v0 / w0


def record_impact(sim: Simulation, t_end: float):
    """Velocities of every body after each step, and the steps whose velocities changed."""
    velocities = [sim.bodies.vel.copy()]
    positions = [sim.bodies.pos.copy()]

    def each_step(s: Simulation) -> None:
        velocities.append(s.bodies.vel.copy())
        positions.append(s.bodies.pos.copy())

    report = sim.run(t_end, chunk_time=sim.dt, on_chunk=each_step)
    assert report.ok, report.message
    return np.array(velocities), np.array(positions)


@pytest.mark.parametrize("e", [0.1, 0.3, 0.5, 0.7, 0.9])
def test_normal_impact_on_wall_rebounds_with_restitution(e):
    radius, v0 = 0.005, 1.0
    params = ContactParams(E=1e7, nu=0.3, e=e, mu=0.0)
    sim = Simulation(
        params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt_fraction=STEP_FRACTION
    )
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.2))
    gap = 0.1 * radius
    body = ball(radius)
    sim.add_body(body, (0, 0, radius + gap), velocity=(0, 0, -v0))
    k, m = params.E * radius, body.mass  # E D / 2 against the wall mirror image
    duration, peak = clamped_oscillator(k, m, damping_ratio(e), v0)

    vel, pos = record_impact(sim, gap / v0 + 1.5 * duration)

    in_contact = np.abs(np.diff(vel[:, 0, 2])) > 0
    assert vel[-1, 0, 2] / v0 == pytest.approx(e, rel=0.01)
    assert in_contact.sum() * sim.dt == pytest.approx(duration, rel=0.02)
    assert radius - pos[:, 0, 2].min() == pytest.approx(peak, rel=0.02)


@pytest.mark.parametrize("e", [0.1, 0.3, 0.5, 0.7, 0.9])
@pytest.mark.parametrize("mass_ratio", [1.0, 4.0])
def test_head_on_sphere_impact_rebounds_with_restitution_and_conserves_momentum(e, mass_ratio):
    r_a = 0.005
    r_b = r_a * mass_ratio ** (1 / 3)  # same density: the mass ratio sets the size ratio
    v_a, v_b = 0.6, -0.4
    params = ContactParams(E=1e7, nu=0.3, e=e, mu=0.0)
    sim = Simulation(
        params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt_fraction=STEP_FRACTION
    )
    a, b = ball(r_a), ball(r_b)
    gap = 0.1 * r_a
    sim.add_body(a, (-r_a - gap / 2, 0, 0), velocity=(v_a, 0, 0))
    sim.add_body(b, (r_b + gap / 2, 0, 0), velocity=(v_b, 0, 0))
    k = params.E * (2 * r_a) * (2 * r_b) / (2 * r_a + 2 * r_b)
    m_eff = a.mass * b.mass / (a.mass + b.mass)
    duration, peak = clamped_oscillator(k, m_eff, damping_ratio(e), v_a - v_b)
    p0 = a.mass * v_a + b.mass * v_b

    vel, pos = record_impact(sim, gap / (v_a - v_b) + 1.5 * duration)

    relative_after = vel[-1, 1, 0] - vel[-1, 0, 0]
    assert relative_after / (v_a - v_b) == pytest.approx(e, rel=0.01)
    momentum = a.mass * vel[:, 0, 0] + b.mass * vel[:, 1, 0]
    assert np.max(np.abs(momentum - p0)) <= 1e-12 * abs(a.mass * v_a)
    in_contact = np.abs(np.diff(vel[:, 0, 0])) > 0
    assert in_contact.sum() * sim.dt == pytest.approx(duration, rel=0.02)
    overlap = r_a + r_b - (pos[:, 1, 0] - pos[:, 0, 0])
    assert overlap.max() == pytest.approx(peak, rel=0.02)


@pytest.mark.parametrize("angle_deg", [45.0, 60.0, 75.0])
def test_oblique_impact_chung_ooi_test4(angle_deg):
    # Chung & Ooi (2011) test 4: alumina sphere R 2.55 mm on a wall, e 0.98, mu 0.092, 3.9 m/s.
    radius, speed, e, mu = 0.00255, 3.9, 0.98, 0.092
    angle = math.radians(angle_deg)
    assert math.tan(angle) > 3.5 * mu * (1 + e)  # gross sliding throughout the contact
    params = ContactParams(E=3.8e11, nu=0.23, e=e, mu=mu)
    sim = Simulation(
        params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt_fraction=1 / 50
    )
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 1.0))
    v_n, v_t = speed * math.cos(angle), speed * math.sin(angle)
    gap = 0.01 * radius
    sim.add_body(ball(radius, density=4000.0), (0, 0, radius + gap), velocity=(v_t, 0, -v_n))

    report = sim.run(gap / v_n + 20 * math.pi * math.sqrt(ball(radius, 4000.0).mass / (3.8e11 * radius)))

    assert report.ok
    assert sim.bodies.vel[0, 2] == pytest.approx(e * v_n, rel=0.01)
    assert sim.bodies.vel[0, 0] == pytest.approx(v_t - mu * (1 + e) * v_n, rel=0.02)
    assert sim.bodies.omega[0, 1] == pytest.approx(5 * mu * (1 + e) * v_n / (2 * radius), rel=0.02)
