"""The combined scenario (``dem/scenarios/combined.py``): several experiments on one material,
each part run with the same parameters and seed, responses named ``<part>.<response>``."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from dem.result import SimulationStatus
from dem.scenarios import registry

HEAP = {
    "kind": "angle_of_repose",
    "particles": {"count": 200},
    "cylinder": {"diameter": 0.08, "height": 0.13, "segments": 16},
    "stages": {"lift_start": 0.15, "rest_speed": 0.02},
    "run": {"dt_fraction": 0.1},
}
FEEDER = {
    "kind": "feeder",
    "items": {"counts": {"camera": 1}},
    "stages": {"insertion_time": 0.05, "vibration_start": 0.3, "vibration_time": 0.1},
}


def test_parts_run_with_the_same_parameters_and_seed_and_their_responses_add_up():
    combined = registry.get("combined")
    config = combined.config({"parts": {"heap": HEAP, "feeder": FEEDER}})
    params = {"E": 1e5, "mu": 0.4}

    result = combined.run(config, params, 3)
    heap = registry.get("angle_of_repose").run(HEAP, params, 3)
    feeder = registry.get("feeder").run(FEEDER, params, 3)

    assert result.status is SimulationStatus.OK, result.message
    assert result.responses == {
        "heap.angle_deg": heap.responses["angle_deg"],
        "heap.height": heap.responses["height"],
        "feeder.n_remaining": feeder.responses["n_remaining"],
    }
    assert result.steps == heap.steps + feeder.steps and result.n_items == heap.n_items + feeder.n_items
    assert combined.cost_estimate(config, params) == pytest.approx(
        registry.get("angle_of_repose").cost_estimate(HEAP, params)
        + registry.get("feeder").cost_estimate(FEEDER, params)
    )


def test_bad_parts_are_named():
    combined = registry.get("combined")
    with pytest.raises(ValidationError, match=r"parts.heap: particles.count = 5000 .* cylinder.height"):
        combined.config({"parts": {"heap": {**HEAP, "particles": {"count": 5000}}}})
    with pytest.raises(ValidationError, match=r"parts.x.kind: unknown scenario kind 'drum'"):
        combined.config({"parts": {"x": {"kind": "drum"}}})
    with pytest.raises(ValidationError, match="cannot be combined"):
        combined.config({"parts": {"x": {"kind": "combined", "parts": {}}}})
