"""Export to VTK legacy files that ParaView opens: spheres as points with a radius (render them
with the Glyph filter, scale by ``radius``), rounded polyhedra as their surfaces (triangles of
``Polyhedron.surface_mesh``, placed by each body's pose) and walls as triangle polydata.

ASCII legacy format, version 3.0: readable, diffable and supported by every ParaView. This
module writes files only; it reads the simulation's state and never changes it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dem.polyhedra import Polyhedron


def _write_polydata(
    path: Path,
    points: np.ndarray,
    cells_keyword: str,
    cells: list[list[int]],
    point_data: dict[str, np.ndarray],
    title: str,
) -> Path:
    lines = ["# vtk DataFile Version 3.0", title, "ASCII", "DATASET POLYDATA", f"POINTS {len(points)} double"]
    lines += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in points]
    size = sum(len(c) + 1 for c in cells)
    lines.append(f"{cells_keyword} {len(cells)} {size}")
    lines += [" ".join(str(v) for v in [len(c), *c]) for c in cells]
    if point_data:
        lines.append(f"POINT_DATA {len(points)}")
        for name, values in point_data.items():
            values = np.asarray(values)
            if values.ndim == 2:
                lines.append(f"VECTORS {name} double")
                lines += [f"{a:.9g} {b:.9g} {c:.9g}" for a, b, c in values]
            else:
                kind = "int" if np.issubdtype(values.dtype, np.integer) else "double"
                lines += [f"SCALARS {name} {kind} 1", "LOOKUP_TABLE default"]
                lines += [f"{v:.9g}" if kind == "double" else str(int(v)) for v in values]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_frame(sim, directory, frame: int) -> list[Path]:
    """Frame number ``frame`` of a run: ``spheres_NNNNN.vtk``, ``polyhedra_NNNNN.vtk`` and
    ``walls_NNNNN.vtk`` in ``directory``."""
    directory = Path(directory)
    return [
        write_spheres(sim, directory / f"spheres_{frame:05d}.vtk"),
        write_polyhedra(sim, directory / f"polyhedra_{frame:05d}.vtk"),
        write_walls(sim, directory / f"walls_{frame:05d}.vtk"),
    ]


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
    return _write_polydata(path, centres, "VERTICES", cells, data, f"demcal spheres t={sim.t:.9g}")


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
    return _write_polydata(path, points, "POLYGONS", cells, data, f"demcal polyhedra t={sim.t:.9g}")


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
    return _write_polydata(path, points, "POLYGONS", cells, data, f"demcal walls t={sim.t:.9g}")
