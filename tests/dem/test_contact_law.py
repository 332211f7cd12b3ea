"""The contact law's formulas (dem/contact.py) against their closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from dem.contact import (
    ContactParams,
    ContactParamsError,
    damping_ratio,
    damping_ratio_linear,
    normal_stiffness,
    restitution_with_clamp,
    tangential_stiffness_ratio,
    wall_stiffness,
)


@pytest.mark.parametrize(
    ("field", "value"),
    [("E", 0.0), ("E", -1e6), ("nu", 0.5), ("nu", -1.0), ("e", 0.0), ("e", 1.2), ("mu", -0.1)],
)
def test_contact_params_reject_unphysical_values_naming_the_field(field, value):
    values = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5, field: value}

    with pytest.raises(ContactParamsError, match=rf"^{field}"):
        ContactParams(**values)


def test_identical_spheres_have_the_papers_stiffness_E_D_over_2():
    E, D = 2.0e7, 0.012

    assert normal_stiffness(E, D, E, D) == pytest.approx(E * D / 2, rel=1e-15)
    assert wall_stiffness(E, D, E) == pytest.approx(E * D / 2, rel=1e-15)


def test_unlike_bodies_combine_in_series():
    E_a, D_a, E_b, D_b = 1e7, 0.01, 4e7, 0.03

    k = normal_stiffness(E_a, D_a, E_b, D_b)

    assert 1 / k == pytest.approx(1 / (E_a * D_a) + 1 / (E_b * D_b), rel=1e-14)


def test_mindlin_tangential_ratio():
    assert tangential_stiffness_ratio(0.0) == pytest.approx(1.0)
    assert tangential_stiffness_ratio(0.3) == pytest.approx(2 * 0.7 / 1.7)


@pytest.mark.parametrize("e", [0.2, 0.5, 0.9])
def test_linear_damping_ratio_gives_e_without_the_clamp(e):
    zeta = damping_ratio_linear(e)
    wd = math.sqrt(1 - zeta**2)

    realised = math.exp(-zeta * math.pi / wd)  # half a damped period, overlap back to zero

    assert realised == pytest.approx(e, rel=1e-12)


@pytest.mark.parametrize("zeta", [0.05, 0.3, 0.9, 1.5, 4.0])
def test_clamped_restitution_matches_an_ode_integration(zeta):
    # x'' + 2 zeta x' + x = 0 from x=0, x'=1, until the force x + 2 zeta x' reaches zero.
    def force_zero(t, y):
        return y[0] + 2 * zeta * y[1]

    force_zero.terminal = True
    force_zero.direction = -1
    sol = solve_ivp(
        lambda t, y: [y[1], -2 * zeta * y[1] - y[0]],
        (0, 50),
        [0.0, 1.0],
        events=force_zero,
        rtol=1e-11,
        atol=1e-13,
        first_step=1e-6,
    )

    assert restitution_with_clamp(zeta) == pytest.approx(-sol.y_events[0][0][1], rel=1e-7)


@pytest.mark.parametrize("e", [0.05, 0.1, 0.3, 0.5, 0.7, 0.9, 0.98])
def test_clamp_corrected_damping_ratio_restores_e(e):
    assert restitution_with_clamp(damping_ratio(e)) == pytest.approx(e, rel=1e-9)
    assert damping_ratio(e) >= damping_ratio_linear(e)


def test_restitution_one_means_no_damping():
    assert damping_ratio(1.0) == 0.0
    assert np.isclose(restitution_with_clamp(0.0), 1.0)
