"""The angle-of-repose test's configuration (``kind = "angle_of_repose"``): every key of
``examples/repose.toml``, and the initial lattice's size, which the config must leave room for.

Only pydantic and numpy here: a study definition names this model in its scenario union
(``dem/scenarios/registry.py``) without importing the engine. The run is ``dem/scenarios/heap.py``.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from dem.scenarios.base import ParamsConfig, Section
from dem.scenarios.feeder_config import ItemsConfig
from dem.scenarios.heap_fit import FitConfig

MAX_ACROSS = 1000  # spheres across the cylinder: bounds the lattice a config may ask for
# Lattice spacing of the initial column, in largest sphere diameters (a loose, non-touching fill).
LATTICE_SPACING = 1.1


class ParticlesConfig(Section):
    shape: Literal["spheres", "items"] = Field("spheres", description="Spheres, or the feeder's items.")
    count: int = Field(300, ge=10, le=100_000, description="Number of spheres.")
    diameter: float = Field(0.01, gt=0, le=1, description="Mean sphere diameter, m.")
    size_spread: float = Field(
        0.1, ge=0, lt=0.5, description="Size classes span diameter x (1 -/+ size_spread)."
    )
    size_classes: int = Field(3, ge=1, le=9, description="Number of sphere sizes (LIGGGHTS atom types).")
    density: float = Field(2500.0, gt=0, description="Sphere density, kg/m^3.")
    items: ItemsConfig = Field(
        default_factory=lambda: ItemsConfig(counts={"smartphone": 4, "feature_phone": 4, "camera": 4}),
        description="With shape = 'items': which items (the feeder's [items] table).",
    )

    def diameters(self) -> np.ndarray:
        """The size classes' diameters, smallest first."""
        if self.size_classes == 1:
            return np.array([self.diameter])
        return self.diameter * np.linspace(1 - self.size_spread, 1 + self.size_spread, self.size_classes)


class CylinderConfig(Section):
    diameter: float = Field(0.1, gt=0, description="Inner diameter, m.")
    height: float = Field(0.15, gt=0, description="Height, m; the initial column must fit in it.")
    lift_speed: float = Field(0.2, gt=0, le=10, description="Lifting speed, m/s.")
    segments: int = Field(24, ge=8, le=256, description="Facets around the circumference.")


class PlateConfig(Section):
    size: float = Field(0.3, gt=0, description="Side of the square plate, m; particles beyond it fall off.")
    roughness: float = Field(
        0.3,
        ge=0,
        le=1,
        description="Depth of the plate's square dimples (pitch: one mean diameter), in mean diameters; "
        "0 is a smooth plate.",
    )


class HeapStagesConfig(Section):
    lift_start: float = Field(0.25, ge=0, description="The column settles until then, s.")
    rest_speed: float = Field(
        0.01, gt=0, description="The heap is at rest when its RMS particle speed is below this, m/s."
    )
    max_time: float = Field(3.0, gt=0, description="The run ends at this simulated time regardless, s.")


class HeapRunConfig(Section):
    dt_fraction: float = Field(
        0.05, gt=0, le=0.5, description="Time step as a fraction of the contact period."
    )
    dt: float | None = Field(None, gt=0, description="Force this time step, s.")
    chunk_time: float = Field(0.01, gt=0, le=1.0, description="Simulated s between rest checks.")
    snapshot_interval: float = Field(0.05, gt=0, description="Simulated s between VTK frames (with vtk_dir).")


class HeapConfig(Section):
    """One angle-of-repose test, as in ``examples/repose.toml``."""

    kind: Literal["angle_of_repose"] = "angle_of_repose"
    params: ParamsConfig = Field(default_factory=ParamsConfig)
    particles: ParticlesConfig = Field(default_factory=ParticlesConfig)
    cylinder: CylinderConfig = Field(default_factory=CylinderConfig)
    plate: PlateConfig = Field(default_factory=PlateConfig)
    stages: HeapStagesConfig = Field(default_factory=HeapStagesConfig)
    fit: FitConfig = Field(default_factory=FitConfig)
    run: HeapRunConfig = Field(default_factory=HeapRunConfig)

    @model_validator(mode="after")
    def _geometry(self) -> HeapConfig:
        if self.plate.size <= self.cylinder.diameter:
            raise ValueError(
                f"plate.size ({self.plate.size} m) must exceed cylinder.diameter ({self.cylinder.diameter} m)"
            )
        if self.stages.max_time <= self.stages.lift_start:
            raise ValueError("stages.max_time must be later than stages.lift_start")
        d_max = self.particles.diameters()[-1]
        if self.cylinder.diameter > MAX_ACROSS * d_max:  # before a lattice of that many sites is laid
            raise ValueError(
                f"particles.diameter = {self.particles.diameter:g} m is too small for cylinder.diameter = "
                f"{self.cylinder.diameter:g} m: at most {MAX_ACROSS} spheres fit across the cylinder here"
            )
        if self.particles.shape == "spheres":
            column_height(self)  # raises with the figures when the column does not fit
        return self


def column_height(config: HeapConfig) -> float:
    """Height of the initial sphere lattice; a ValueError names the keys when it overflows."""
    sites = len(lattice_layer(config))
    layers = math.ceil(config.particles.count / max(1, sites))
    spacing = LATTICE_SPACING * config.particles.diameters()[-1]
    height = layers * spacing
    if height > config.cylinder.height:
        raise ValueError(
            f"particles.count = {config.particles.count} needs a column {height * 1e3:.0f} mm high "
            f"({layers} layers of {sites}); raise cylinder.height to at least that, widen "
            "cylinder.diameter, or use fewer particles"
        )
    return height


def lattice_layer(config: HeapConfig) -> np.ndarray:
    """One layer of lattice sites (x, y) inside the cylinder's inscribed polygon."""
    d_max = config.particles.diameters()[-1]
    spacing = LATTICE_SPACING * d_max
    inner = 0.5 * config.cylinder.diameter * math.cos(math.pi / config.cylinder.segments) - 0.55 * d_max
    n = int(inner // spacing)
    grid = np.arange(-n, n + 1) * spacing
    x, y = np.meshgrid(grid, grid, indexing="ij")
    keep = np.hypot(x, y) <= inner
    return np.column_stack([x[keep], y[keep]])
