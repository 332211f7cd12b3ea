"""The heap's plate and cylinder are both of the trial's wall material (``dem/scenarios/heap.py``).

A sphere of the heap's particles (e = 0.9) thrown at either wall of an angle-of-repose run built
from a trial with e_wall = 0.3 rebounds with the item-wall pair's restitution, 0.3, not with the
particles' own (the normal velocity ratio of a linear spring-dashpot with the clamp-corrected
damping ratio, ``dem.contact.damping_ratio``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.clump import Clump
from dem.scenarios.base import RunControl, merged_params
from dem.scenarios.heap import _HeapRun
from dem.scenarios.heap_config import HeapConfig

RADIUS = 0.005
BALL = Clump.solid_sphere(RADIUS, 2500.0)
TRIAL = {"E": 1e7, "nu": 0.3, "e": 0.9, "mu": 0.5, "e_wall": 0.3}
SPEED = 0.5
GAP = 1e-4


def heap_run() -> _HeapRun:
    """The heap run of ``TRIAL`` (a smooth plate, a fine time step), before the lift."""
    config = HeapConfig.model_validate(
        {"particles": {"count": 10}, "plate": {"roughness": 0.0}, "run": {"dt_fraction": 0.01}}
    )
    params, problem = merged_params(config.params, TRIAL)
    assert problem == ""
    return _HeapRun(config, params, seed=0, control=RunControl())


def rebound(run: _HeapRun, position, normal) -> float:
    """Normal speed after / before of a ball thrown at SPEED against ``normal`` (the wall's,
    pointing at the ball) from ``position``, gravity off (the walls' law is what is measured)."""
    normal = np.asarray(normal, dtype=float)
    run.sim.gravity = np.zeros(3)
    body = run.sim.add_body(BALL, position, velocity=-SPEED * normal)
    report = run.sim.run(0.005)
    assert report.ok, report.message
    return float(run.sim.bodies.vel[body] @ normal) / SPEED


def test_a_sphere_thrown_at_the_heaps_cylinder_rebounds_with_e_wall():
    run = heap_run()
    cyl = run.config.cylinder
    facet = 0.5 * cyl.diameter * math.cos(math.pi / cyl.segments)  # the inscribed radius
    outward = np.array([math.cos(math.pi / cyl.segments), math.sin(math.pi / cyl.segments), 0.0])
    start = (facet - RADIUS - GAP) * outward + np.array([0.0, 0.0, 0.8 * cyl.height])  # above the column

    assert rebound(run, start, -outward) == pytest.approx(TRIAL["e_wall"], rel=0.02)


def test_a_sphere_dropped_on_the_heaps_plate_beside_the_cylinder_rebounds_with_e_wall():
    run = heap_run()
    start = (0.5 * (run.config.cylinder.diameter + 0.5 * run.config.plate.size), 0.0, RADIUS + GAP)

    assert rebound(run, start, (0.0, 0.0, 1.0)) == pytest.approx(TRIAL["e_wall"], rel=0.02)
