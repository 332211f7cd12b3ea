"""The items fed to the vibration feeder: the paper's three WEEE classes as parametric meshes, or
the user's own (scanned) meshes from a folder, each with its clump.

The paper (Kawaguchi et al. 2021) fed 10 smartphones, 10 feature phones and 10 compact digital
cameras, 3D-scanned; its Table 1 (volumes and masses) is not in our copy, so the nominal shapes
below come from manufacturers' published dimensions (width x height x depth) and masses:

- smartphone: Apple iPhone 6, 138.1 x 67.0 x 6.9 mm, 129 g; Samsung Galaxy S7, 142.4 x 69.6 x
  7.9 mm, 152 g; Samsung Galaxy S8, 148.9 x 68.1 x 8.0 mm, 155 g; Apple iPhone 11 Pro, 144.0 x
  71.4 x 8.1 mm, 188 g. Nominal: 146 x 71 x 8 mm, 170 g, outline corners rounded (r 9 mm).
- feature phone (candy-bar and closed flip phones): Nokia 105 (2017), about 112 x 49 x 14 mm,
  73 g; Nokia 3310 (2000), 113 x 48 x 22 mm, 133 g; Motorola RAZR V3 (closed), 98 x 53 x
  13.9 mm, 95 g. Nominal: 110 x 50 x 16 mm, 95 g, corners rounded (r 8 mm).
- compact digital camera: Canon IXUS 160 / PowerShot ELPH 160, 95.2 x 54.3 x 22.1 mm, 127 g;
  Canon IXUS 285 HS, 99.6 x 58.0 x 22.8 mm, 147 g; Sony Cyber-shot DSC-W800, 96.8 x 55.5 x
  20.8 mm, 125 g (with battery and card). Nominal body 96 x 56 x 22 mm, 135 g, plus a cylindrical
  lens barrel (36 mm diameter, 10 mm protrusion, centred 21 mm off the body's centre along its
  length): the barrel makes the camera non-box and its mass distribution asymmetric. Barrel
  size and corner radii are our choice, not product data.

Each mesh is one watertight solid (rounded slabs are convex hulls of corner cylinders; the camera
is a manifold boolean union of slab and barrel), so mass properties come out right.

Representation (``REPRESENTATIONS``): a rounded polyhedron (``dem/polyhedra.py``: flat faces,
edges rounded by a quarter of the thinnest dimension; the camera's pieces are its known parts,
slab and barrel) or a sphere clump of ``resolution`` spheres (``dem/clumping.py``).

Per-item spread: every dimension and the mass of an item is the nominal one times an independent
factor drawn uniformly from [1 - spread, 1 + spread], so no two items are identical. Fitting 30
clumps would cost seconds per run, so the shape is made once per kind (clumps also cached) and
mapped to each item by ``dem.clumping.deform_clump`` (centres scaled with the mesh, radii by the
smallest factor: the spheres stay inscribed) or ``dem.polyhedra.deform_polyhedron`` (cores
mapped, still convex); mass, centre of mass and inertia are those of the item's own mesh and
mass. Draw the item set from a fixed generator if the same 30 "physical" items should be fed in
every run, as in the experiment.

User meshes (``items_from_folder``): STL/OBJ/PLY files in a folder with counts and masses (from
the caller, or a ``items.toml`` / ``items.json`` manifest in the folder), validated, decimated when
heavy (scans; ``dem.mesh.decimate`` keeps the volume), then decomposed into convex pieces (CoACD;
a scan of a convex item stays one piece, ``dem.polyhedra.CONVEX_TOLERANCE``) or clumped. This
module must not run simulations.
"""

from __future__ import annotations

import json
import logging
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh

from dem.clump import Clump
from dem.clumping import DEFAULT_N_SPHERES, deform_clump, make_clump
from dem.mesh import ALLOWED_FILE_TYPES, MeshError, decimate, load_mesh_file
from dem.polyhedra import CORE_TOLERANCE, Polyhedron, deform_polyhedron, make_polyhedron

logger = logging.getLogger(__name__)

KINDS = ("smartphone", "feature_phone", "camera")
DEFAULT_COUNTS = {"smartphone": 10, "feature_phone": 10, "camera": 10}
# Scanned meshes are decimated to this many faces before use (the paper: scans reduced to 1/1000).
FOLDER_MESH_FACES = 5000
MANIFEST_NAMES = ("items.toml", "items.json")
REPRESENTATIONS = ("polyhedron", "clump")
DEFAULT_REPRESENTATION = "clump"
_CORNER_SECTIONS = 12


