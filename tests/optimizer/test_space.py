"""Genes in [0, 1] map to parameters on the scales the study asks for."""

from __future__ import annotations

import math

import numpy as np
import pytest

from optimizer.space import ParameterSpace
from optimizer.study import Parameters


def test_young_modulus_gene_is_logarithmic():
    space = ParameterSpace(Parameters(E={"low": 1e5, "high": 1e9}))

    params = space.params(np.array([0.5, 0.0, 0.0, 0.0]))

    assert params["E"] == pytest.approx(math.sqrt(1e5 * 1e9))


def test_linear_parameters_and_fixed_ones():
    space = ParameterSpace(Parameters(nu={"fixed": 0.3}, mu={"low": 0.2, "high": 0.6}))

    params = space.params(np.array([1.0, 0.5, 0.25]))

    assert space.names == ["E", "e", "mu"]
    assert params == pytest.approx({"E": 1e9, "nu": 0.3, "e": 0.05 + 0.5 * 0.9, "mu": 0.3})


def test_genes_round_trip():
    space = ParameterSpace(Parameters())
    genes = np.array([0.1, 0.2, 0.7, 0.9])

    assert space.genes(space.params(genes)) == pytest.approx(genes)
