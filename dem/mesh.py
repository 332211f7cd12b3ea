"""Triangle meshes of rigid bodies: load (STL, OBJ, PLY), validate, repair, decimate, and compute
the mass properties the engine integrates with.

Uploads are loaded from bytes with an allow-listed ``file_type``; this module never opens a path a
user sent, never unpacks archives and never follows references inside a file (OBJ material
libraries are ignored). ``load_mesh_file`` is a convenience for local files the operator owns.

Validation either returns a repaired, watertight mesh with a ``ValidationReport`` (warnings say
what was repaired) or raises a ``MeshError`` subclass whose message names the problem and how to
fix it. Units are metres; ``scale`` converts (0.001 for files drawn in millimetres).

Mass properties come from the closed surface (divergence theorem, as trimesh computes them), with
either a density or a total mass. This module must not know about spheres or clumps.
"""

from __future__ import annotations

import hashlib
import io
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from dem.frames import principal_axes

logger = logging.getLogger(__name__)

ALLOWED_FILE_TYPES = ("stl", "obj", "ply")
# ``decimate`` keeps a result only if its volume is within this fraction of the mesh's, trying
# the quadric simplifier's aggressions in turn: at its default (7) fast-simplification folded a
# scanned phone and a camera into watertight meshes 12 % and 25 % smaller; 3 kept 99.5 % of both.
DECIMATION_VOLUME_TOLERANCE = 0.01
DECIMATION_AGGRESSIONS = (7, 5, 3, 1, 0)  # 0 keeps most faces where the others fold the surface

# Leading bytes of containers we refuse: an "STL" that is really a zip must not reach a parser
# that would happily unpack it.
_ARCHIVE_MAGIC = {
    b"PK\x03\x04": "zip",
    b"\x1f\x8b": "gzip",
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
    b"7z\xbc\xaf\x27\x1c": "7z",
    b"Rar!": "rar",
}


class MeshError(ValueError):
    """A mesh cannot be used as a rigid body; the message says what to fix."""


class MeshFormatError(MeshError):
    """The bytes are not a mesh of an accepted type (unknown type, archive, unparsable)."""


class MeshGeometryError(MeshError):
    """The geometry is unusable: non-finite vertices, no volume, too small or too large."""


class MeshTooLargeError(MeshError):
    """More faces than the configured limit."""


class MeshNotWatertightError(MeshError):
    """Open edges remain after repair, so volume and inertia are undefined."""


@dataclass(frozen=True)
class MeshLimits:
    """What a mesh may be. Sizes are the largest bounding-box edge after scaling, in metres."""

    max_faces: int = 2_000_000
    min_size: float = 1e-4  # 0.1 mm: below this a file is almost surely in the wrong unit
    max_size: float = 10.0  # 10 m


@dataclass
class ValidationReport:
    """What validation found and repaired. JSON-able through ``to_dict``."""

    n_vertices: int
    n_faces: int
    extents: list[float]  # bounding box edges, m
    volume: float  # m^3
    watertight: bool
    repaired: bool = False
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class MassProperties:
    """Rigid-body properties of a closed mesh, in the mesh's coordinates (m, kg).

    ``inertia`` is the full tensor about the centre of mass; ``principal_axes`` has the principal
    axes as columns, right-handed, ordered like ``principal_moments`` (ascending).
    """

    mass: float
    volume: float
    density: float
    com: np.ndarray
    inertia: np.ndarray
    principal_moments: np.ndarray
    principal_axes: np.ndarray

    def body_fields(self) -> dict:
        """What a body in its principal frame keeps of these (``Clump``, ``Polyhedron``)."""
        return dict(
            mass=self.mass,
            inertia=self.principal_moments,
            volume=self.volume,
            com=self.com,
            axes=self.principal_axes,
        )


def _refuse_archives(data: bytes) -> None:
    for magic, kind in _ARCHIVE_MAGIC.items():
        if data.startswith(magic):
            raise MeshFormatError(
                f"the upload is a {kind} archive; send a single STL, OBJ or PLY file instead"
            )


def _normalised_type(file_type: str) -> str:
    kind = file_type.lower().lstrip(".").strip()
    if kind not in ALLOWED_FILE_TYPES:
        raise MeshFormatError(
            f"mesh type {file_type!r} is not accepted; use one of {', '.join(ALLOWED_FILE_TYPES)}"
        )
    return kind


