"""nu_wall, the walls' Poisson's ratio, reaches the item-wall pair's tangential stiffness.

A solid sphere resting on a wall, its contact stuck, is a tangential oscillator: the spring K_t
at the contact point moves the centre (mass m) and turns the sphere (inertia I = 2 m R^2 / 5), so
the contact point's displacement s obeys s'' = -K_t (1/m + R^2/I) s and oscillates at
omega^2 = 7 K_t / (2 m). Started with no angular momentum about the contact point
(I omega_y + m R v_x = 0) the centre's velocity is v0 cos(omega t). K_t is Mindlin's
(Johnson, Contact Mechanics, 1985, ch. 7): K_t / K_n = 4 G* / E*, with
1/G* = (2 - nu_a)/G_a + (2 - nu_b)/G_b and 1/E* = (1 - nu_a^2)/E_a + (1 - nu_b^2)/E_b, so a rubber
wall (nu_wall = 0.49) under plastic items (nu = 0.3) makes the pair 15 % softer tangentially than
walls of the items' nu would.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.clump import Clump
from dem.materials import TrialMaterials
from dem.scenarios.base import ParamsConfig, merged_params
from dem.simulation import Simulation
from dem.walls import WallMesh

RADIUS = 0.005
BALL = Clump.solid_sphere(RADIUS, 1000.0)
G = 9.81
# Plastic items on a rubber mat: e = 1 so that nothing damps the oscillation, mu high so that the
# contact sticks.
TRIAL = {"E": 1e7, "nu": 0.3, "e": 1.0, "mu": 1.0, "E_wall": 2e6, "nu_wall": 0.49}


def mindlin_tangential_stiffness(E, nu, E_wall, nu_wall, diameter) -> float:
    """K_t of a sphere of diameter D on a wall: K_n of the two E in series (the wall is the
    sphere's mirror image, ``dem/contact.py``) times 4 G* / E*."""
    k_n = diameter * E * E_wall / (E + E_wall)
    g, g_wall = E / (2 * (1 + nu)), E_wall / (2 * (1 + nu_wall))
    e_star = 1 / ((1 - nu**2) / E + (1 - nu_wall**2) / E_wall)
    g_star = 1 / ((2 - nu) / g + (2 - nu_wall) / g_wall)
    return 4 * g_star / e_star * k_n


def tangential_period_on_a_wall(trial: dict[str, float]) -> float:
    """The measured period of a stuck sphere's tangential oscillation on a wall made of the
    trial's wall material, the run built from the trial's parameters as a scenario builds it."""
    params, problem = merged_params(ParamsConfig(), trial)
    assert problem == ""
    materials = TrialMaterials.of(params)
    sim = Simulation(
        materials.items, gravity=(0, 0, -G), domain_min=(-1, -1, -1), domain_max=(1, 1, 1),
        dt_fraction=0.005, interactions=materials.interactions,
    )  # fmt: skip
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.1, material=materials.walls))
    k_n = 2 * RADIUS * params["E"] * params.get("E_wall", params["E"])
    k_n /= params["E"] + params.get("E_wall", params["E"])
    v0 = 1e-3  # K_t s_max is a fifth of mu m g: the contact sticks throughout
    sim.add_body(
        BALL, (0, 0, RADIUS - BALL.mass * G / k_n), velocity=(v0, 0, 0), omega=(0, -2.5 * v0 / RADIUS, 0)
    )
    times, speeds = [], []
    report = sim.run(
        0.006, chunk_time=sim.dt, on_chunk=lambda s: (times.append(s.t), speeds.append(s.bodies.vel[0, 0]))
    )
    assert report.ok, report.message
    t, v = np.array(times), np.array(speeds)
    assert np.max(np.abs(v)) == pytest.approx(v0, rel=0.01)  # stuck: no energy lost to sliding
    down = np.flatnonzero((v[:-1] > 0) & (v[1:] <= 0))  # downward zero crossings, one a period
    crossings = t[down] + v[down] / (v[down] - v[down + 1]) * (t[down + 1] - t[down])
    return float(np.mean(np.diff(crossings)))


def test_sphere_stuck_on_a_wall_oscillates_with_mindlins_stiffness_of_both_poisson_ratios():
    k_t = mindlin_tangential_stiffness(TRIAL["E"], TRIAL["nu"], TRIAL["E_wall"], TRIAL["nu_wall"], 2 * RADIUS)
    expected = 2 * math.pi * math.sqrt(2 * BALL.mass / (7 * k_t))

    assert tangential_period_on_a_wall(TRIAL) == pytest.approx(expected, rel=0.01)
