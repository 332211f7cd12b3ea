"""The pair rule of dem/materials.py: explicit pair values, the combining rule, Mindlin's ratio."""

from __future__ import annotations

import math

import pytest

from dem.contact import ContactParamsError, damping_ratio, tangential_stiffness_ratio
from dem.materials import (
    L_KT,
    L_MU,
    L_ZETA,
    Interaction,
    Material,
    MaterialTable,
    combined_interaction,
    pair_tangential_ratio,
)

RUBBER = Material(E=1e7, nu=0.45, e=0.9, mu=0.8, name="rubber")
STEEL = Material(E=2e11, nu=0.3, e=0.3, mu=0.2, name="steel")


def test_like_materials_keep_their_own_e_mu_and_mindlin_ratio():
    pair = combined_interaction(RUBBER, RUBBER)

    assert pair.e == pytest.approx(0.9, rel=1e-15)
    assert pair.mu == pytest.approx(0.8, rel=1e-15)
    assert pair_tangential_ratio(STEEL, STEEL) == pytest.approx(tangential_stiffness_ratio(0.3), rel=1e-14)


def test_unlike_materials_combine_by_geometric_means():
    pair = combined_interaction(RUBBER, STEEL)

    assert pair.e == pytest.approx(math.sqrt(0.9 * 0.3), rel=1e-15)
    assert pair.mu == pytest.approx(math.sqrt(0.8 * 0.2), rel=1e-15)


def test_unlike_materials_tangential_ratio_is_4_gstar_over_estar():
    # Hand-evaluated Mindlin: 1/E* = sum (1 - nu^2)/E, 1/G* = sum (2 - nu)/G, G = E / (2 (1 + nu)).
    e_star = 1 / ((1 - 0.45**2) / 1e7 + (1 - 0.3**2) / 2e11)
    g_star = 1 / ((2 - 0.45) / (1e7 / 2.9) + (2 - 0.3) / (2e11 / 2.6))

    assert pair_tangential_ratio(RUBBER, STEEL) == pytest.approx(4 * g_star / e_star, rel=1e-14)
    swapped = pair_tangential_ratio(STEEL, RUBBER)
    assert swapped == pytest.approx(pair_tangential_ratio(RUBBER, STEEL), rel=1e-15)


def test_explicit_pair_overrides_the_rule_in_either_order():
    table = MaterialTable({("steel", "rubber"): Interaction(e=0.5, mu=0.6)})
    r, s = table.index(RUBBER), table.index(STEEL)

    assert table.interaction(RUBBER, STEEL) == Interaction(0.5, 0.6)
    assert table.law[r, s, L_ZETA] == pytest.approx(damping_ratio(0.5), rel=1e-15)
    assert table.law[s, r, L_MU] == 0.6
    # Pairs not given still follow the rule.
    assert table.law[r, r, L_MU] == pytest.approx(0.8)
    assert table.law[s, s, L_KT] == pytest.approx(tangential_stiffness_ratio(0.3), rel=1e-14)
    assert list(table.E) == [1e7, 2e11]


def test_table_numbers_materials_by_name_once():
    table = MaterialTable()

    assert table.index(RUBBER) == 0
    assert table.index(STEEL) == 1
    assert table.index(Material(E=1e7, nu=0.45, e=0.9, mu=0.8, name="rubber")) == 0
    assert len(list(table.pairs())) == 3


def test_two_materials_with_one_name_are_refused():
    table = MaterialTable()
    table.index(RUBBER)

    with pytest.raises(ContactParamsError, match="named 'rubber'"):
        table.index(Material(E=2e7, nu=0.45, e=0.9, mu=0.8, name="rubber"))


@pytest.mark.parametrize(("e", "mu"), [(0.0, 0.5), (1.5, 0.5), (0.5, -0.1), (float("nan"), 0.5)])
def test_interaction_rejects_unphysical_pair_values(e, mu):
    with pytest.raises(ContactParamsError):
        Interaction(e=e, mu=mu)
