"""Several experiments on one material: a scenario whose run is one run of each of its parts.

A study calibrating N parameters needs about N independent responses; a heap's angle constrains
friction, the feeder's N_t constrains the collision parameters too. ``kind = "combined"`` holds
named parts, each an ordinary scenario config (with its own ``kind``) and optionally its own
engine::

    [scenario]
    kind = "combined"
    [scenario.parts.heap]
    kind = "angle_of_repose"
    engine = "liggghts"        # optional; the study's engine otherwise
    [scenario.parts.feeder]
    kind = "feeder"

Every part runs with the same contact parameters and seed; the responses are the parts'
responses named ``<part>.<response>`` (``heap.angle_deg``, ``feeder.n_remaining``), so a study's
experiments name them like any other. Wall time, steps and cost add up; the first part that does
not end ``ok`` gives the run its status and message (the others' responses are kept).
"""

from __future__ import annotations

import time

from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.base import Response, RunControl, Scenario
from dem.scenarios.combined_config import CombinedConfig


def responses_of(config: CombinedConfig) -> tuple[Response, ...]:
    declared = []
    for name in config.parts:
        scenario, data, _ = config.part(name)
        for response in scenario.declared(data):
            declared.append(
                Response(
                    f"{name}.{response.name}",
                    response.unit,
                    response.integer,
                    scenario.failed_responses(data)[response.name],
                    f"{name}: {response.description}",
                    f"{name} {response.label or response.name}",
                )
            )
    return tuple(declared)


def run_combined(config: CombinedConfig, params: dict[str, float], seed: int, control: RunControl):
    from dem.engines.base import DEFAULT_ENGINE, run_scenario

    started = time.monotonic()
    responses: dict[str, float | int | None] = {}
    status, message = SimulationStatus.OK, ""
    totals = {"steps": 0, "cost": 0.0, "sim_time": 0.0, "n_items": 0}
    merged = {**config.params.model_dump(), **params}
    for name in config.parts:
        scenario, data, engine = config.part(name)
        part_params = {k: v for k, v in merged.items()}
        result = run_scenario(scenario, data, part_params, seed, control, engine=engine or DEFAULT_ENGINE)
        for key, value in result.responses.items():
            responses[f"{name}.{key}"] = value
        totals["steps"] += result.steps
        totals["cost"] += result.cost
        totals["sim_time"] += result.sim_time
        totals["n_items"] += result.n_items
        if result.status is not SimulationStatus.OK and status is SimulationStatus.OK:
            status, message = result.status, f"{name}: {result.message}"
            if result.status in (SimulationStatus.TIMEOUT, SimulationStatus.CANCELLED):
                break
    for response in responses_of(config):
        responses.setdefault(response.name, None)
    return SimulationResult(
        status=status,
        message=message,
        responses=responses,
        wall_time_s=time.monotonic() - started,
        params={k: float(v) for k, v in merged.items()},
        seed=seed,
        **totals,
    )


def _sum(config: CombinedConfig, params: dict[str, float], what: str) -> float:
    total = 0.0
    for name in config.parts:
        scenario, data, _ = config.part(name)
        total += scenario.cost_estimate(data, params) if what == "cost" else scenario.duration(data) or 0.0
    return total


def _time_step(config: CombinedConfig, params: dict[str, float]) -> float:
    steps = []
    for name in config.parts:
        scenario, data, _ = config.part(name)
        steps.append(scenario.time_step(data, params))
    return min(steps)


SCENARIO = Scenario(
    kind="combined",
    title="several experiments on one material (each part one scenario)",
    config_model=CombinedConfig,
    responses=(),
    responses_function=responses_of,
    run_function=run_combined,
    cost_function=lambda config, params: _sum(config, params, "cost"),
    time_step_function=_time_step,
    duration_function=lambda config: _sum(config, {}, "duration"),
    failed_function=lambda config: {r.name: r.failed_value for r in responses_of(config)},
    engines=("numba",),
    progress_label="bodies",
)
