"""The vibration feeder's tray: its geometry as a config, and the triangle mesh the engine walls
are made of, either built parametrically or read from the user's STL/OBJ file.

The tray frame: x runs along the tray from the back wall of the inlet (x = 0) to the open outlet
end (x = ``length``), y across it (centred), z up from the floor (z = 0). The parametric tray is
the paper's (Kawaguchi et al., Mater. Trans. 62(4), 2021, Fig. 2): a rectangular inlet section
260 mm wide, a straight taper, a short outlet channel 100 mm wide, side walls and a back wall of
one height, and no wall at the outlet end. The paper gives the two widths; the lengths are ours
(an ERIEZ 36C-sized tray): 250 mm inlet + 250 mm taper + 100 mm outlet channel = 600 mm, walls
120 mm high, floor horizontal (``tilt_deg`` = 0).

``tilt_deg`` tilts the whole tray about the y axis, positive lowering the outlet end; the
tray-to-world transform is ``tray_to_world``. A user tray mesh must be given in the same tray
frame (its outlet end is its largest x); ``mesh_scale`` converts its units to metres.

This module only describes and builds geometry. It knows nothing of items, motion or the engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from dem.frames import transform


class TrayConfig(BaseModel):
    """Tray geometry in metres and degrees; see the module docstring for the frame."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    inlet_width: float = Field(0.260, gt=0, description="Width of the rectangular inlet section, m.")
    outlet_width: float = Field(0.100, gt=0, description="Width of the outlet channel, m.")
    inlet_length: float = Field(0.250, gt=0, description="Length of the rectangular inlet section, m.")
    taper_length: float = Field(0.250, ge=0, description="Length of the straight taper, m.")
    outlet_length: float = Field(0.100, ge=0, description="Length of the outlet channel, m.")
    wall_height: float = Field(0.120, gt=0, description="Height of the side and back walls, m.")
    tilt_deg: float = Field(
        0.0, ge=-30, le=30, description="Tray tilt about y, degrees; positive lowers the outlet end."
    )
    mesh_file: Path | None = Field(
        None, description="STL/OBJ tray in the tray frame instead of the parametric one."
    )
    mesh_scale: float = Field(1.0, gt=0, description="Factor from the mesh file's units to metres.")

    @model_validator(mode="after")
    def _outlet_not_wider_than_inlet(self) -> TrayConfig:
        if self.outlet_width > self.inlet_width:
            raise ValueError(
                f"outlet_width ({self.outlet_width} m) is wider than inlet_width "
                f"({self.inlet_width} m); a feeder tray narrows towards its outlet"
            )
        return self

    @property
    def length(self) -> float:
        return self.inlet_length + self.taper_length + self.outlet_length


@dataclass(frozen=True)
class TrayGeometry:
    """The built tray: a triangle mesh in the world frame and the places the scenario needs."""

    vertices: np.ndarray  # (n, 3) world frame, m
    faces: np.ndarray  # (m, 3) int, normals pointing into the tray
    tray_to_world: np.ndarray  # (3, 3) rotation; world = tray_to_world @ tray
    outlet_x: float  # tray-frame x of the open outlet end
    inlet_x: tuple[float, float]  # tray-frame x range of the inlet region
    inlet_y: tuple[float, float]  # tray-frame y range of the inlet region
    wall_height: float

    def to_tray_frame(self, points: np.ndarray) -> np.ndarray:
        """World points (n, 3) in the tray frame."""
        return transform(points, self.tray_to_world)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Tray-frame points (n, 3) in the world frame."""
        return transform(points, self.tray_to_world.T)

    @property
    def inlet_area(self) -> float:
        return (self.inlet_x[1] - self.inlet_x[0]) * (self.inlet_y[1] - self.inlet_y[0])


class TrayMeshError(ValueError):
    """The user's tray mesh cannot be used; the message says why and what to change."""


