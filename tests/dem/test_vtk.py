"""The VTK export of spheres, rounded polyhedra and walls."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from dem.clump import Clump
from dem.contact import ContactParams
from dem.convex import gjk_distance
from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle, matrix
from dem.simulation import Simulation
from dem.vtk import write_polyhedra, write_spheres, write_walls
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


def read_polydata(path) -> tuple[np.ndarray, list[list[int]], dict[str, list[str]]]:
    """Points, cells and the raw point-data lines of a legacy ASCII polydata file."""
    lines = path.read_text().splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith("POINTS"))
    n = int(lines[start].split()[1])
    points = np.array([line.split() for line in lines[start + 1 : start + 1 + n]], dtype=float)
    n_cells = int(lines[start + 1 + n].split()[1])
    cells = [[int(v) for v in line.split()[1:]] for line in lines[start + 2 + n : start + 2 + n + n_cells]]
    data = {}
    for k, line in enumerate(lines):
        if line.startswith(("SCALARS", "VECTORS")):
            skip = 2 if line.startswith("SCALARS") else 1
            data[line.split()[1]] = lines[k + skip : k + skip + n]
    return points, cells, data


def test_a_rounded_polyhedron_is_written_as_its_surface_at_its_pose(tmp_path):
    box = Polyhedron.box((0.04, 0.03, 0.01), 0.002, 1000.0)
    sim = falling_pair()
    pose = from_axis_angle((1.0, 2.0, -0.5), 0.7)
    body = sim.add_body(box, (0.1, -0.05, 0.08), quaternion=pose, velocity=(0.3, 0, -0.1))

    sphere_lines = write_spheres(sim, tmp_path / "spheres.vtk").read_text().splitlines()
    points, cells, data = read_polydata(write_polyhedra(sim, tmp_path / "polyhedra.vtk"))

    assert "POINTS 2 double" in sphere_lines  # the clump's two spheres; the box is not a sphere
    mesh = trimesh.Trimesh(points, np.array(cells), process=False)
    assert mesh.is_watertight and len(cells) > 12
    # Every point lies on the rounded surface: at distance r from the core placed by the pose.
    local = np.ascontiguousarray((points - sim.bodies.pos[body]) @ matrix(pose))
    eye, origin = np.eye(3), np.zeros(3)
    distance = [
        gjk_distance(local, k, 1, eye, origin, box.core, 0, 8, eye, origin)[0] for k in range(len(local))
    ]
    assert np.allclose(distance, box.rounding, rtol=1e-6)
    # ... and it encloses the rounded box's volume (Steiner: core, slabs, quarter cylinders, ball),
    # less what the icosphere's flat facets cut off the rounding (under 10 % of its part).
    a, b, c = box.core.max(axis=0) - box.core.min(axis=0)
    r = box.rounding
    rounding_part = np.pi * r * r * (a + b + c) + 4 / 3 * np.pi * r**3
    steiner = a * b * c + 2 * r * (a * b + b * c + a * c) + rounding_part
    assert steiner - 0.1 * rounding_part < mesh.volume <= steiner
    assert set(data["body"]) == {str(body)}
    assert np.allclose(np.array([v.split() for v in data["velocity"]], dtype=float), [0.3, 0, -0.1])
