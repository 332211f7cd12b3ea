r"""Materials and their pair interactions: what two touching surfaces do together.

Every body and every wall has a material (``Material``: a named ``ContactParams``). Restitution
and friction are properties of a *pair* of surfaces, not of one material, so, as in EDEM, Rocky and
LIGGGHTS (``coefficientRestitution`` / ``coefficientFriction`` given ``peratomtypepair``), a pair
may be given explicitly (``Interaction``); pairs not given follow the default combining rule.

The pair rule (each fact of it lives here once):

* stiffness: each body contributes ``k_i = E_i D_i`` and the two combine in series
  (``dem.contact.normal_stiffness``); a wall is the mirror image of the body with the wall's E
  (``dem.contact.wall_stiffness``). Stiffness is never a pair value: it follows from both E.
* restitution: the explicit pair value, else ``e_ab = sqrt(e_a e_b)``. Why the geometric mean: the
  rebound keeps the fraction ``e^2`` of the normal kinetic energy; letting each material keep its
  own fraction of it gives ``e_ab^2 = e_a e_b``, and like materials keep their own e.
* friction: the explicit pair value, else ``mu_ab = sqrt(mu_a mu_b)`` (like materials keep their
  own mu; a frictionless surface makes the pair frictionless).
* tangential stiffness: Mindlin's ratio for unlike materials,
  ``K_t / K_n = 4 G* / E*`` with ``1/E* = (1 - nu_a^2)/E_a + (1 - nu_b^2)/E_b`` and
  ``1/G* = (2 - nu_a)/G_a + (2 - nu_b)/G_b``, ``G = E / (2 (1 + nu))``; for like materials this is
  ``2 (1 - nu) / (2 - nu)`` (``dem.contact.tangential_stiffness_ratio``).

``MaterialTable`` numbers the distinct materials of a simulation and holds every pair's
``(zeta, mu, K_t/K_n)`` as arrays for the kernels. ``TrialMaterials`` turns a trial's parameters
(the items' four and the optional item-wall ones of ``dem/parameters.py``) into the items'
material, the walls' and their explicit pair. This module computes no forces.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dem.contact import ContactParams, ContactParamsError, damping_ratio, tangential_stiffness_ratio
from dem.parameters import PARAMETER_NAMES, WALL_PARAMETER_NAMES

# Columns of ``MaterialTable.law``.
L_ZETA, L_MU, L_KT = 0, 1, 2


class MaterialArrays(NamedTuple):
    """The table as the kernels see it."""

    E: np.ndarray  # (n,) Young's modulus of each material, Pa
    law: np.ndarray  # (n, n, 3) each pair's damping ratio, friction, K_t / K_n (``L_*``)


@dataclass(frozen=True)
class Material(ContactParams):
    """A named material: E, nu, and the e, mu it brings to pairs without an explicit value."""

    name: str = ""

    @classmethod
    def of(cls, params: ContactParams, name: str = "") -> Material:
        """``params`` as a material (unchanged if it already is one and no name is given)."""
        if isinstance(params, Material) and not name:
            return params
        name = name or getattr(params, "name", "")
        return cls(E=params.E, nu=params.nu, e=params.e, mu=params.mu, name=name)


@dataclass(frozen=True)
class Interaction:
    """Explicit e and mu of one pair of materials."""

    e: float
    mu: float

    def __post_init__(self) -> None:
        for name in ("e", "mu"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise ContactParamsError(f"{name} must be a finite number, got {value!r}")
        if not 0.0 < self.e <= 1.0:
            raise ContactParamsError(f"e (pair restitution) must be in (0, 1], got {self.e}")
        if self.mu < 0:
            raise ContactParamsError(f"mu (pair friction) must be >= 0, got {self.mu}")


def combined_interaction(a: ContactParams, b: ContactParams) -> Interaction:
    """The default rule: geometric means of e and of mu (a like pair keeps its values exactly)."""
    e = a.e if a.e == b.e else math.sqrt(a.e * b.e)
    mu = a.mu if a.mu == b.mu else math.sqrt(a.mu * b.mu)
    return Interaction(e=e, mu=mu)


def pair_tangential_ratio(a: ContactParams, b: ContactParams) -> float:
    """K_t / K_n = 4 G* / E* (Mindlin) for two materials; with one nu it is 2 (1 - nu) / (2 - nu)
    whatever the moduli, and is computed so."""
    if a.nu == b.nu:
        return tangential_stiffness_ratio(a.nu)
    g_a = a.E / (2.0 * (1.0 + a.nu))
    g_b = b.E / (2.0 * (1.0 + b.nu))
    e_star = 1.0 / ((1.0 - a.nu**2) / a.E + (1.0 - b.nu**2) / b.E)
    g_star = 1.0 / ((2.0 - a.nu) / g_a + (2.0 - b.nu) / g_b)
    return 4.0 * g_star / e_star


def _key(a: str, b: str) -> tuple[str, str]:
    return (a, b) if a <= b else (b, a)


class MaterialTable:
    """The materials of one simulation, numbered in order of first use, and every pair's law.

    ``explicit`` maps a pair of material names (either order) to its ``Interaction``. Materials
    are told apart by name; two different materials with one name are an error.
    """

    def __init__(self, explicit: Mapping[tuple[str, str], Interaction] | None = None) -> None:
        self.materials: list[Material] = []
        self._explicit: dict[tuple[str, str], Interaction] = {}
        for (a, b), interaction in (explicit or {}).items():
            if not isinstance(interaction, Interaction):
                raise ContactParamsError(f"pair ({a!r}, {b!r}): expected an Interaction, got {interaction!r}")
            self._explicit[_key(a, b)] = interaction
        self.E = np.zeros(0)
        self.law = np.zeros((0, 0, 3))

    def index(self, material: ContactParams) -> int:
        """The number of ``material``, adding it (and its pairs) on first use. An unnamed
        material is named by its values, so equal ones share a number."""
        material = Material.of(material)
        if not material.name:
            name = f"E={material.E:g} nu={material.nu:g} e={material.e:g} mu={material.mu:g}"
            material = Material.of(material, name)
        for k, known in enumerate(self.materials):
            if known.name == material.name:
                if known != material:
                    raise ContactParamsError(
                        f"two different materials are named {material.name!r}; give each its own name"
                    )
                return k
        self.materials.append(material)
        self._rebuild()
        return len(self.materials) - 1

    def interaction(self, a: ContactParams, b: ContactParams) -> Interaction:
        """The explicit interaction of the pair if given, else the combining rule's."""
        a, b = Material.of(a), Material.of(b)
        return self._explicit.get(_key(a.name, b.name)) or combined_interaction(a, b)

    def _rebuild(self) -> None:
        n = len(self.materials)
        self.E = np.array([m.E for m in self.materials], dtype=np.float64)
        self.law = np.zeros((n, n, 3))
        for i, a in enumerate(self.materials):
            for j, b in enumerate(self.materials):
                pair = self.interaction(a, b)
                self.law[i, j] = damping_ratio(pair.e), pair.mu, pair_tangential_ratio(a, b)

    def arrays(self) -> MaterialArrays:
        return MaterialArrays(self.E, self.law)

    def pairs(self) -> Iterable[tuple[Material, Material, Interaction]]:
        """Every unordered pair of known materials with its interaction."""
        for i, a in enumerate(self.materials):
            for b in self.materials[i:]:
                yield a, b, self.interaction(a, b)


