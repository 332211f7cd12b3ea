"""The built-in engine: the numba kernels of ``dem/`` through the scenario's own ``run``."""

from __future__ import annotations

from dem.parameters import ALL_PARAMETER_NAMES
from dem.scenarios.base import RunControl, Scenario


class BuiltinEngine:
    name = "numba"
    parameters = ALL_PARAMETER_NAMES

    def unavailable(self, options=None) -> str:
        return ""

    def refuses(self, scenario: Scenario, config, options=None) -> str:
        return ""

    def run(self, scenario: Scenario, config, params, seed: int, control: RunControl, options=None):
        return scenario.run(config, params, seed, control)
