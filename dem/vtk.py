"""Export to files that ParaView opens as a time series: spheres as points with a radius (render
them with the Glyph filter, scale by ``radius``), rounded polyhedra as their surfaces (triangles of
``Polyhedron.surface_mesh``, placed by each body's pose) and walls as triangle polydata.

Each frame is three VTK XML PolyData files (``.vtp``, ASCII: readable, diffable), and each of the
three streams has a ParaView collection (``spheres.pvd``, ``polyhedra.pvd``, ``walls.pvd``) that
lists its frames with their simulated time, rewritten after every frame so that a run that was
stopped still opens as the time series it wrote. A ``.pvd`` can only list XML files, which is why
the frames are ``.vtp`` and not legacy ``.vtk``. This module writes files only; it reads the
simulation's state and never changes it.
"""

from __future__ import annotations

from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from dem.polyhedra import Polyhedron

STREAMS = ("spheres", "polyhedra", "walls")


def _ascii(values: np.ndarray) -> str:
    values = np.asarray(values)
    if np.issubdtype(values.dtype, np.integer):
        return " ".join(str(int(v)) for v in values.ravel())
    return " ".join(f"{v:.9g}" for v in values.ravel())


def _write_polydata(
    path: Path,
    points: np.ndarray,
    cells_keyword: str,
    cells: list[list[int]],
    point_data: dict[str, np.ndarray],
    title: str,
) -> Path:
    """One VTK XML PolyData file; ``cells_keyword`` is ``Verts`` (points) or ``Polys``."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    connectivity = np.array([v for c in cells for v in c], dtype=np.int64)
    offsets = np.cumsum([len(c) for c in cells], dtype=np.int64)
    counts = {"Verts": 0, "Polys": 0, cells_keyword: len(cells)}
    lines = [
        '<?xml version="1.0"?>',
        f"<!-- {title} -->",
        '<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">',
        "<PolyData>",
        f'<Piece NumberOfPoints="{len(points)}" NumberOfVerts="{counts["Verts"]}" NumberOfLines="0" '
        f'NumberOfStrips="0" NumberOfPolys="{counts["Polys"]}">',
        "<PointData>",
    ]
    for name, values in point_data.items():
        values = np.asarray(values)
        kind = "Int64" if np.issubdtype(values.dtype, np.integer) else "Float64"
        components = values.shape[1] if values.ndim == 2 else 1
        lines.append(
            f'<DataArray type="{kind}" Name="{name}" NumberOfComponents="{components}" format="ascii">'
            f"{_ascii(values)}</DataArray>"
        )
    lines += [
        "</PointData>",
        "<Points>",
        f'<DataArray type="Float64" NumberOfComponents="3" format="ascii">{_ascii(points)}</DataArray>',
        "</Points>",
        f"<{cells_keyword}>",
        f'<DataArray type="Int64" Name="connectivity" format="ascii">{_ascii(connectivity)}</DataArray>',
        f'<DataArray type="Int64" Name="offsets" format="ascii">{_ascii(offsets)}</DataArray>',
        f"</{cells_keyword}>",
        "</Piece>",
        "</PolyData>",
        "</VTKFile>",
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def _add_to_collection(collection: Path, t: float, frame_file: Path, frame: int) -> None:
    """List ``frame_file`` at time ``t`` in the ``.pvd`` collection; frame 0 starts a new one."""
    if frame > 0 and collection.is_file():
        root = ElementTree.parse(collection).getroot()
    else:
        root = ElementTree.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
        ElementTree.SubElement(root, "Collection")
    ElementTree.SubElement(
        root.find("Collection"), "DataSet", timestep=f"{t:.9g}", group="", part="0", file=frame_file.name
    )
    ElementTree.indent(root)
    ElementTree.ElementTree(root).write(collection, xml_declaration=True, encoding="utf-8")


def write_frame(sim, directory, frame: int) -> list[Path]:
    """Frame number ``frame`` of a run: ``spheres_NNNNN.vtp``, ``polyhedra_NNNNN.vtp`` and
    ``walls_NNNNN.vtp`` in ``directory``, each added to its stream's ``.pvd`` at ``sim.t``."""
    directory = Path(directory)
    writers = {"spheres": write_spheres, "polyhedra": write_polyhedra, "walls": write_walls}
    paths = []
    for stream in STREAMS:
        path = writers[stream](sim, directory / f"{stream}_{frame:05d}.vtp")
        _add_to_collection(directory / f"{stream}.pvd", sim.t, path, frame)
        paths.append(path)
    return paths


def write_spheres(sim, path) -> Path:
    """Every active clump's spheres: centre, radius, body id, body velocity (a polyhedron's
    pieces are not spheres: ``write_polyhedra`` draws them)."""
    path = Path(path)
    body = sim.spheres.body
    keep = sim.bodies.active[body] & (sim.spheres.core_count == 0)
    centres = sim.sphere_positions()[keep]
    cells = [[k] for k in range(len(centres))]
    data = {
        "radius": sim.spheres.radius[keep],
        "body": body[keep].astype(np.int64),
        "velocity": sim.bodies.vel[body[keep]],
    }
    return _write_polydata(path, centres, "Verts", cells, data, f"demcal spheres t={sim.t:.9g}")


def write_polyhedra(sim, path) -> Path:
    """Every active rounded polyhedron's surface as triangles in world coordinates, with the
    body id and body velocity at each point."""
    path = Path(path)
    meshes: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # per shape: body-frame surface
    points, cells, body, velocity = [], [], [], []
    offset = 0
    for b in np.flatnonzero(sim.bodies.active):
        shape = sim.shape(b)
        if not isinstance(shape, Polyhedron):
            continue
        if id(shape) not in meshes:
            mesh = shape.surface_mesh()
            meshes[id(shape)] = (np.asarray(mesh.vertices), np.asarray(mesh.faces))
        vertices, faces = meshes[id(shape)]
        points.append(sim.bodies.pos[b] + vertices @ sim.bodies.rot[b].T)
        cells += (faces + offset).tolist()
        body.append(np.full(len(vertices), b, dtype=np.int64))
        velocity.append(np.tile(sim.bodies.vel[b], (len(vertices), 1)))
        offset += len(vertices)
    data = {"body": np.concatenate(body), "velocity": np.concatenate(velocity)} if points else {}
    points = np.concatenate(points) if points else np.zeros((0, 3))
    return _write_polydata(path, points, "Polys", cells, data, f"demcal polyhedra t={sim.t:.9g}")


def write_walls(sim, path) -> Path:
    """All walls' triangles at their current (moved) position, with the wall index."""
    path = Path(path)
    points, cells, owner = [], [], []
    offset = 0
    for k, wall in enumerate(sim.walls):
        points.append(sim.wall_vertices(k))
        cells += [[offset + int(a), offset + int(b), offset + int(c)] for a, b, c in wall.faces]
        owner.append(np.full(len(wall.vertices), k))
        offset += len(wall.vertices)
    points = np.concatenate(points) if points else np.zeros((0, 3))
    data = {"wall": np.concatenate(owner).astype(np.int64)} if owner else {}
    return _write_polydata(path, points, "Polys", cells, data, f"demcal walls t={sim.t:.9g}")