def tilt_rotation(tilt_deg: float) -> np.ndarray:
    """Rotation about y that lowers +x (the outlet end) for a positive tilt."""
    a = math.radians(tilt_deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def parametric_tray_mesh(config: TrayConfig) -> tuple[np.ndarray, np.ndarray]:
    """Floor, side walls and back wall of the tapered tray in the tray frame.

    Each face is wound so that its normal points into the tray (up for the floor), the side that
    items touch.
    """
    x = [0.0, config.inlet_length, config.inlet_length + config.taper_length, config.length]
    half = [config.inlet_width / 2, config.inlet_width / 2, config.outlet_width / 2, config.outlet_width / 2]
    # Drop zero-length sections so that no face is degenerate.
    stations = [(xi, hi) for i, (xi, hi) in enumerate(zip(x, half, strict=True)) if i == 0 or xi > x[i - 1]]
    h = config.wall_height
    vertices: list[tuple[float, float, float]] = []
    faces: list[tuple[int, int, int]] = []

    def quad(a, b, c, d) -> None:
        """Two triangles a-b-c, a-c-d (counter-clockwise seen from the normal side)."""
        base = len(vertices)
        vertices.extend([a, b, c, d])
        faces.extend([(base, base + 1, base + 2), (base, base + 2, base + 3)])

    for (x0, h0), (x1, h1) in zip(stations[:-1], stations[1:], strict=True):
        quad((x0, -h0, 0.0), (x1, -h1, 0.0), (x1, h1, 0.0), (x0, h0, 0.0))  # floor, normal +z
        quad((x0, -h0, 0.0), (x0, -h0, h), (x1, -h1, h), (x1, -h1, 0.0))  # right wall, normal +y
        quad((x0, h0, 0.0), (x1, h1, 0.0), (x1, h1, h), (x0, h0, h))  # left wall, normal -y
    h_back = stations[0][1]
    quad((0.0, -h_back, 0.0), (0.0, h_back, 0.0), (0.0, h_back, h), (0.0, -h_back, h))  # back, normal +x
    return np.array(vertices, dtype=float), np.array(faces, dtype=np.int64)


def load_tray_mesh(path: Path, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """A user's tray from STL/OBJ, in the tray frame and metres; it need not be watertight."""
    import trimesh

    if not path.is_file():
        raise TrayMeshError(f"tray.mesh_file {path} does not exist")
    try:
        mesh = trimesh.load(path, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise TrayMeshError(f"tray.mesh_file {path} is not a readable STL/OBJ mesh: {exc}") from exc
    vertices = np.asarray(mesh.vertices, dtype=float) * scale
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(faces) == 0 or not np.isfinite(vertices).all():
        raise TrayMeshError(f"tray.mesh_file {path} has no faces or non-finite vertices")
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    if extent.max() > 20.0 or extent.max() < 0.05:
        raise TrayMeshError(
            f"tray.mesh_file {path} is {extent.max():.3g} m long after mesh_scale={scale}; "
            "set tray.mesh_scale (0.001 for a file in millimetres)"
        )
    return vertices, faces


def build_tray(config: TrayConfig) -> TrayGeometry:
    """The tray's mesh in the world frame and the inlet and outlet the scenario needs."""
    if config.mesh_file is None:
        vertices, faces = parametric_tray_mesh(config)
        outlet_x = config.length
        inlet_x = (0.0, config.inlet_length)
        y_half = config.inlet_width / 2
        height = config.wall_height
    else:
        vertices, faces = load_tray_mesh(config.mesh_file, config.mesh_scale)
        outlet_x = float(vertices[:, 0].max())
        x0 = float(vertices[:, 0].min())
        inlet_x = (x0, x0 + config.inlet_length)
        y_half = config.inlet_width / 2
        height = float(vertices[:, 2].max())
    rotation = tilt_rotation(config.tilt_deg)
    return TrayGeometry(
        vertices=transform(vertices, rotation.T),
        faces=faces,
        tray_to_world=rotation,
        outlet_x=outlet_x,
        inlet_x=inlet_x,
        inlet_y=(-y_half, y_half),
        wall_height=height,
    )
