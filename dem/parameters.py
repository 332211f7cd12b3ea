"""The contact parameters a calibration can search and their physical ranges.

The four of the paper's eq. 1-2 (E, nu, e, mu) are the items' material: every trial carries them.
The item-wall ones (E_wall, nu_wall, e_wall, mu_wall) are optional: a wall's Young's modulus and
Poisson's ratio, and the e and mu of the item-wall pair (``dem/materials.py``: e and mu belong to a
pair, normal stiffness comes from both E in series, tangential stiffness from both E and nu). A
trial that does not name one gets the item value it stands for (``item_parameter``), so a study
without them runs exactly as before they existed.

The one home of these facts: the contact law, the scenarios' configs, the optimiser's study
definition, the API and the CLI all read them from here. Plain Python (no numba), so that the
API and the CLI can check a value without loading the engine.
"""

from __future__ import annotations

import math

PARAMETER_NAMES = ("E", "nu", "e", "mu")
WALL_PARAMETER_NAMES = ("E_wall", "nu_wall", "e_wall", "mu_wall")
ALL_PARAMETER_NAMES = PARAMETER_NAMES + WALL_PARAMETER_NAMES  # the canonical order (the GA's genes)
PARAMETER_MEANINGS = {
    "E": "Young's modulus, Pa", "nu": "Poisson's ratio", "e": "restitution", "mu": "friction",
    "E_wall": "the walls' Young's modulus, Pa", "nu_wall": "the walls' Poisson's ratio",
    "e_wall": "item-wall restitution", "mu_wall": "item-wall friction",
}
# name: (low, high, low inclusive, high inclusive): E > 0, -1 < nu < 0.5, 0 < e <= 1, mu >= 0;
# a wall parameter has the range of the item parameter it stands for.
PHYSICAL_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "E": (0.0, math.inf, False, False),
    "nu": (-1.0, 0.5, False, False),
    "e": (0.0, 1.0, False, True),
    "mu": (0.0, math.inf, True, False),
}
PHYSICAL_RANGES.update({name: PHYSICAL_RANGES[name.removesuffix("_wall")] for name in WALL_PARAMETER_NAMES})


def item_parameter(name: str) -> str:
    """The item parameter a wall parameter takes when not given (``mu_wall`` -> ``mu``)."""
    return name.removesuffix("_wall")


def unknown_names_problem(names) -> str | None:
    """A sentence naming the unknown ones among ``names`` and the ones that fit, or None."""
    unknown = [name for name in names if name not in ALL_PARAMETER_NAMES]
    if not unknown:
        return None
    return (
        f"unknown parameter(s) {', '.join(map(str, unknown))}; the parameters are "
        f"{', '.join(PARAMETER_NAMES)} (the items' material) and, optionally, "
        f"{', '.join(WALL_PARAMETER_NAMES)} (the item-wall pair)"
    )


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
