"""Walls: triangle meshes grouped into planar facets, with an optional material and motion.

A facet is a set of edge-connected coplanar triangles (the floor of a tray made of two
triangles is one facet). The engine finds one contact per sphere and facet, at the facet's
closest point, so a sphere rolling over the shared edge of two coplanar triangles feels one
continuous force, never two. Between non-coplanar facets of the same wall the rule is: an
edge or vertex contact is dropped when its contact point also lies on another facet that the
sphere touches at least as closely (a convex edge is then felt once, a concave corner keeps both
face contacts); see ``dem/forces.py``. Walls are two-sided.

This module checks and groups the meshes and gives the kernels their rows (``Walls``; the facets'
arrays and distance queries are in ``dem/facets.py``); it must not compute forces.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from dem.contact import N_SUMS, ContactParams
from dem.facets import Facets, build_facets
from dem.frames import dot, norm
from dem.motion import MOTION_ROW, Motion, motion_row

log = logging.getLogger(__name__)

_COPLANAR_COS = 1.0 - 1e-9
MAX_WALL_FACES = 200_000


class WallMeshError(ValueError):
    """A wall mesh is not usable; the message says what to fix."""


@dataclass(frozen=True)
class WallMesh:
    """A rigid triangle-mesh wall at its reference position (displaced by ``motion`` at time t)."""

    vertices: np.ndarray  # (m, 3) m
    faces: np.ndarray  # (k, 3) vertex indices
    material: ContactParams | None = None  # None: the particles' own parameters
    motion: Motion | None = None  # None: at rest
    name: str = ""
    facets: list[np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        faces = np.ascontiguousarray(self.faces, dtype=np.int64)
        label = f"wall {self.name!r}" if self.name else "wall"
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 3:
            raise WallMeshError(f"{label}: vertices must be an (m, 3) array with m >= 3")
        if not np.all(np.isfinite(vertices)):
            raise WallMeshError(f"{label}: vertices contain NaN or infinite values")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise WallMeshError(f"{label}: faces must be a non-empty (k, 3) array of vertex indices")
        if len(faces) > MAX_WALL_FACES:
            raise WallMeshError(f"{label}: {len(faces)} faces; decimate the mesh below {MAX_WALL_FACES}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise WallMeshError(f"{label}: a face refers to a vertex index outside 0..{len(vertices) - 1}")
        vertices, faces = _merge_duplicate_vertices(vertices, faces)
        tri = vertices[faces]
        area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        scale = float(np.ptp(vertices, axis=0).max())
        degenerate = area2 <= 1e-12 * scale * scale
        if np.any(degenerate):
            log.warning("%s: dropping %d degenerate (zero-area) triangles", label, int(degenerate.sum()))
            faces = faces[~degenerate]
            if len(faces) == 0:
                raise WallMeshError(f"{label}: every triangle has zero area")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "facets", _group_planar_facets(vertices, faces))

    @property
    def n_facets(self) -> int:
        return len(self.facets)

    @classmethod
    def box(cls, lo, hi, *, open_top: bool = True, **kwargs) -> WallMesh:
        """The inside of an axis-aligned box (floor, four sides and, unless open, a lid)."""
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        corners = np.array(
            [[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])]
        )
        quads = [(0, 1, 3, 2), (0, 4, 5, 1), (1, 5, 7, 3), (3, 7, 6, 2), (2, 6, 4, 0)]
        if not open_top:
            quads.append((4, 6, 7, 5))
        faces = [tri for a, b, c, d in quads for tri in ((a, b, c), (a, c, d))]
        return cls(corners, np.array(faces), **kwargs)

    @classmethod
    def plane(cls, point, normal, size: float, **kwargs) -> WallMesh:
        """A square of side ``size`` centred on ``point`` with the given normal."""
        point = np.asarray(point, dtype=np.float64)
        normal = np.asarray(normal, dtype=np.float64)
        normal = normal / norm(normal)
        helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(normal, helper)
        u /= norm(u)
        v = np.cross(normal, u)
        h = 0.5 * size
        corners = np.array(
            [point - h * u - h * v, point + h * u - h * v, point + h * u + h * v, point - h * u + h * v]
        )
        return cls(corners, np.array([[0, 1, 2], [0, 2, 3]]), **kwargs)


def _merge_duplicate_vertices(vertices: np.ndarray, faces: np.ndarray):
    """STL stores every triangle's own corners; shared edges are found on merged vertices."""
    scale = max(float(np.ptp(vertices, axis=0).max()), 1e-300)
    keys = np.round(vertices / (scale * 1e-9)).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return vertices[first], inverse.reshape(-1)[faces]


def _group_planar_facets(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """Triangle indices of each facet: connected components over shared edges of parallel faces."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    parent = list(range(len(faces)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner: dict[tuple[int, int], int] = {}
    for t, face in enumerate(faces):
        for a, b in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
            edge = (int(min(a, b)), int(max(a, b)))
            other = owner.setdefault(edge, t)
            if other != t and abs(dot(normals[t], normals[other])) >= _COPLANAR_COS:
                ra, rb = root(t), root(other)
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for t in range(len(faces)):
        groups.setdefault(root(t), []).append(t)
    return [np.array(g, dtype=np.int64) for _, g in sorted(groups.items())]


class Walls(NamedTuple):
    """The walls as the kernels see them: one row per wall, plus their facets."""

    motion: np.ndarray  # (n, MOTION_ROW) prescribed motion (``dem/motion.py``)
    disp: np.ndarray  # (n, 3) displacement at the current time, written by the run loop
    vel: np.ndarray  # (n, 3) velocity at the current time, written by the run loop
    material: np.ndarray  # (n,) int64 index into the simulation's MaterialTable
    facets: Facets
    facet_sum: np.ndarray  # (n_facets, N_SUMS) scratch of the force pass: one body's sums per facet


def wall_arrays(walls: list[WallMesh], material_index) -> Walls:
    """The kernels' view of ``walls``; ``material_index(wall.material)`` numbers each wall's
    material (None: the particles' default)."""
    n = len(walls)
    motion = np.zeros((n, MOTION_ROW))
    material = np.zeros(n, dtype=np.int64)
    for k, wall in enumerate(walls):
        motion[k] = motion_row(wall.motion)
        material[k] = material_index(wall.material)
    facets = build_facets(walls)
    facet_sum = np.zeros((max(facets.n, 1), N_SUMS))
    return Walls(motion, np.zeros((n, 3)), np.zeros((n, 3)), material, facets, facet_sum)
