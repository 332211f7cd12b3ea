"""The angle-of-repose scenario (``dem/scenarios/heap.py``) and its surface fit
(``dem/scenarios/heap_fit.py``): the fit is exact on a sphere-covered cone, insensitive to its
choices on a simulated heap, the angle grows with friction, and LIGGGHTS agrees with the
built-in engine on the same case within the spread of seeds. Small heaps keep it to seconds per
run; the larger figures are in benchmarks/README.md.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pydantic import ValidationError

from dem.engines.base import run_scenario
from dem.result import SimulationStatus
from dem.scenarios import registry
from dem.scenarios.base import RunControl
from dem.scenarios.heap import _HeapRun, heap_geometry, sphere_packing
from dem.scenarios.heap_config import HeapConfig
from dem.scenarios.heap_fit import FitConfig, HeapFitError, fit_heap

QUICK = "examples/repose-quick.toml"


def quick_config(**sections) -> HeapConfig:
    import tomllib

    with open(QUICK, "rb") as handle:
        data = tomllib.load(handle)
    for key, value in sections.items():
        data[key] = {**data.get(key, {}), **value}
    return HeapConfig.model_validate(data)


def cone_of_spheres(angle_deg: float, radius: float = 0.15, d: float = 0.01, seed: int = 0):
    """Spheres filling a cone of this angle: the top ones touch the surface from below."""
    rng = np.random.default_rng(seed)
    height = radius * math.tan(math.radians(angle_deg))
    points = []
    for x in np.arange(-radius, radius, d):
        for y in np.arange(-radius, radius, d):
            rho = math.hypot(x, y)
            if rho >= radius:
                continue
            surface = height - rho * math.tan(math.radians(angle_deg))
            for z in np.arange(0.5 * d, surface - 0.5 * d + 1e-12, d):
                points.append((x, y, z))
            points.append((x + rng.uniform(-0.1, 0.1) * d, y, surface - 0.5 * d))
    return np.array(points), np.full(len(points), 0.5 * d)


@pytest.mark.parametrize("angle", [15.0, 25.0, 35.0])
def test_fit_recovers_the_angle_of_a_sphere_covered_cone(angle):
    points, radii = cone_of_spheres(angle)
    fit = fit_heap(points, radii)
    assert fit.angle_deg == pytest.approx(angle, abs=0.7)
    assert fit.height == pytest.approx(0.15 * math.tan(math.radians(angle)), abs=0.01)
    assert fit.spread_deg < 1.5


def test_fit_refuses_too_few_spheres_with_a_message():
    with pytest.raises(HeapFitError, match="spheres on the plate"):
        fit_heap(np.zeros((3, 3)), np.full(3, 0.005))


@pytest.fixture(scope="module")
def quick_heaps():
    """The quick config's heap for seeds 0, 1, 2: (config, results, sphere states)."""
    config = quick_config()
    results, states = [], []
    for seed in range(3):
        run = _HeapRun(config, config.params.model_dump(), seed, RunControl())
        results.append(run.execute(time.monotonic()))
        assert results[-1].status is SimulationStatus.OK, results[-1].message
        states.append(run.sphere_state())
    return config, results, states


VARIANTS = [
    {"sectors": 4},
    {"sectors": 6},
    {"bin_width": 0.75},
    {"bin_width": 1.5},
    {"inner": 0.1},
    {"inner": 0.3},
    {"outer": 0.9},
    {"outer": 0.7},
]


def test_fit_is_insensitive_to_its_choices(quick_heaps):
    # Calibration compares means over seeds, so what matters is a choice's systematic shift of the
    # mean angle, against how well the fits determine that mean: each heap's angle has the
    # standard error of its least-squares line (angle_se_deg, from its residuals), the mean of n
    # heaps sqrt(sum se^2) / n, and the difference of two such means (default and variant) the
    # root sum of both. A choice passes if it moves the mean by less than twice that. (The two
    # fits read the same heaps, so the bound is generous by at most sqrt(2); a choice that biases
    # the line, such as cells whose size varies with rho, moves it by more.)
    config, results, states = quick_heaps
    default = [fit_heap(p, r, config=config.fit, diameter=0.01) for p, r in states]
    assert [res.responses["angle_deg"] for res in results] == pytest.approx([f.angle_deg for f in default])
    for variant in VARIANTS:
        fits = [fit_heap(p, r, config=FitConfig(**variant), diameter=0.01) for p, r in states]
        shift = np.mean([f.angle_deg for f in fits]) - np.mean([f.angle_deg for f in default])
        se = math.sqrt(sum(f.angle_se_deg**2 for f in fits + default)) / len(states)
        assert abs(shift) < 2 * se, (variant, shift, se)


