"""The combined scenario's configuration (``kind = "combined"``): named parts, each an ordinary
scenario config with its own ``kind`` (and optionally its own ``engine``); see
``dem/scenarios/combined.py``.

Only pydantic here: a study definition names this model in its scenario union
(``dem/scenarios/registry.py``) without importing the engine. Parts are validated by their kind's
config model through the registry, which loads only config models too.
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import Field, field_validator

from dem.scenarios.base import ParamsConfig, Scenario, Section

PART_NAME = r"^[A-Za-z][A-Za-z0-9_]*$"


class CombinedConfig(Section):
    kind: Literal["combined"] = "combined"
    params: ParamsConfig = Field(default_factory=ParamsConfig)
    parts: dict[str, dict[str, Any]] = Field(
        ..., min_length=1, description="Named scenario configs, each with its kind (and an optional engine)."
    )

    @field_validator("parts")
    @classmethod
    def _parts(cls, parts: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        from dem.scenarios.registry import validate_config

        checked = {}
        for name, part in parts.items():
            if not re.match(PART_NAME, name):
                raise ValueError(f"parts.{name}: a part's name is a letter then letters, digits or _")
            if not isinstance(part, dict):
                raise ValueError(f"parts.{name}: expected a table with the part's kind and settings")
            if part.get("kind") == "combined":
                raise ValueError(f"parts.{name}: parts cannot be combined scenarios themselves")
            engine = part.get("engine")
            config = validate_config({k: v for k, v in part.items() if k != "engine"}, prefix=f"parts.{name}")
            checked[name] = {**config, **({"engine": engine} if engine else {})}
        return checked

    def part(self, name: str) -> tuple[Scenario, dict[str, Any], str | None]:
        from dem.scenarios.registry import for_config

        data = dict(self.parts[name])
        engine = data.pop("engine", None)
        return for_config(data), data, engine
