"""The engine protocol and the engine registry: how a scenario run reaches an engine.

An engine has a ``name`` (what a study's ``engine = "..."`` says), the contact parameters it
can apply (``parameters``: the items' four and, where it has them, the item-wall ones), tells
whether it can run on this machine (``unavailable()``: '' or why not, e.g. the ``liggghts``
binary is missing) and whether it can run a given scenario config (``refuses(scenario,
config)``: '' or why not), and runs one simulation: ``run(scenario, config, params, seed,
control, options)`` returns a ``dem.result.SimulationResult`` with the scenario's declared
``responses``, the wall time and its ``engine`` name, and never raises. ``options`` are the
study's engine options (the command engine's template and command; LIGGGHTS' binary path).

How to add an engine:

1. write ``dem/engines/<name>.py`` with a class implementing ``Engine`` (an external engine
   writes its input into a fresh temporary folder, runs the program with the control's deadline
   as a timeout, reads the responses back; see ``liggghts.py``);
2. add it to ``_ENGINES`` below;
3. declare it in the ``engines`` of every scenario it supports (``dem/scenarios/base.py``), and
   test both engines on one case (``tests/dem/test_engines.py``).
A worker advertises the engines whose ``unavailable()`` is empty (``available_engines``).
"""

from __future__ import annotations

import importlib
import time
from typing import Any, Protocol

from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.base import RunControl, Scenario

_ENGINES = {
    "numba": ("dem.engines.builtin", "BuiltinEngine"),
    "liggghts": ("dem.engines.liggghts", "LiggghtsEngine"),
    "command": ("dem.engines.command", "CommandEngine"),
}
DEFAULT_ENGINE = "numba"


class Engine(Protocol):
    name: str
    parameters: tuple[str, ...]  # the contact parameters it can apply (``dem/parameters.py``)

    def unavailable(self, options: dict[str, Any] | None = None) -> str: ...

    def refuses(self, scenario: Scenario, config, options: dict[str, Any] | None = None) -> str: ...

    def run(
        self,
        scenario: Scenario,
        config,
        params: dict[str, float],
        seed: int,
        control: RunControl,
        options: dict[str, Any] | None = None,
    ) -> SimulationResult: ...


class UnknownEngineError(KeyError):
    def __str__(self) -> str:
        return str(self.args[0])


def engine_names() -> list[str]:
    return sorted(_ENGINES)


def get_engine(name: str) -> Engine:
    try:
        module, cls = _ENGINES[name]
    except KeyError:
        raise UnknownEngineError(
            f"unknown engine {name!r}; known engines: {', '.join(engine_names())}"
        ) from None
    return getattr(importlib.import_module(module), cls)()


def available_engines() -> list[str]:
    """The engines this machine can run (what a worker advertises)."""
    return [name for name in engine_names() if not get_engine(name).unavailable()]


def refusal(engine_name: str, scenario: Scenario, config, options: dict[str, Any] | None = None) -> str:
    """'' when ``engine_name`` can run this scenario config, else why not (checked at study creation);
    an engine that does not exist raises ``UnknownEngineError``."""
    engine = get_engine(engine_name)
    if engine_name not in scenario.engines:
        return (
            f"engine {engine_name!r} does not run scenario {scenario.kind!r}; it runs on "
            f"{', '.join(scenario.engines)}"
        )
    return engine.refuses(scenario, scenario.config(config), options)


def parameters_refusal(engine_name: str, names) -> str:
    """'' when the engine applies every one of these parameters, else which it cannot."""
    engine = get_engine(engine_name)
    missing = [name for name in names if name not in engine.parameters]
    if not missing:
        return ""
    return (
        f"engine {engine_name!r} cannot apply {', '.join(missing)}; it takes "
        f"{', '.join(engine.parameters)} (the built-in engine 'numba' takes them all)"
    )


def run_scenario(
    scenario: Scenario,
    config,
    params: dict[str, float],
    seed: int,
    control: RunControl | None = None,
    engine: str = DEFAULT_ENGINE,
    options: dict[str, Any] | None = None,
) -> SimulationResult:
    """One run of ``scenario`` on ``engine``; never raises (a refusal is an ``error`` result)."""
    started = time.monotonic()
    try:
        config = scenario.config(config)
        problem = refusal(engine, scenario, config, options)
        implementation = get_engine(engine)
        problem = problem or implementation.unavailable(options)
        if problem:
            return SimulationResult(
                status=SimulationStatus.ERROR,
                message=problem,
                seed=int(seed),
                engine=engine,
                params={k: float(v) for k, v in params.items()},
            )
        result = implementation.run(
            scenario, config, params, int(seed), control or RunControl(), options or {}
        )
    except Exception as exc:  # the contract: a result, never a traceback
        return SimulationResult(
            status=SimulationStatus.ERROR,
            message=f"{type(exc).__name__}: {exc}",
            seed=int(seed) if isinstance(seed, int) and seed >= 0 else 0,
            wall_time_s=time.monotonic() - started,
            engine=engine,
        )
    return result.model_copy(update={"engine": engine})