def load_mesh(
    data: bytes,
    file_type: str,
    *,
    scale: float = 1.0,
    limits: MeshLimits | None = None,
) -> tuple[trimesh.Trimesh, ValidationReport]:
    """Parse mesh bytes of an allow-listed type, scale to metres, validate and repair.

    Several bodies in one file are merged into one mesh: a clump is one rigid body.
    """
    kind = _normalised_type(file_type)
    if not data:
        raise MeshFormatError("the mesh file is empty")
    _refuse_archives(data)
    if not np.isfinite(scale) or scale <= 0:
        raise MeshGeometryError(f"scale must be a positive number (got {scale}); 0.001 converts mm to m")
    try:
        # No resolver: an OBJ's mtllib or texture references are never opened.
        loaded = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - parsers raise anything on garbage input
        raise MeshFormatError(f"cannot read the file as {kind.upper()}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshFormatError(f"the {kind.upper()} file contains no triangles")
    mesh = trimesh.Trimesh(
        vertices=np.asarray(loaded.vertices, dtype=np.float64) * scale,
        faces=np.asarray(loaded.faces, dtype=np.int64),
        process=False,
    )
    return validate_mesh(mesh, limits=limits)


def load_mesh_file(
    path: str | Path, *, scale: float = 1.0, limits: MeshLimits | None = None
) -> tuple[trimesh.Trimesh, ValidationReport]:
    """Load a local mesh file (operator-owned; uploads go through ``load_mesh``)."""
    path = Path(path)
    return load_mesh(path.read_bytes(), path.suffix, scale=scale, limits=limits)


def validate_mesh(
    mesh: trimesh.Trimesh, *, limits: MeshLimits | None = None
) -> tuple[trimesh.Trimesh, ValidationReport]:
    """Check and repair a copy of ``mesh``; raise a ``MeshError`` naming what is wrong."""
    limits = limits or MeshLimits()
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    if len(faces) > limits.max_faces:
        raise MeshTooLargeError(
            f"mesh has {len(faces)} faces, more than the limit of {limits.max_faces}; "
            "decimate it first (e.g. to 1/1000 of a raw scan)"
        )
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise MeshGeometryError(
            f"mesh has {int(bad.sum())} vertices with NaN or infinite coordinates; "
            "re-export it from the CAD or scanning software"
        )
    warnings: list[str] = []
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True, validate=False)
    extents = mesh.extents if len(mesh.vertices) else np.zeros(3)
    size = float(np.max(extents))
    if size < limits.min_size or size > limits.max_size:
        raise MeshGeometryError(
            f"mesh is {size:.3g} m across, outside {limits.min_size:g}-{limits.max_size:g} m; "
            "meshes are read in metres, pass scale=0.001 for a file drawn in millimetres"
        )

    degenerate = ~mesh.nondegenerate_faces(height=1e-12 * size)
    if degenerate.any():
        mesh.update_faces(~degenerate)
        mesh.remove_unreferenced_vertices()
        warnings.append(f"removed {int(degenerate.sum())} degenerate (zero-area) faces")
    duplicate = len(mesh.faces) - len(mesh.unique_faces().nonzero()[0])
    if duplicate:
        mesh.update_faces(mesh.unique_faces())
        warnings.append(f"removed {duplicate} duplicate faces")
    if len(mesh.faces) < 4:
        raise MeshGeometryError("mesh has fewer than 4 usable faces; it cannot enclose a volume")

    repaired = bool(warnings)
    if not mesh.is_watertight:
        open_edges = _open_edge_count(mesh)
        trimesh.repair.fill_holes(mesh)
        if not mesh.is_watertight:
            raise MeshNotWatertightError(
                f"mesh is not watertight: {open_edges} open edges and filling the holes failed; "
                "close the holes (e.g. 'make manifold' in your mesh tool) and upload again"
            )
        warnings.append(f"filled holes bounded by {open_edges} open edges")
        repaired = True
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
        warnings.append("made the face winding consistent")
        repaired = True
    with np.errstate(invalid="ignore", divide="ignore"):
        # trimesh divides by the volume for the centre of mass; a flat mesh is reported below.
        if mesh.volume < 0:
            trimesh.repair.fix_inversion(mesh)
            warnings.append("flipped inward-facing normals")
            repaired = True
        volume = float(mesh.volume)
        is_volume = bool(mesh.is_volume)
    # Relative threshold: a closed but flat sheet has a volume of rounding noise only.
    if not volume > 1e-9 * size**3 or not is_volume:
        raise MeshGeometryError(
            f"mesh encloses no volume ({volume:.3g} m^3): it is flat, inside-out or self-overlapping; "
            "export a closed solid"
        )
    for message in warnings:
        logger.warning("mesh repaired: %s", message)
    report = ValidationReport(
        n_vertices=len(mesh.vertices),
        n_faces=len(mesh.faces),
        extents=[float(x) for x in mesh.extents],
        volume=volume,
        watertight=True,
        repaired=repaired,
        warnings=warnings,
    )
    return mesh, report


