"""The scenario registry: every scenario kind by name, so callers never import a scenario module.

``get(kind)`` returns the ``dem.scenarios.base.Scenario``; ``kinds()`` lists them. Built-in
scenarios are the modules in ``BUILT_IN`` (each defines ``SCENARIO``), imported on first use so
that importing the registry stays cheap; ``register`` adds one at run time (a plug-in, a test).
A config without ``kind`` is a feeder config: studies stored before the registry existed had no
``kind`` key (``DEFAULT_KIND``).
"""

from __future__ import annotations

import importlib
import threading
import tomllib
from pathlib import Path
from typing import Any

from dem.scenarios.base import Scenario, error_message

BUILT_IN = ("dem.scenarios.feeder", "dem.scenarios.heap", "dem.scenarios.combined")
DEFAULT_KIND = "feeder"

_registry: dict[str, Scenario] = {}
_loaded = False
_loading = threading.Lock()
_loader: int | None = None


class UnknownScenarioError(KeyError):
    """No scenario of that kind; the message lists the known kinds."""

    def __str__(self) -> str:  # KeyError would print the message in quotes
        return str(self.args[0])


def _load_built_ins() -> None:
    """Import the built-ins once. ``serve`` asks from its request threads and its driver thread
    at once: a thread must never see the flag set before the kinds are registered."""
    global _loaded, _loader
    if _loaded or _loader == threading.get_ident():  # done, or a built-in asking while it loads
        return
    with _loading:
        if _loaded:
            return
        _loader = threading.get_ident()
        try:
            for module in BUILT_IN:
                register(importlib.import_module(module).SCENARIO)
            _loaded = True
        finally:
            _loader = None


def register(scenario: Scenario) -> Scenario:
    """Add (or replace) a scenario kind."""
    _registry[scenario.kind] = scenario
    return scenario


def kinds() -> list[str]:
    _load_built_ins()
    return sorted(_registry)


def get(kind: str) -> Scenario:
    _load_built_ins()
    try:
        return _registry[kind]
    except KeyError:
        raise UnknownScenarioError(
            f"unknown scenario kind {kind!r}; known kinds: {', '.join(sorted(_registry))}"
        ) from None


def kind_of(config: dict[str, Any]) -> str:
    """The kind a config mapping declares (``feeder`` when it has none)."""
    return str(config.get("kind") or DEFAULT_KIND)


def for_config(config: dict[str, Any]) -> Scenario:
    """The scenario a config mapping belongs to."""
    return get(kind_of(config))


class ScenarioConfigError(ValueError):
    """A scenario config is not valid; the message names each key as ``scenario.<key>``."""


def validate_config(data: dict[str, Any], prefix: str = "scenario") -> dict[str, Any]:
    """The config validated by its kind's model, as JSON-able data with ``kind`` set; errors are
    one ``ScenarioConfigError`` naming every bad key (``scenario.cylinder.height: ...``)."""
    from pydantic import ValidationError

    if not isinstance(data, dict):
        raise ScenarioConfigError(f"{prefix}: expected a table of the scenario's settings")
    try:
        scenario = for_config(data)
    except UnknownScenarioError as exc:
        raise ScenarioConfigError(f"{prefix}.kind: {exc}") from None
    try:
        return scenario.config({k: v for k, v in data.items() if k != "kind"}).model_dump(mode="json")
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            where = ".".join(str(part) for part in err["loc"])
            message = error_message(err, scenario.config_model)
            problems.append(f"{prefix}{'.' + where if where else ''}: {message}")
        raise ScenarioConfigError("; ".join(problems)) from None


def config_json_schema() -> dict[str, Any]:
    """The JSON Schema of a config of any registered kind, self-contained (no ``$ref``), so that
    an API can publish it for a field holding a scenario. A kind other than ``DEFAULT_KIND`` must
    be named; every alternative forbids unknown keys, as ``validate_config`` does."""
    _load_built_ins()
    alternatives = []
    for kind in sorted(_registry):
        schema = _inline(_registry[kind].config_model.model_json_schema())
        if kind != DEFAULT_KIND:
            schema["required"] = sorted({*schema.get("required", []), "kind"})
        alternatives.append(schema)
    return {"anyOf": alternatives}


def publish_config_schema(schema: dict[str, Any]) -> None:
    """``json_schema_extra`` for a field that holds a scenario config as a plain mapping (it is
    validated by ``validate_config``): its published schema becomes ``config_json_schema()``,
    computed when the schema is asked for, not when the field's module is imported."""
    description = schema.get("description")
    schema.clear()
    schema.update(config_json_schema())
    if description:
        schema["description"] = description


def _inline(schema: dict[str, Any]) -> dict[str, Any]:
    definitions = schema.pop("$defs", {})

    def resolve(node: Any) -> Any:
        if isinstance(node, dict):
            if "$ref" in node:
                target = resolve(definitions[node["$ref"].rsplit("/", 1)[-1]])
                return {**target, **{k: resolve(v) for k, v in node.items() if k != "$ref"}}
            return {key: resolve(value) for key, value in node.items()}
        if isinstance(node, list):
            return [resolve(item) for item in node]
        return node

    return resolve(schema)


def load_config_file(path: Path | str):
    """A scenario config from a TOML file (its ``kind`` picks the scenario; relative paths in it
    are taken from the file's folder where the scenario has such paths)."""
    path = Path(path)
    with path.open("rb") as handle:
        data = tomllib.load(handle)
    scenario = for_config(data)
    if scenario.load_function is not None:
        return scenario.load_function(path)
    return scenario.config({k: v for k, v in data.items() if k != "kind"})
