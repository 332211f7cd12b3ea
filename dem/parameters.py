"""The four contact parameters the calibration searches (E, nu, e, mu) and their physical ranges.

The one home of both facts: the contact law, the feeder's config, the optimiser's study
definition, the API and the CLI all read them from here. Plain Python (no numba), so that the
API and the CLI can check a value without loading the engine.
"""

from __future__ import annotations

import math

PARAMETER_NAMES = ("E", "nu", "e", "mu")
PARAMETER_MEANINGS = {
    "E": "Young's modulus, Pa", "nu": "Poisson's ratio", "e": "restitution", "mu": "friction",
}
# name: (low, high, low inclusive, high inclusive): E > 0, -1 < nu < 0.5, 0 < e <= 1, mu >= 0.
PHYSICAL_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "E": (0.0, math.inf, False, False),
    "nu": (-1.0, 0.5, False, False),
    "e": (0.0, 1.0, False, True),
    "mu": (0.0, math.inf, True, False),
}


def in_physical_range(name: str, value: float) -> bool:
    """Whether ``value`` is a finite number inside the physical range of parameter ``name``."""
    low, high, low_in, high_in = PHYSICAL_RANGES[name]
    above = value >= low if low_in else value > low
    below = value <= high if high_in else value < high
    return above and below and math.isfinite(value)


def physical_range_text(name: str) -> str:
    """The range as an interval, e.g. ``(0, 1]`` for e."""
    low, high, low_in, high_in = PHYSICAL_RANGES[name]
    return f"{'[' if low_in else '('}{low:g}, {high:g}{']' if high_in else ')'}"


def range_problem(name: str, value: object) -> str | None:
    """Why ``value`` cannot be parameter ``name`` (a sentence naming it), or None if it can."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{name} ({PARAMETER_MEANINGS[name]}) must be a number, got {value!r}"
    if not in_physical_range(name, value):
        return (
            f"{name} = {value} is outside its physical range {physical_range_text(name)} "
            f"({PARAMETER_MEANINGS[name]})"
        )
    return None
