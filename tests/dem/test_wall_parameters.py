"""A trial's item-wall parameters reach the engine: the feeder's tray is of their material.

A rounded box on the floor of the feeder's tray tilted by theta (the run is built by the
feeder scenario itself, from a trial's parameters, before its vibration starts) sticks when
tan(theta) < mu_wall and slides with a = g (sin(theta) - mu_wall cos(theta)) when
tan(theta) > mu_wall, whatever the items' own mu (each test gives the items the mu that would do
the opposite): mu_wall is the item-wall pair's friction (``dem.materials.TrialMaterials``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle
from dem.scenarios.base import merged_params
from dem.scenarios.feeder import _FeederRun
from dem.scenarios.feeder_config import FeederConfig

G = 9.81
TILT_DEG = 20.0  # tan = 0.364
ITEMS = {"E": 1e7, "nu": 0.3, "e": 0.3}
SIZE = (0.04, 0.03, 0.01)
BOX = Polyhedron.box(SIZE, 0.002, 1000.0)


def box_on_tilted_tray(params: dict[str, float]) -> tuple[_FeederRun, np.ndarray]:
    """The feeder's run for these trial parameters, with a box resting flat on its floor in the
    middle of the inlet region, and the world direction down the floor (tray-frame x)."""
    config = FeederConfig.model_validate({"tray": {"tilt_deg": TILT_DEG}, "run": {"dt": 2e-5}})
    checked, problem = merged_params(config.params, params)
    assert problem == ""
    run = _FeederRun(config, checked, seed=0, snapshot_dir=None)
    centre = np.array([0.5 * sum(run.tray.inlet_x), 0.0, 0.5 * SIZE[2]])
    tilt = from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(TILT_DEG))
    run.sim.add_body(BOX, run.tray.to_world(centre[None, :])[0], tilt)
    down_the_floor = run.tray.to_world(np.array([[1.0, 0.0, 0.0]]))[0]
    return run, down_the_floor


def test_box_on_tilted_tray_sticks_when_tan_theta_is_below_mu_wall():
    mu_wall, mu_items = 0.9, 0.1
    assert mu_items < math.tan(math.radians(TILT_DEG)) < mu_wall
    run, down = box_on_tilted_tray({**ITEMS, "mu": mu_items, "mu_wall": mu_wall})
    run.sim.run(0.1)
    x0 = run.sim.bodies.pos[0] @ down

    report = run.sim.run(0.5)

    assert report.ok, report.message
    assert abs(run.sim.bodies.pos[0] @ down - x0) < 1e-4


def test_box_on_tilted_tray_slides_with_g_sin_minus_mu_wall_cos_when_tan_theta_exceeds_it():
    mu_wall, mu_items, theta = 0.1, 0.9, math.radians(TILT_DEG)
    assert mu_wall < math.tan(theta) < mu_items
    run, down = box_on_tilted_tray({**ITEMS, "mu": mu_items, "mu_wall": mu_wall})
    run.sim.run(0.1)
    v0, t0 = run.sim.bodies.vel[0] @ down, run.sim.t

    report = run.sim.run(0.3)

    assert report.ok, report.message
    measured = (run.sim.bodies.vel[0] @ down - v0) / (run.sim.t - t0)
    assert measured == pytest.approx(G * (math.sin(theta) - mu_wall * math.cos(theta)), rel=0.03)
