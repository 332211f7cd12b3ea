"""A rigid body's shape as the engine sees it: a clump of overlapping spheres in the body's
principal frame, with mass properties taken from the mesh (never from the spheres).

The engine (``dem/simulation.py``) consumes ``Clump``; ``dem/mesh.py`` and the clump generator
produce it from triangle meshes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Clump:
    """Spheres and mass properties of one rigid body.

    ``offset`` are sphere centres in the principal frame (origin at the centre of mass, axes along
    the principal axes), so the body-frame inertia tensor is ``diag(inertia)``. ``com`` and
    ``axes`` place that frame in the mesh's coordinates: a mesh vertex ``v`` is at body-frame
    ``axes.T @ (v - com)``.
    """

    radius: np.ndarray  # (n,) sphere radii, m
    offset: np.ndarray  # (n, 3) sphere centres in the principal frame, m
    mass: float  # kg
    inertia: np.ndarray  # (3,) principal moments of inertia, kg m^2
    volume: float  # m^3, of the mesh
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) in mesh coordinates
    axes: np.ndarray = field(default_factory=lambda: np.eye(3))  # (3, 3) columns = principal axes
    max_error: float = 0.0  # m, largest distance between mesh surface and clump envelope
    name: str = ""

    @classmethod
    def solid_sphere(cls, radius: float, density: float, name: str = "sphere") -> Clump:
        """A one-sphere body of uniform density: the analytic case (I = 2/5 m r^2)."""
        volume = 4.0 / 3.0 * np.pi * radius**3
        mass = density * volume
        return cls(
            radius=np.array([float(radius)]),
            offset=np.zeros((1, 3)),
            mass=mass,
            inertia=np.full(3, 0.4 * mass * radius**2),
            volume=volume,
            name=name,
        )

    @property
    def n_spheres(self) -> int:
        return int(self.radius.shape[0])

    @property
    def equivalent_diameter(self) -> float:
        """Diameter of the sphere of equal volume: the body's contact size in the contact law."""
        return float((6.0 * self.volume / np.pi) ** (1.0 / 3.0))
