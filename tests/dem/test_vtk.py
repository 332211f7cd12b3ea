"""The VTK export of spheres and walls."""

from __future__ import annotations

import math

import numpy as np

from dem.clump import Clump
from dem.contact import ContactParams
from dem.simulation import Simulation
from dem.vtk import write_spheres, write_walls
from dem.walls import WallMesh


def falling_pair() -> Simulation:
    r = 0.005
    mass = 1000 * 4 / 3 * math.pi * r**3
    clump = Clump(
        radius=np.full(2, r),
        offset=np.array([[-r, 0, 0], [r, 0, 0]]),
        mass=2 * mass,
        inertia=np.array([0.8, 2.8, 2.8]) * mass * r * r,
        volume=2 * mass / 1000,
    )
    sim = Simulation(
        ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5), domain_min=(-1, -1, -1), domain_max=(1, 1, 1)
    )
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.2))
    sim.add_body(clump, (0, 0, 0.05))
    return sim


def test_vtk_files_list_every_sphere_and_wall_triangle(tmp_path):
    sim = falling_pair()

    spheres = write_spheres(sim, tmp_path / "spheres.vtk").read_text().splitlines()
    walls = write_walls(sim, tmp_path / "walls.vtk").read_text().splitlines()

    assert spheres[0] == "# vtk DataFile Version 3.0"
    assert "POINTS 2 double" in spheres and "VERTICES 2 4" in spheres
    centre = np.array(spheres[spheres.index("POINTS 2 double") + 1].split(), dtype=float)
    assert np.allclose(centre, [-0.005, 0, 0.05])
    assert "POLYGONS 2 8" in walls
