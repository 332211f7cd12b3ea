"""The VTK export of spheres, rounded polyhedra and walls."""

from __future__ import annotations

import math
from xml.etree import ElementTree

import numpy as np
import trimesh

from dem.clump import Clump
from dem.contact import ContactParams
from dem.convex import gjk_distance, place
from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle, matrix
from dem.simulation import Simulation
from dem.vtk import write_frame, write_polyhedra, write_spheres, write_walls
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


def read_polydata(path) -> tuple[np.ndarray, list[list[int]], dict[str, np.ndarray]]:
    """Points, cells and point data of a VTK XML PolyData file, read with a plain XML parser."""
    piece = ElementTree.parse(path).getroot().find("PolyData/Piece")

    def array(element) -> np.ndarray:
        kind = int if element.get("type").startswith("Int") else float
        values = np.array((element.text or "").split(), dtype=kind)
        components = int(element.get("NumberOfComponents", "1"))
        return values.reshape(-1, components) if components > 1 else values

    points = array(piece.find("Points/DataArray")).reshape(-1, 3)
    cells = []
    for keyword in ("Verts", "Polys"):
        block = piece.find(keyword)
        if block is None:
            continue
        arrays = {a.get("Name"): array(a) for a in block.findall("DataArray")}
        bounds = np.concatenate([[0], arrays["offsets"]]).astype(int)
        cells += [arrays["connectivity"][a:b].tolist() for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    assert int(piece.get("NumberOfPoints")) == len(points)
    assert int(piece.get("NumberOfVerts")) + int(piece.get("NumberOfPolys")) == len(cells)
    data = {a.get("Name"): array(a) for a in piece.findall("PointData/DataArray")}
    return points, cells, data


def test_vtk_files_list_every_sphere_and_wall_triangle(tmp_path):
    sim = falling_pair()

    points, cells, data = read_polydata(write_spheres(sim, tmp_path / "spheres.vtp"))
    _, wall_cells, _ = read_polydata(write_walls(sim, tmp_path / "walls.vtp"))

    assert cells == [[0], [1]]
    assert np.allclose(points[0], [-0.005, 0, 0.05])
    assert np.allclose(data["radius"], 0.005)
    assert [len(c) for c in wall_cells] == [3, 3]


def test_frames_form_a_paraview_time_series_whose_every_file_exists(tmp_path):
    sim = falling_pair()

    for frame in range(3):
        write_frame(sim, tmp_path, frame)
        sim.run(sim.t + 0.01)

    for stream in ("spheres", "polyhedra", "walls"):
        root = ElementTree.parse(tmp_path / f"{stream}.pvd").getroot()
        datasets = root.findall("Collection/DataSet")
        assert root.get("type") == "Collection"
        assert [d.get("file") for d in datasets] == [f"{stream}_{k:05d}.vtp" for k in range(3)]
        times = [float(d.get("timestep")) for d in datasets]
        assert times[0] == 0.0 and np.all(np.diff(times) > 0.009)
        for dataset in datasets:
            read_polydata(tmp_path / dataset.get("file"))  # exists and parses
    heights = [read_polydata(tmp_path / f"spheres_{k:05d}.vtp")[0][0, 2] for k in range(3)]
    assert heights[0] > heights[1] > heights[2]  # each frame holds its own moment of the fall


def test_a_rounded_polyhedron_is_written_as_its_surface_at_its_pose(tmp_path):
    box = Polyhedron.box((0.04, 0.03, 0.01), 0.002, 1000.0)
    sim = falling_pair()
    pose = from_axis_angle((1.0, 2.0, -0.5), 0.7)
    body = sim.add_body(box, (0.1, -0.05, 0.08), quaternion=pose, velocity=(0.3, 0, -0.1))

    sphere_points, _, _ = read_polydata(write_spheres(sim, tmp_path / "spheres.vtp"))
    points, cells, data = read_polydata(write_polyhedra(sim, tmp_path / "polyhedra.vtp"))

    assert len(sphere_points) == 2  # the clump's two spheres; the box is not a sphere
    mesh = trimesh.Trimesh(points, np.array(cells), process=False)
    assert mesh.is_watertight and len(cells) > 12
    # Every point lies on the rounded surface: at distance r from the core placed by the pose.
    local = np.ascontiguousarray((points - sim.bodies.pos[body]) @ matrix(pose))
    eye, origin = np.eye(3), np.zeros(3)
    distance = [
        gjk_distance(local, place(k, 1, eye, origin), box.core, place(0, 8, eye, origin))[0]
        for k in range(len(local))
    ]
    assert np.allclose(distance, box.rounding, rtol=1e-6)
    # ... and it encloses the rounded box's volume (Steiner: core, slabs, quarter cylinders, ball),
    # less what the icosphere's flat facets cut off the rounding (under 10 % of its part).
    a, b, c = box.core.max(axis=0) - box.core.min(axis=0)
    r = box.rounding
    rounding_part = np.pi * r * r * (a + b + c) + 4 / 3 * np.pi * r**3
    steiner = a * b * c + 2 * r * (a * b + b * c + a * c) + rounding_part
    assert steiner - 0.1 * rounding_part < mesh.volume <= steiner
    assert set(data["body"].tolist()) == {body}
    assert np.allclose(data["velocity"], [0.3, 0, -0.1])
