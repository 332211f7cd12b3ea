"""What every scenario declares, so that nothing outside ``dem/scenarios/`` needs to know one.

A scenario is one laboratory experiment made a simulation (the vibration feeder, a heap's angle
of repose). Its module defines a ``Scenario`` object, listed in ``dem/scenarios/registry.py``
under its ``kind``; studies, workers, the API and the CLI then reach it only through
``registry.get(kind)``, and a study definition reaches its config model only through
``registry.ScenarioConfig``.

A scenario declares:

* ``kind`` — the name a study's ``[scenario]`` table carries as ``kind = "..."``;
* ``config_model`` — a pydantic model of its configuration, with a ``kind: Literal[...]`` field
  (the discriminator of ``StudyDefinition.scenario``) and a ``params`` section of default contact
  parameters (``ParamsConfig``), in a module of its own that imports nothing heavy;
* ``responses`` — the named quantities a run measures (``Response``: unit, integer or real, the
  value a failed run gets, which the objectives use as the worst case, and the short label the
  dashboard's axes and tables print with the unit, "angle of repose (deg)");
* ``cost_estimate(config, params)`` — the run's expected work in body-steps (bodies x time steps),
  which sizes job timeouts and orders trials longest first; and ``time_step(config, params)``,
  the step the engine will take (a cheap estimate);
* ``run(config, params, seed, control)`` — one run with the built-in engine; it never raises and
  returns a ``dem.result.SimulationResult`` whose ``responses`` holds every declared response
  (``None`` when the run failed);
* ``engines`` — which engines can run it (``"numba"`` always; ``"liggghts"`` when an adapter exists
  in ``dem/engines/liggghts.py``; ``"command"`` for any scenario).

How to add a scenario (the angle of repose, ``dem/scenarios/heap_config.py`` and
``dem/scenarios/heap.py``, followed this recipe):

1. write its config model (``kind: Literal["<kind>"] = "<kind>"``, a ``params`` section, the rest
   ``Section``s) in ``dem/scenarios/<name>_config.py``, importing only pydantic, numpy and other
   config modules: every study definition imports it (``tests/dem/test_scenario_registry.py``
   checks that no engine comes with it);
2. write ``dem/scenarios/<name>.py`` with its ``run`` and a module-level ``SCENARIO = Scenario(...)``
   whose ``config_model`` is that model;
3. add ``"<kind>": ("dem.scenarios.<name>_config:<Model>", "dem.scenarios.<name>")`` to ``BUILT_IN``
   in ``dem/scenarios/registry.py``: the study's scenario union and the API's schema gain it;
4. add a quick example config under ``examples/`` and tests under ``tests/dem/``: the registry test
   then checks the declaration (every response produced, cost positive, JSON round trip, the
   config model the one the union holds).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_serializer

from dem.parameters import ALL_PARAMETER_NAMES, range_problem, unknown_names_problem
from dem.result import SimulationResult


class Section(BaseModel):
    """A config section: unknown keys are errors, so a typo never silently keeps a default."""

    # Every number finite: ``inf`` or ``nan`` would only fail later, in a worker.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class ParamsConfig(Section):
    """Contact parameters used when the caller does not give them (the paper's Table 2 area);
    their ranges are ``dem/parameters.py``'s. The item-wall ones are optional: unset, the walls
    are of the items' material (and a dump leaves them out, so a config written before they
    existed reads and writes as it did)."""

    E: float = Field(1e7, description="Young's modulus, Pa.")
    nu: float = Field(0.3, description="Poisson's ratio.")
    e: float = Field(0.5, description="Restitution coefficient.")
    mu: float = Field(0.5, description="Friction coefficient.")
    E_wall: float | None = Field(None, description="The walls' Young's modulus, Pa; default E.")
    nu_wall: float | None = Field(None, description="The walls' Poisson's ratio; default nu.")
    e_wall: float | None = Field(None, description="Item-wall restitution; default e.")
    mu_wall: float | None = Field(None, description="Item-wall friction; default mu.")

    @field_validator(*ALL_PARAMETER_NAMES)
    @classmethod
    def _physical(cls, value: float | None, info: ValidationInfo) -> float | None:
        problem = None if value is None else range_problem(info.field_name, value)
        if problem is not None:
            raise ValueError(problem)
        return value

    @model_serializer(mode="wrap")
    def _without_unset_wall(self, handler):
        data = handler(self)
        return {key: value for key, value in data.items() if value is not None}


@dataclass(frozen=True)
class Response:
    """One measured quantity of a scenario."""

    name: str
    unit: str  # "1" for pure numbers; a count says what it counts ("items")
    integer: bool
    failed_value: float  # what a failed run counts as in the objectives: the worst plausible value
    description: str = ""
    label: str = ""  # short name for plot axes and tables ("N_t", "angle of repose"); default: name

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "unit": self.unit,
            "type": "integer" if self.integer else "real",
            "failed_value": self.failed_value,
            "description": self.description,
            "label": self.label or self.name,
        }


@dataclass
class RunControl:
    """How a caller steers a run: a wall-clock deadline (``time.monotonic()``), a stop request
    polled between chunks, a progress callback (simulated time, a scenario-specific count) and
    optional output folders (snapshots for the dashboard's replay, ParaView files)."""

    deadline: float | None = None
    should_stop: Callable[[], bool] | None = None
    progress: Callable[[float, int], None] | None = None
    snapshot_dir: Path | None = None
    vtk_dir: Path | None = None


RunFunction = Callable[[Any, dict[str, float], int, RunControl], SimulationResult]


@dataclass(frozen=True)
class Scenario:
    """A registered scenario kind; see the module docstring."""

    kind: str
    title: str
    config_model: type[BaseModel]
    responses: tuple[Response, ...]
    run_function: RunFunction
    cost_function: Callable[[Any, dict[str, float]], float]
    time_step_function: Callable[[Any, dict[str, float]], float]
    responses_function: Callable[[Any], tuple[Response, ...]] | None = None  # config-dependent responses
    duration_function: Callable[[Any], float] | None = None  # simulated s a run lasts at most
    load_function: Callable[[Path], BaseModel] | None = None  # a TOML file with paths made absolute
    failed_function: Callable[[Any], dict[str, float]] | None = None  # config-dependent worst values
    engines: tuple[str, ...] = ("numba", "command")
    progress_label: str = "bodies"
    extra: dict[str, Any] = field(default_factory=dict)

    def config(self, data: dict[str, Any] | BaseModel, context: dict[str, Any] | None = None) -> BaseModel:
        """Validate a config given as a mapping (``kind`` may be omitted); ``context`` is
        pydantic's (``dem.scenarios.paths.READ_FILES`` for the user's own files)."""
        if isinstance(data, self.config_model):
            return data
        return self.config_model.model_validate({**dict(data), "kind": self.kind}, context=context)

    def declared(self, config=None) -> tuple[Response, ...]:
        """The responses a run of this config measures (a combined scenario's depend on its parts)."""
        if self.responses_function is not None and config is not None:
            return tuple(self.responses_function(self.config(config)))
        return self.responses

    def response(self, name: str, config=None) -> Response:
        declared = self.declared(config)
        for response in declared:
            if response.name == name:
                return response
        known = ", ".join(r.name for r in declared)
        raise KeyError(f"scenario {self.kind!r} has no response {name!r}; it measures {known}")

    def run(self, config, params: dict[str, float], seed: int, control: RunControl | None = None):
        return self.run_function(self.config(config), dict(params), int(seed), control or RunControl())

    def cost_estimate(self, config, params: dict[str, float]) -> float:
        return float(self.cost_function(self.config(config), dict(params)))

    def time_step(self, config, params: dict[str, float]) -> float:
        return float(self.time_step_function(self.config(config), dict(params)))

    def duration(self, config) -> float | None:
        """Simulated seconds a run lasts at most (progress bars and logs); None if unknown."""
        return None if self.duration_function is None else float(self.duration_function(self.config(config)))

    def describe(self, responses: dict[str, Any], config=None) -> str:
        """Responses as text with units: 'angle_deg=21.3 deg, height=0.04 m'."""
        parts = []
        for r in self.declared(config):
            value = responses.get(r.name)
            shown = "-" if value is None else (f"{int(value)}" if r.integer else f"{value:.4g}")
            parts.append(f"{r.name}={shown}" + ("" if r.unit == "1" or value is None else f" {r.unit}"))
        return ", ".join(parts)

    def failed_responses(self, config=None) -> dict[str, float | int]:
        """What each response counts as when a run failed (the config may change the worst case)."""
        declared = self.declared(config)
        values = {r.name: r.failed_value for r in declared}
        if config is not None and self.failed_function is not None:
            values.update(self.failed_function(self.config(config)))
        return {r.name: (int(values[r.name]) if r.integer else float(values[r.name])) for r in declared}


def merged_params(config_params: ParamsConfig, params: dict[str, float]) -> tuple[dict[str, float], str]:
    """The run's contact parameters (the caller's over the config's) and an error, '' when usable.
    Item-wall parameters appear only when the caller or the config gives them."""
    merged = {**config_params.model_dump(), **params}
    problem = unknown_names_problem(sorted(params))
    if problem:
        return _floats(merged), problem
    try:
        return ParamsConfig.model_validate(merged).model_dump(), ""
    except Exception as exc:  # pydantic ValidationError, or a value that is not a number
        return _floats(merged), f"bad parameters: {exc}"


def _floats(values: dict) -> dict[str, float]:
    """Parameters as floats where they are numbers, so that an error result still validates."""
    out = {}
    for key, value in values.items():
        try:
            out[str(key)] = float(value)
        except (TypeError, ValueError):
            out[str(key)] = math.nan
    return out


def field_path(
    model: type[BaseModel] | None, loc: Sequence[Any]
) -> tuple[tuple[Any, ...], type[BaseModel] | None]:
    """A pydantic error location as the user wrote it, and the model its last key belongs to
    (None when the path leaves the models). pydantic puts a discriminated union's tag after the
    field (``scenario.angle_of_repose.cylinder``); the user wrote ``scenario.cylinder``."""
    path: list[Any] = []
    owner, current = None, model
    rest = list(loc)
    while rest:
        part = rest.pop(0)
        path.append(part)
        if isinstance(part, int):  # an index into a list: the same model
            continue
        owner = current
        field = current.model_fields.get(str(part)) if current is not None else None
        if field is None:
            current = None
            continue
        members = [
            c for c in (field.annotation, *get_args(field.annotation))
            if isinstance(c, type) and issubclass(c, BaseModel)
        ]
        current = members[0] if members else None
        if field.discriminator and rest:
            tagged = {m.model_fields[field.discriminator].default: m for m in members}
            if rest[0] in tagged:
                current = tagged[rest.pop(0)]
    return tuple(path), owner


def nearest_key(model: type[BaseModel] | None, loc: Sequence[Any]) -> str | None:
    """The valid key closest to an unknown one at ``loc`` (a pydantic error location) in
    ``model``, for "did you mean ...?"; None when nothing is close or the path leaves the models."""
    path, owner = field_path(model, loc)
    if owner is None or not path:
        return None
    close = difflib.get_close_matches(str(path[-1]), list(owner.model_fields), n=1, cutoff=0.6)
    return close[0] if close else None


def error_message(err: dict[str, Any], model: type[BaseModel] | None) -> str:
    """One pydantic error's message; an unknown key names the nearest valid one."""
    message = str(err.get("msg", "invalid")).removeprefix("Value error, ")
    if err.get("type") == "extra_forbidden":
        near = nearest_key(model, tuple(err.get("loc", ())))
        message = f"unknown key{f'; did you mean {near!r}?' if near else ''}"
    return message


def error_line(err: dict[str, Any], model: type[BaseModel] | None, prefix: str = "") -> str:
    """One pydantic error as ``where: message``, ``where`` the key's path as the user wrote it
    under ``prefix``, given once (not again when the message starts with it)."""
    path, _ = field_path(model, tuple(err.get("loc", ())))
    where = ".".join(str(part) for part in (prefix, *path) if part != "")
    message = error_message(err, model)
    return message if not where or message.startswith(where) else f"{where}: {message}"