@dataclass(frozen=True)
class TrialMaterials:
    """The materials of a scenario's run from its parameters: the items', and the walls' with the
    item-wall pair when a trial names any item-wall parameter (``WALL_PARAMETER_NAMES``).

    A wall of material ``walls`` has E = E_wall and nu = nu_wall (default: the items' E and nu;
    the normal stiffness is the two E in series, ``dem.contact.wall_stiffness``, the tangential
    one Mindlin's ratio of both materials, ``pair_tangential_ratio``); the pair (items, walls) has
    e = e_wall and mu = mu_wall (default: the items' e and mu). Without any of them ``walls`` is
    None: the walls take the items' material, as every run did before these parameters existed,
    and the run is the same to the last bit.
    """

    items: ContactParams
    walls: Material | None = None
    interactions: Mapping[tuple[str, str], Interaction] | None = None

    ITEMS = "items"

    @classmethod
    def of(cls, params: Mapping[str, float], wall: str = "walls") -> TrialMaterials:
        """From a run's merged parameters (``dem.scenarios.base.merged_params``); ``wall`` names
        the walls' material."""
        items = ContactParams(**{name: float(params[name]) for name in PARAMETER_NAMES})
        given = {name: float(params[name]) for name in WALL_PARAMETER_NAMES if params.get(name) is not None}
        if not given:
            return cls(items)
        items = Material.of(items, cls.ITEMS)
        E, nu = given.get("E_wall", items.E), given.get("nu_wall", items.nu)
        walls = Material(E=E, nu=nu, e=items.e, mu=items.mu, name=wall)
        pair = Interaction(e=given.get("e_wall", items.e), mu=given.get("mu_wall", items.mu))
        return cls(items, walls, {(cls.ITEMS, wall): pair})