class ItemsError(ValueError):
    """The item set cannot be built as asked; the message names the kind, file or key."""


@dataclass(frozen=True)
class ItemSpec:
    """Outer dimensions (m) and mass (kg) of one item. ``length`` >= ``width`` >= ``thickness``,
    with thickness the body's depth; a camera's lens barrel comes on top of it."""

    kind: str
    length: float
    width: float
    thickness: float
    mass: float
    corner_radius: float = 0.0  # rounding of the outline seen from the front, m
    lens_diameter: float = 0.0  # camera lens barrel; 0 means none
    lens_protrusion: float = 0.0
    lens_offset: float = 0.0  # barrel centre from the body centre along the length, m

    def mesh(self) -> trimesh.Trimesh:
        """The item as one closed mesh: length along x, width along y, depth along z."""
        parts = self.pieces()
        if len(parts) == 1:
            return parts[0]
        return trimesh.boolean.union(parts, engine="manifold")

    def pieces(self) -> list[trimesh.Trimesh]:
        """The item's convex parts (their union is ``mesh()``): the slab, and the lens barrel,
        which starts inside the body so that the union is one solid, not two touching ones."""
        body = _rounded_slab(self.length, self.width, self.thickness, self.corner_radius)
        if self.lens_diameter <= 0 or self.lens_protrusion <= 0:
            return [body]
        sink = 0.25 * self.thickness
        barrel = trimesh.creation.cylinder(
            radius=0.5 * self.lens_diameter, height=self.lens_protrusion + sink, sections=32
        )
        barrel.apply_translation(
            [self.lens_offset, 0.0, 0.5 * self.thickness + 0.5 * (self.lens_protrusion - sink)]
        )
        return [body, barrel]

    def scaled(self, length: float, width: float, thickness: float, mass: float) -> ItemSpec:
        """This spec with dimensions and mass multiplied by the given factors; the lens barrel
        scales with the body (its diameter by the mean in-plane factor: the mesh's barrel becomes
        very slightly elliptical)."""
        return replace(
            self,
            length=self.length * length,
            width=self.width * width,
            thickness=self.thickness * thickness,
            mass=self.mass * mass,
            corner_radius=self.corner_radius * float(np.sqrt(length * width)),
            lens_diameter=self.lens_diameter * float(np.sqrt(length * width)),
            lens_protrusion=self.lens_protrusion * thickness,
            lens_offset=self.lens_offset * length,
        )


@dataclass(frozen=True)
class Item:
    """One body to feed: its mesh (m, mesh coordinates), mass (kg) and the shape the engine
    simulates (a rounded polyhedron or a clump)."""

    name: str
    kind: str
    mesh: trimesh.Trimesh
    mass: float
    shape: Polyhedron | Clump
    spec: ItemSpec | None = None


CATALOGUE: dict[str, ItemSpec] = {
    "smartphone": ItemSpec("smartphone", 0.146, 0.071, 0.008, 0.170, corner_radius=0.009),
    "feature_phone": ItemSpec("feature_phone", 0.110, 0.050, 0.016, 0.095, corner_radius=0.008),
    "camera": ItemSpec(
        "camera",
        0.096,
        0.056,
        0.022,
        0.135,
        corner_radius=0.005,
        lens_diameter=0.036,
        lens_protrusion=0.010,
        lens_offset=0.021,
    ),
}

