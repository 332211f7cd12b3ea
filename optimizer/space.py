"""The search space: the map between the GA's genes (each in [0, 1]) and contact parameters.

A gene is the normalised position of a free parameter between its bounds, on a log10 scale where
the study asks for it (E by default: its plausible values span decades, and a linear gene would
spend almost every individual in the top decade). Fixed parameters carry no gene.

This module only converts; it must not sample, evaluate or know about pymoo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from optimizer.study import Parameters


@dataclass(frozen=True)
class Axis:
    name: str
    low: float
    high: float
    log: bool

    def value(self, gene: float) -> float:
        gene = min(max(float(gene), 0.0), 1.0)
        if self.log:
            low, high = math.log10(self.low), math.log10(self.high)
            return 10.0 ** (low + gene * (high - low))
        return self.low + gene * (self.high - self.low)

    def gene(self, value: float) -> float:
        if self.log:
            low, high = math.log10(self.low), math.log10(self.high)
            return (math.log10(value) - low) / (high - low)
        return (value - self.low) / (self.high - self.low)


class ParameterSpace:
    """Genes <-> parameter dicts for one study's ``parameters`` section."""

    def __init__(self, parameters: Parameters):
        self.axes = [
            Axis(name, spec.low, spec.high, bool(spec.log))
            for name in parameters.free()
            for spec in [getattr(parameters, name)]
        ]
        self.fixed = parameters.fixed_values()
        self.all_names = parameters.names()

    @property
    def n_genes(self) -> int:
        return len(self.axes)

    @property
    def names(self) -> list[str]:
        return [axis.name for axis in self.axes]

    def params(self, genes: np.ndarray) -> dict[str, float]:
        """Every parameter of the study (the items' four, and the item-wall ones it names) for
        one individual, in the canonical order."""
        values = dict(self.fixed)
        values.update({axis.name: axis.value(gene) for axis, gene in zip(self.axes, genes, strict=True)})
        return {name: values[name] for name in self.all_names}

    def genes(self, params: dict[str, float]) -> np.ndarray:
        return np.array([axis.gene(params[axis.name]) for axis in self.axes])
