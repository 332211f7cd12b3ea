"""The scenario registry: every scenario kind by name, so callers never import a scenario module.

``BUILT_IN`` is the one list of kinds: each kind's config model, in a module that imports only
pydantic and numpy (``dem/scenarios/<name>_config.py``), and the module of its ``SCENARIO`` (the
run, which imports the numba engine). ``config_model(kind)`` and ``ScenarioConfig`` (the
discriminated union on ``kind`` that ``StudyDefinition.scenario`` is) load only config models, so
that a study definition is cheap to import; ``get(kind)`` returns the ``Scenario`` and imports
its module on first use. A config without ``kind`` is a feeder config: studies stored before the
registry existed had no ``kind`` key (``DEFAULT_KIND``).
"""

from __future__ import annotations

import importlib
import tomllib
from pathlib import Path
from typing import Annotated, Any, Union

from pydantic import BaseModel, BeforeValidator, Field, ValidationInfo

from dem.scenarios.base import Scenario, error_line
from dem.scenarios.paths import READ_FILES

# kind -> ("module:ConfigModel", module defining SCENARIO)
BUILT_IN: dict[str, tuple[str, str]] = {
    "feeder": ("dem.scenarios.feeder_config:FeederConfig", "dem.scenarios.feeder"),
    "angle_of_repose": ("dem.scenarios.heap_config:HeapConfig", "dem.scenarios.heap"),
    "combined": ("dem.scenarios.combined_config:CombinedConfig", "dem.scenarios.combined"),
}
DEFAULT_KIND = "feeder"


class UnknownScenarioError(KeyError):
    """No scenario of that kind; the message lists the known kinds."""

    def __str__(self) -> str:  # KeyError would print the message in quotes
        return str(self.args[0])

    @classmethod
    def of(cls, kind: str) -> UnknownScenarioError:
        return cls(f"unknown scenario kind {kind!r}; known kinds: {', '.join(kinds())}")


def kinds() -> list[str]:
    return sorted(BUILT_IN)


def _entry(kind: str) -> tuple[str, str]:
    try:
        return BUILT_IN[kind]
    except KeyError:
        raise UnknownScenarioError.of(kind) from None


def config_model(kind: str) -> type[BaseModel]:
    """The config model of a kind, without importing its run (imports are thread-safe)."""
    module, name = _entry(kind)[0].split(":")
    return getattr(importlib.import_module(module), name)


def get(kind: str) -> Scenario:
    """The scenario of a kind; imports its module (and the engine) on first use."""
    return importlib.import_module(_entry(kind)[1]).SCENARIO


def _default_kind(data: Any, info: ValidationInfo) -> Any:
    """``kind`` may be left out for the feeder; an unknown one is named with the known kinds."""
    if not isinstance(data, dict):
        return data
    kind = data.get("kind") or DEFAULT_KIND
    if kind not in BUILT_IN:
        raise ValueError(f"{info.field_name}.kind: {UnknownScenarioError.of(kind)}")
    return {**data, "kind": kind}


ScenarioConfig = Annotated[
    Union[tuple(config_model(kind) for kind in BUILT_IN)],  # noqa: UP007 - a Union built from a tuple
    Field(discriminator="kind"),
    BeforeValidator(_default_kind),
]


def kind_of(config: dict[str, Any] | BaseModel) -> str:
    """The kind a config declares (``feeder`` when a mapping has none)."""
    if isinstance(config, BaseModel):
        return str(config.kind)
    return str(config.get("kind") or DEFAULT_KIND)


def for_config(config: dict[str, Any] | BaseModel) -> Scenario:
    """The scenario a config (a mapping or a validated model) belongs to."""
    return get(kind_of(config))


class ScenarioConfigError(ValueError):
    """A scenario config is not valid; the message names each key as ``scenario.<key>``."""


def validate_config(data: dict[str, Any], prefix: str = "scenario") -> dict[str, Any]:
    """The config validated by its kind's model, as JSON-able data with ``kind`` set; errors are
    one ``ScenarioConfigError`` naming every bad key (``scenario.cylinder.height: ...``)."""
    from pydantic import ValidationError

    if not isinstance(data, dict):
        raise ScenarioConfigError(f"{prefix}: expected a table of the scenario's settings")
    kind = kind_of(data)
    try:
        model = config_model(kind)
    except UnknownScenarioError as exc:
        raise ScenarioConfigError(f"{prefix}.kind: {exc}") from None
    try:
        return model.model_validate({**data, "kind": kind}).model_dump(mode="json")
    except ValidationError as exc:
        lines = [error_line(err, model, prefix) for err in exc.errors()]
        raise ScenarioConfigError("; ".join(lines)) from None


def load_config_file(path: Path | str) -> BaseModel:
    """A scenario config from a TOML file (its ``kind`` picks the scenario; relative paths in it
    are taken from the file's folder where the scenario has such paths)."""
    path = Path(path)
    with path.open("rb") as handle:
        data = tomllib.load(handle)
    scenario = for_config(data)
    if scenario.load_function is not None:
        return scenario.load_function(path)
    return scenario.config({k: v for k, v in data.items() if k != "kind"}, context=READ_FILES)