def _open_edge_count(mesh: trimesh.Trimesh) -> int:
    """Edges used by exactly one face (the rim of the holes)."""
    edges = mesh.edges_sorted
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


def decimate(
    mesh: trimesh.Trimesh, *, target_faces: int | None = None, fraction: float | None = None
) -> trimesh.Trimesh:
    """Quadric-error decimation of a heavy (scanned) mesh to ``target_faces`` or ``fraction``.

    The paper reduced its scans to 1/1000 of their size before simulation. The result must stay
    watertight; if the simplifier opens it, holes are filled, and if that fails we raise rather
    than hand back a body without a volume.
    """
    if (target_faces is None) == (fraction is None):
        raise MeshError("decimate needs exactly one of target_faces or fraction")
    n_faces = len(mesh.faces)
    target = int(target_faces) if target_faces is not None else int(round(n_faces * float(fraction)))
    if target < 8:
        raise MeshError(f"decimation target of {target} faces is too coarse; keep at least 8")
    if target >= n_faces:
        return mesh.copy()
    volume = float(mesh.volume)
    change = None
    for aggression in DECIMATION_AGGRESSIONS:
        simplified = mesh.simplify_quadric_decimation(face_count=target, aggression=aggression)
        simplified.merge_vertices()
        _remove_fins(simplified)
        if not simplified.is_watertight:
            trimesh.repair.fill_holes(simplified)
        if not simplified.is_watertight:
            continue
        trimesh.repair.fix_normals(simplified)
        change = abs(float(simplified.volume) / volume - 1.0)
        if change <= DECIMATION_VOLUME_TOLERANCE:
            logger.info(
                "decimated mesh from %d to %d faces (aggression %d, volume within %.2g %%)",
                n_faces, len(simplified.faces), aggression, 100 * change,
            )  # fmt: skip
            return simplified
    if change is None:
        raise MeshNotWatertightError(f"decimating to {target} faces opened the mesh; choose a larger target")
    raise MeshGeometryError(
        f"decimating to {target} faces changed the volume by {100 * change:.2g} % or more at every "
        f"aggression; choose a larger target"
    )


def _remove_fins(mesh: trimesh.Trimesh) -> None:
    """Drop back-to-back face pairs (same three vertices, opposite winding): the quadric
    simplifier leaves such zero-volume fins on noisy scans, and they make an edge non-manifold."""
    _, group, counts = np.unique(np.sort(mesh.faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    single = counts[group.ravel()] == 1
    if not single.all():
        mesh.update_faces(single)
        mesh.remove_unreferenced_vertices()


def mass_properties(
    mesh: trimesh.Trimesh, *, mass: float | None = None, density: float | None = None
) -> MassProperties:
    """Mass, centre of mass and inertia of the solid bounded by ``mesh``.

    Give exactly one of ``mass`` (kg; the density follows from the volume) or ``density``
    (kg/m^3). The principal axes are the eigenvectors of the inertia tensor, made right-handed
    (``dem.frames.principal_axes``).
    """
    if (mass is None) == (density is None):
        raise MeshError("give exactly one of mass or density")
    volume = float(mesh.volume)
    if not volume > 0:
        raise MeshGeometryError(f"mesh volume is {volume:.3g} m^3; validate the mesh first")
    if mass is not None:
        if not mass > 0:
            raise MeshError(f"mass must be positive (got {mass} kg)")
        density = mass / volume
    elif not density > 0:
        raise MeshError(f"density must be positive (got {density} kg/m^3)")
    else:
        mass = density * volume
    unit = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    unit.density = 1.0
    inertia = np.asarray(unit.moment_inertia, dtype=np.float64) * density
    inertia = 0.5 * (inertia + inertia.T)
    moments, axes = principal_axes(inertia)  # not LAPACK's: the same last bit on every machine
    return MassProperties(
        mass=float(mass),
        volume=volume,
        density=float(density),
        com=np.asarray(unit.center_mass, dtype=np.float64),
        inertia=inertia,
        principal_moments=moments,
        principal_axes=axes,
    )


def mesh_digest(mesh: trimesh.Trimesh) -> str:
    """A stable hash of the geometry (vertices and faces bytes), for caches."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(mesh.vertices, dtype="<f8").tobytes())
    digest.update(np.ascontiguousarray(mesh.faces, dtype="<i8").tobytes())
    return digest.hexdigest()