def test_fit_standard_error_is_the_least_squares_one():
    # One sphere (d = 10 mm) per (sector, bin) cell, its top on h = 0.2 - 0.5 rho plus e or -e
    # alternately: the fitted line is exactly that one and the residuals are exactly +-e. The
    # fitted range 0.2 R..0.8 R (R = 0.195 m) holds bins k = 4..15 (rho_k = (k + 1/2) d) of the 8
    # sectors: n = 96 cells, sum (rho - mean)^2 = 8 d^2 sum (k - 9.5)^2 = 1144 d^2, so
    # se(slope) = sqrt(96 e^2 / 94 / (1144 d^2)) and se(angle) = se(slope) / (1 + 0.5^2).
    d, e = 0.01, 0.001
    points = []
    for sector in range(8):
        azimuth = -math.pi + (sector + 0.5) * math.pi / 4
        for k in range(20):
            rho = (k + 0.5) * d
            top = 0.2 - 0.5 * rho + e * (-1) ** (k + sector)
            points.append((rho * math.cos(azimuth), rho * math.sin(azimuth), top - 0.5 * d))

    fit = fit_heap(np.array(points), np.full(len(points), 0.5 * d))

    assert fit.radius == pytest.approx(0.195)
    assert fit.angle_deg == pytest.approx(math.degrees(math.atan(0.5)), abs=1e-9)
    slope_se = math.sqrt(96 * e * e / 94 / (1144 * d * d))
    assert fit.angle_se_deg == pytest.approx(math.degrees(slope_se / 1.25), rel=1e-9)


def test_quick_heap_comes_to_rest_within_seconds(quick_heaps):
    config, results, states = quick_heaps
    result, (points, _) = results[0], states[0]
    assert 10 < result.responses["angle_deg"] < 35
    assert result.sim_time < config.stages.max_time  # ended at rest, not at the time limit
    assert result.n_items == config.particles.count
    # The heap stands where the cylinder was: its centroid is on the axis.
    assert np.hypot(*points[:, :2].mean(axis=0)) < 0.01


def test_angle_grows_with_friction():
    config = quick_config(particles={"count": 600}, cylinder={"diameter": 0.13}, plate={"size": 0.4})
    angles = {
        mu: registry.get("angle_of_repose").run(config, {"mu": mu}, 0).responses["angle_deg"]
        for mu in (0.0, 1.0)
    }
    assert angles[1.0] > angles[0.0] + 2.0, angles


def test_geometry_and_packing_are_the_engines_common_input():
    config = quick_config()
    packing = sphere_packing(config, seed=3)
    assert len(packing.positions) == config.particles.count
    r = 0.5 * config.particles.diameters()[packing.size_class]
    inner = 0.5 * config.cylinder.diameter * math.cos(math.pi / config.cylinder.segments)
    assert np.all(np.hypot(packing.positions[:, 0], packing.positions[:, 1]) + r < inner)
    assert np.all(packing.positions[:, 2] - r > 0)
    gaps = np.linalg.norm(packing.positions[:, None] - packing.positions[None], axis=2) - (
        r[:, None] + r[None]
    )
    assert np.all(gaps[~np.eye(len(r), dtype=bool)] > 0)  # no overlap at the start
    geometry = heap_geometry(config, packing.column)
    assert geometry.lift_distance > packing.column
    assert np.array_equal(sphere_packing(config, seed=3).positions, packing.positions)


def test_config_errors_name_the_key():
    with pytest.raises(ValidationError, match="cylinder.height"):
        quick_config(particles={"count": 5000})
    with pytest.raises(ValidationError, match="plate.size"):
        quick_config(plate={"size": 0.05})


def test_items_heap_runs_with_the_builtin_engine():
    config = quick_config(
        particles={"shape": "items", "items": {"counts": {"feature_phone": 3, "camera": 3}, "resolution": 6}},
        cylinder={"diameter": 0.5, "height": 0.5},
        plate={"size": 1.2, "roughness": 0.0},
        params={"E": 1e6},
        stages={"max_time": 1.2},
    )
    result = registry.get("angle_of_repose").run(config, {}, 1)
    # Six items make no cone to fit; the run must still end with a result that says why.
    assert result.status in (SimulationStatus.OK, SimulationStatus.ERROR)
    assert result.n_items == 6
    if result.status is SimulationStatus.ERROR:
        assert "heap" in result.message


def test_liggghts_agrees_with_the_builtin_engine_within_the_seed_spread(liggghts):
    config = quick_config()
    scenario = registry.get("angle_of_repose")
    angles = {"numba": [], "liggghts": []}
    for engine in angles:
        for seed in range(3):
            result = run_scenario(scenario, config, {"mu": 0.5}, seed, engine=engine)
            assert result.status is SimulationStatus.OK, result.message
            assert result.engine == engine and result.wall_time_s > 0 and result.steps > 0
            angles[engine].append(result.responses["angle_deg"])
    ours, theirs = np.array(angles["numba"]), np.array(angles["liggghts"])
    spread = max(ours.std(ddof=1), theirs.std(ddof=1), 1.0)
    assert abs(ours.mean() - theirs.mean()) < 2 * spread, angles
