"""The vibration feeder's configuration (``kind = "feeder"``): every key of ``examples/feeder.toml``.

Only pydantic and numpy here, the tray's geometry config and the paths' rules
(``dem/scenarios/paths.py``): a study definition names this model in its scenario union
(``dem/scenarios/registry.py``) without importing the engine (the items module is imported only
to look into a user's folder of meshes). The run is ``dem/scenarios/feeder.py``.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationInfo, model_validator

from dem.scenarios.base import ParamsConfig, Section
from dem.scenarios.paths import READ_FILES, path_tables
from dem.scenarios.tray import TrayConfig

# Share of the inlet region's volume (floor area x wall height) that randomly piled flat items
# can fill; beyond it the items cannot all be deposited in the inlet region.
INLET_PACKING_LIMIT = 0.6


class ItemsConfig(Section):
    """Which items are fed: the built-in WEEE set, the user's meshes from a folder, or shapes
    uploaded to the service (``uploaded``)."""

    counts: dict[str, int] = Field(
        default_factory=lambda: {"smartphone": 10, "feature_phone": 10, "camera": 10},
        description="Items per kind (built-in kinds, file stems of the folder's meshes, or uploaded "
        "shape ids with uploaded = true).",
    )
    spread: float = Field(0.05, ge=0, le=0.3, description="Relative random spread of dimensions and mass.")
    representation: Literal["polyhedron", "clump"] = Field(
        "clump",
        description="Item shape: rounded polyhedra (flat faces, rounded edges) or sphere clumps.",
    )
    resolution: int = Field(12, ge=1, le=400, description="Clump resolution passed to the clump generator.")
    core_tolerance: float = Field(
        0.1,
        ge=0,
        lt=1,
        description="Polyhedra: each convex core is simplified to within this fraction of the rounding "
        "radius r of the full core (Hausdorff distance, inwards only); 0 keeps every core vertex "
        "(up to 48).",
    )
    folder: Path | None = Field(None, description="Folder of STL/OBJ item meshes instead of the built-ins.")
    masses: dict[str, float] = Field(
        default_factory=dict, description="Mass per folder mesh stem, kg (an uploaded shape's is its own)."
    )
    uploaded: bool = Field(
        False, description="counts name shapes uploaded to the service (POST /api/v1/shapes) by id."
    )

    @model_validator(mode="after")
    def _folder_meshes(self, info: ValidationInfo) -> ItemsConfig:
        """A folder read from the user's own config (``READ_FILES``) is looked into now, so that a
        count without its mesh or mass is a config error, not a failed run: counts left out come
        from the folder's manifest, its masses join the config's."""
        if self.folder is None or info.context != READ_FILES:
            return self
        from dem.scenarios.items import folder_items

        given = self.counts if "counts" in self.model_fields_set else None
        found = folder_items(self.folder, given, self.masses)
        self.counts, self.masses = found.counts, found.masses
        return self

    @model_validator(mode="after")
    def _counts_positive(self) -> ItemsConfig:
        for kind, count in self.counts.items():
            if count < 0:
                raise ValueError(f"counts.{kind} is {count}; counts cannot be negative")
        if sum(self.counts.values()) == 0:
            raise ValueError("counts: at least one item is needed")
        if self.uploaded and self.folder is not None:
            raise ValueError("give either folder (meshes in a folder) or uploaded = true (shapes by id)")
        return self


class StagesConfig(Section):
    insertion_time: float = Field(1.0, gt=0, description="Items are created over this time, s.")
    vibration_start: float = Field(5.0, gt=0, description="End of deposition, start of vibration, s.")
    vibration_time: float = Field(60.0, ge=0, description="Duration of the vibration, s.")

    @model_validator(mode="after")
    def _insertion_before_vibration(self) -> StagesConfig:
        if self.insertion_time > self.vibration_start:
            raise ValueError(
                f"insertion_time ({self.insertion_time} s) must not exceed vibration_start "
                f"({self.vibration_start} s)"
            )
        return self

    @property
    def end(self) -> float:
        return self.vibration_start + self.vibration_time


class VibrationConfig(Section):
    frequency: float = Field(60.0, gt=0, le=1000, description="Hz.")
    amplitude: float = Field(1.5e-3, ge=0, le=0.05, description="Displacement amplitude, m.")
    amplitude_kind: Literal["peak", "peak_to_peak"] = Field(
        "peak", description="Whether amplitude is the peak (A in A sin wt) or peak-to-peak (2A)."
    )
    angle_deg: float = Field(
        25.0, ge=0, le=90, description="Inclination from the horizontal, towards the outlet."
    )
    ramp_time: float = Field(0.0, ge=0, description="Linear ramp of the amplitude at the start, s.")

    @property
    def peak_amplitude(self) -> float:
        return self.amplitude if self.amplitude_kind == "peak" else self.amplitude / 2

    @property
    def direction(self) -> tuple[float, float, float]:
        """World direction of the tray's displacement (x towards the outlet, z up)."""
        a = math.radians(self.angle_deg)
        return (math.cos(a), 0.0, math.sin(a))


class RunConfig(Section):
    dt_fraction: float = Field(
        0.05, gt=0, le=0.5, description="Time step as a fraction of the contact period."
    )
    dt: float | None = Field(None, gt=0, description="Force this time step, s (overrides dt_fraction).")
    stop_when_empty: bool = Field(True, description="End the run when every item has been discharged.")
    snapshot_interval: float = Field(
        0.1, gt=0, description="Simulated s between snapshots (with snapshot_dir)."
    )
    chunk_time: float = Field(0.01, gt=0, le=1.0, description="Simulated s between discharge checks.")


class FeederConfig(Section):
    """One vibration feeder experiment, as in ``examples/feeder.toml``."""

    kind: Literal["feeder"] = "feeder"
    params: ParamsConfig = Field(default_factory=ParamsConfig)
    tray: TrayConfig = Field(default_factory=TrayConfig)
    items: ItemsConfig = Field(default_factory=ItemsConfig)
    stages: StagesConfig = Field(default_factory=StagesConfig)
    vibration: VibrationConfig = Field(default_factory=VibrationConfig)
    run: RunConfig = Field(default_factory=RunConfig)

    @model_validator(mode="after")
    def _items_fit_the_inlet(self) -> FeederConfig:
        if self.items.folder is not None or self.items.uploaded:
            return self  # user meshes are measured when they are loaded
        from dem.scenarios.items import nominal_volume

        bulk = sum(nominal_volume(kind) * count for kind, count in self.items.counts.items())
        inlet = self.tray.inlet_width * self.tray.inlet_length * self.tray.wall_height
        if bulk > INLET_PACKING_LIMIT * inlet:
            raise ValueError(
                f"items.counts: {sum(self.items.counts.values())} items ({bulk * 1e3:.2f} L) do not fit "
                f"the inlet region ({inlet * 1e3:.2f} L, at most {INLET_PACKING_LIMIT:.0%} of it can be "
                "filled); reduce items.counts or enlarge tray.inlet_length, tray.inlet_width or "
                "tray.wall_height"
            )
        return self



def load_feeder_config(path: Path | str) -> FeederConfig:
    """Read and validate a feeder TOML file; relative mesh paths are taken from the file's folder,
    and the items folder's meshes are looked into (``ItemsConfig``)."""
    path = Path(path)
    with path.open("rb") as handle:
        data = tomllib.load(handle)
    base = path.resolve().parent
    for _, table, field in list(path_tables(data)):
        given = table[field]
        if isinstance(given, str) and not Path(given).is_absolute():
            table[field] = str(base / given)
    return FeederConfig.model_validate(data, context=READ_FILES)
