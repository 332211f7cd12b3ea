"""The job function: one trial in, one simulation result out, as plain JSON-able dicts.

``run_trial(spec)`` is what every executor runs (the local process pool, the RQ worker through
``worker/rq_job.py``). ``spec`` is a ``TrialSpec`` as a dict: the scenario config inline (its
``kind`` finds the scenario in ``dem.scenarios.registry``), the contact parameters, the seed, an
optional wall-clock limit, and optionally ``engine`` / ``engine_options`` (``dem/engines``). It
never raises: a bad scenario, an exception in the engine, or anything else becomes a result with
status ``error`` and a message, so one bad simulation never takes a study or a worker down.
Only ``BaseException``s that are not ``Exception`` (KeyboardInterrupt, SystemExit) pass
through: they mean the process is stopping.

Must not: open a database, talk to Redis, or know about studies beyond the spec it is handed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dem.result import SimulationResult, SimulationStatus

logger = logging.getLogger(__name__)


def run_trial(
    spec: dict[str, Any],
    *,
    should_stop: Callable[[], bool] | None = None,
    progress: Callable[[float, int], None] | None = None,
    snapshot_root: Path | None = None,
    data_dir: Path | None = None,
) -> dict[str, Any]:
    """Run one simulation for ``spec``; returns ``SimulationResult.model_dump(mode="json")``.

    With ``spec["keep_snapshots"]`` and a ``snapshot_root`` (the worker's data dir), the run's
    snapshots go to ``snapshot_root/<trial id>/``, where the dashboard's replay reads them.
    The meshes the scenario names are this process's files in ``data_dir``
    (``dem/scenarios/paths.py``).
    """
    started = time.monotonic()
    params = spec.get("params") or {}
    seed = spec.get("seed", 0)
    try:
        from dem.engines.base import DEFAULT_ENGINE, run_scenario
        from dem.scenarios.base import RunControl
        from dem.scenarios.paths import resolve_paths
        from dem.scenarios.registry import for_config

        config = resolve_paths(spec["scenario"], data_dir)
        scenario = for_config(config)
        timeout_s = spec.get("timeout_s")
        control = RunControl(
            deadline=started + float(timeout_s) if timeout_s else None,
            should_stop=should_stop,
            progress=progress,
        )
        if spec.get("keep_snapshots") and snapshot_root is not None:
            control.snapshot_dir = Path(snapshot_root) / str(spec["trial_id"])
        result = run_scenario(
            scenario,
            config,
            dict(params),
            int(seed),
            control,
            engine=spec.get("engine") or DEFAULT_ENGINE,
            options=spec.get("engine_options"),
        )
    except Exception as exc:  # the contract: a result, never a traceback
        logger.exception("trial %s failed before or inside the simulation", spec.get("trial_id"))
        result = SimulationResult(
            status=SimulationStatus.ERROR,
            message=f"{type(exc).__name__}: {exc}",
            params=_floats(params),
            seed=seed if isinstance(seed, int) and seed >= 0 else 0,
            wall_time_s=time.monotonic() - started,
        )
    return result.model_dump(mode="json")


def _floats(params: dict[str, Any]) -> dict[str, float]:
    clean = {}
    for name, value in params.items():
        try:
            clean[str(name)] = float(value)
        except (TypeError, ValueError):
            continue  # an unusable value is already named in the error message
    return clean


def longest_first(specs: Sequence[Any], data_dir: Path | None = None) -> list[Any]:
    """Trial specs in the order executors should start them: the largest estimated cost first.

    The scenario estimates each trial's body-steps (``Scenario.cost_estimate``): the automatic
    step scales as 1/sqrt(E), so a stiffer trial takes more steps. Starting the longest trials
    first (LPT scheduling) keeps a generation from ending with one long trial running alone while
    the other workers idle. Equal estimates (a forced step) go stiffest first, as before.
    """
    def key(spec: Any) -> tuple[float, float]:
        return -estimated_cost(spec.scenario, spec.params, data_dir), -float(spec.params.get("E", 0.0))

    return sorted(specs, key=key)


def estimated_cost(scenario: dict[str, Any], params: dict[str, float], data_dir: Path | None = None) -> float:
    """The scenario's body-steps estimate, with its meshes from ``data_dir``; 0 for a config that
    does not validate (it will fail fast) or whose meshes are not here."""
    from dem.scenarios.paths import resolve_paths
    from dem.scenarios.registry import for_config

    try:
        config = resolve_paths(scenario, data_dir)
        return for_config(config).cost_estimate(config, params)
    except Exception:
        return 0.0