def _rounded_slab(length: float, width: float, thickness: float, corner_radius: float) -> trimesh.Trimesh:
    if corner_radius <= 0:
        return trimesh.creation.box((length, width, thickness))
    corner_radius = min(corner_radius, 0.499 * min(length, width))
    corner = trimesh.creation.cylinder(radius=corner_radius, height=thickness, sections=4 * _CORNER_SECTIONS)
    x, y = 0.5 * length - corner_radius, 0.5 * width - corner_radius
    points = np.vstack([corner.vertices + [sx * x, sy * y, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    return trimesh.convex.convex_hull(points)


def _spec(kind: str) -> ItemSpec:
    try:
        return CATALOGUE[kind]
    except KeyError:
        raise ItemsError(f"unknown item kind {kind!r}; built-in kinds are {', '.join(KINDS)}") from None


def nominal_volume(kind: str) -> float:
    """Volume of the nominal item of ``kind``, m^3 (for checking that a set fits the tray)."""
    return float(_nominal_mesh(kind).volume)


_NOMINAL_MESHES: dict[str, trimesh.Trimesh] = {}


def _nominal_mesh(kind: str) -> trimesh.Trimesh:
    if kind not in _NOMINAL_MESHES:
        _NOMINAL_MESHES[kind] = _spec(kind).mesh()
    return _NOMINAL_MESHES[kind]


def _factors(rng: np.random.Generator, spread: float, count: int) -> np.ndarray:
    if not 0 <= spread < 0.5:
        raise ItemsError(f"spread must be in [0, 0.5) (got {spread})")
    return 1.0 + spread * rng.uniform(-1.0, 1.0, size=(count, 4))


def _variant(
    name: str,
    kind: str,
    mesh: trimesh.Trimesh,
    shape: Polyhedron | Clump,
    factors: np.ndarray,
    mass: float,
    spec: ItemSpec | None,
) -> Item:
    """The item of ``mesh`` scaled by factors (x, y, z) with the given mass, shape mapped along."""
    matrix = np.diag(factors[:3])
    scaled = mesh.copy()
    scaled.apply_transform(np.block([[matrix, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
    deform = deform_polyhedron if isinstance(shape, Polyhedron) else deform_clump
    return Item(
        name=name,
        kind=kind,
        mesh=scaled,
        mass=mass,
        shape=deform(shape, matrix, scaled, mass=mass, name=name),
        spec=spec,
    )


def _shape(
    representation: str,
    mesh: trimesh.Trimesh,
    mass: float,
    resolution: int,
    name: str,
    cache_dir,
    pieces: list[trimesh.Trimesh] | None = None,
    core_tolerance: float = CORE_TOLERANCE,
) -> Polyhedron | Clump:
    """The nominal shape of one kind in the chosen representation."""
    if representation == "polyhedron":
        return make_polyhedron(mesh, mass=mass, pieces=pieces, name=name, core_tolerance=core_tolerance)
    if representation == "clump":
        return make_clump(mesh, mass=mass, n_spheres=resolution, name=name, cache_dir=cache_dir)
    raise ItemsError(f"representation {representation!r}; choose one of {', '.join(REPRESENTATIONS)}")


def default_items(
    rng: np.random.Generator,
    counts: dict[str, int] | None = None,
    spread: float = 0.03,
    resolution: int = DEFAULT_N_SPHERES,
    *,
    representation: str = DEFAULT_REPRESENTATION,
    cache_dir: str | Path | None | bool = None,
    core_tolerance: float = CORE_TOLERANCE,
) -> list[Item]:
    """The paper's WEEE set (by default 10 + 10 + 10), kind by kind, each item perturbed.

    ``representation``: one of ``REPRESENTATIONS``; ``resolution`` is the clump's sphere count
    (``make_clump(n_spheres=...)``); ``core_tolerance`` the polyhedra's core simplification
    (``make_polyhedron``).
    """
    counts = DEFAULT_COUNTS if counts is None else counts
    items: list[Item] = []
    for kind, count in counts.items():
        if count < 0:
            raise ItemsError(f"counts.{kind} is {count}; counts cannot be negative")
        if count == 0:
            continue
        nominal = _spec(kind)
        mesh = _nominal_mesh(kind)
        shape = _shape(
            representation, mesh, nominal.mass, resolution, kind, cache_dir, nominal.pieces(), core_tolerance
        )
        for index, factors in enumerate(_factors(rng, spread, count)):
            spec = nominal.scaled(*factors)
            items.append(_variant(f"{kind}-{index + 1:02d}", kind, mesh, shape, factors, spec.mass, spec))
    return items


def _read_manifest(folder: Path) -> dict:
    for name in MANIFEST_NAMES:
        path = folder / name
        if path.exists():
            try:
                text = path.read_text()
                return tomllib.loads(text) if name.endswith(".toml") else json.loads(text)
            except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
                raise ItemsError(f"{path}: cannot parse the manifest: {exc}") from exc
    return {}


def _mesh_files(folder: Path) -> dict[str, Path]:
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix.lower().lstrip(".") in ALLOWED_FILE_TYPES:
            if path.stem in files:
                raise ItemsError(f"{folder}: two meshes are named {path.stem!r}; rename one")
            files[path.stem] = path
    return files


class FolderItems(NamedTuple):
    """What a folder of meshes feeds: counts and masses (kg) per file stem, the meshes' scale to
    metres, and the mesh file of every stem."""

    counts: dict[str, int]
    masses: dict[str, float]
    scale: float
    files: dict[str, Path]


def folder_items(
    folder: str | Path,
    counts: dict[str, int] | None = None,
    masses: dict[str, float] | None = None,
    scale: float | None = None,
) -> FolderItems:
    """The counts, masses and scale of a folder of meshes: the caller's where given, else its
    manifest's, ``items.toml`` (``scale = 0.001`` and ``[items.<stem>]`` tables with ``count``
    and ``mass``) or the same as ``items.json``. Reads file names and the manifest, no mesh; an
    ``ItemsError`` names the missing mesh, mass or manifest and what to give instead."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ItemsError(f"items folder {folder} does not exist or is not a folder")
    manifest = _read_manifest(folder)
    entries = manifest.get("items", {})
    if not isinstance(entries, dict) or not all(isinstance(e, dict) for e in entries.values()):
        raise ItemsError(f"{folder}: the manifest's 'items' must be a table of <stem> = {{count, mass}}")
    try:
        counts = dict(counts) if counts else {stem: int(e.get("count", 1)) for stem, e in entries.items()}
        masses = {**{stem: float(e["mass"]) for stem, e in entries.items() if "mass" in e}, **(masses or {})}
        scale = float(manifest.get("scale", 1.0)) if scale is None else scale
    except (TypeError, ValueError) as exc:
        raise ItemsError(f"{folder}: the manifest's counts, masses and scale are numbers ({exc})") from None
    files = _mesh_files(folder)
    if not counts:
        raise ItemsError(f"{folder}: no counts given and no {' or '.join(MANIFEST_NAMES)} manifest found")
    for stem, count in counts.items():
        if stem not in files:
            example = ", ".join(f"{found} = 1" for found in files) or "<stem> = 1"
            raise ItemsError(
                f"counts.{stem}: no mesh {stem}.stl/.obj/.ply in {folder} "
                f"(found: {', '.join(files) or 'none'}); counts name the folder's meshes by file "
                f"stem (counts = {{ {example} }}), or leave counts out to take them from its "
                f"{MANIFEST_NAMES[0]}"
            )
        if count > 0 and stem not in masses:
            raise ItemsError(
                f"masses.{stem}: the mass (kg) of {files[stem].name} is missing; give masses.{stem} "
                f"or a mass in the folder's {MANIFEST_NAMES[0]}"
            )
    return FolderItems(counts, masses, scale, files)


def items_from_folder(
    folder: str | Path,
    counts: dict[str, int] | None = None,
    masses: dict[str, float] | None = None,
    rng: np.random.Generator | None = None,
    spread: float = 0.0,
    resolution: int = DEFAULT_N_SPHERES,
    *,
    scale: float | None = None,
    representation: str = DEFAULT_REPRESENTATION,
    cache_dir: str | Path | None | bool = None,
    core_tolerance: float = CORE_TOLERANCE,
) -> list[Item]:
    """Items from a folder of STL/OBJ/PLY meshes; kinds are file stems.

    ``counts``, ``masses`` (kg) and ``scale`` (the files' unit in metres) as ``folder_items``
    takes them. Meshes over ``FOLDER_MESH_FACES`` faces are decimated first; a non-convex mesh
    becomes convex pieces by ``dem.polyhedra.convex_pieces`` (CoACD) in the polyhedron
    representation.
    """
    counts, masses, scale, files = folder_items(folder, counts, masses, scale)
    rng = rng if rng is not None else np.random.default_rng(0)

    items: list[Item] = []
    for stem, count in counts.items():
        if count <= 0:
            continue
        try:
            mesh, report = load_mesh_file(files[stem], scale=scale)
            if len(mesh.faces) > FOLDER_MESH_FACES:
                mesh = decimate(mesh, target_faces=FOLDER_MESH_FACES)
        except MeshError as exc:
            raise ItemsError(f"{files[stem].name}: {exc}") from exc
        for warning in report.warnings:
            logger.warning("%s: %s", files[stem].name, warning)
        mass = float(masses[stem])
        try:
            shape = _shape(representation, mesh, mass, resolution, stem, cache_dir, None, core_tolerance)
        except MeshError as exc:
            raise ItemsError(f"{files[stem].name}: {exc}") from exc
        for index, factors in enumerate(_factors(rng, spread, count)):
            name = f"{stem}-{index + 1:02d}"
            items.append(_variant(name, stem, mesh, shape, factors, mass * factors[3], None))
    return items
