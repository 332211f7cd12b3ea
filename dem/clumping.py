"""Sphere clumps from closed triangle meshes: the shape of a rigid body as the engine sees it.

Algorithm (inscribed spheres, greedy surface cover):

1. The surface is sampled uniformly by area (plus the mesh's vertices, so that corners count).
2. Candidate centres approximate the medial axis: for every sample ``p`` with inward normal ``n``
   the shrinking-ball iteration (Ma, Bae, Choi & Rusinkiewicz, 2012, "3D medial axis point
   approximation using nearest neighbors and the normal field") shrinks the ball tangent at ``p``
   until no other sample lies inside it. A grid along the principal axes supplies the deepest
   points where the samples miss them (where several medial sheets meet, as at a cube's centre).
   Each candidate's radius is then the exact distance from
   its centre to the mesh (point-triangle distances, with the inside test by the generalised
   winding number), so every sphere is inscribed: it never bulges out of the mesh. Candidates
   smaller than ``min_radius_fraction`` of the largest inscribed sphere are dropped (tiny spheres
   add contacts but hardly change the shape).
3. Greedy cover: the *gap* of a surface point is its distance to the envelope of the chosen
   spheres (``min_j |p - c_j| - r_j``). Each step adds the candidate that reduces the summed gap
   the most among those that also reduce the currently worst gap, so large inscribed spheres come
   first and smaller ones at edges and corners follow, pulling the envelope onto the outline.
   It stops at ``n_spheres`` spheres, or when the worst gap is below ``tolerance``.
4. ``Clump.max_error`` is measured afterwards on a denser, independent sample of the full mesh:
   the largest inward gap or outward bulge (the latter only from the sampling of a decimated
   working mesh; it is zero for an exactly inscribed clump).

Mass, centre of mass and inertia come from the mesh (``dem.mesh.mass_properties``), never from the
spheres. Thin flat bodies have an irreducible gap in the middle of their faces between spheres of
radius thickness / 2; a phone at the default 24 spheres has a face gap of a few millimetres while
its outline and thickness are exact to about a millimetre. Each sphere's contact properties are
the engine's business (it normalises per body so stiffness does not depend on the count).

Clumps are cached on disk by mesh hash + resolution + mass (npz, atomic writes) and in memory.
This module must not import anything outside ``dem`` (the cache directory is an argument, or
``$DEMCAL_DATA_DIR/clumps``).
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from dem.clump import Clump
from dem.conf import JIT_FLAGS
from dem.frames import norm, smallest_singular_value, symmetric_eigen, transform
from dem.mesh import MeshError, decimate, mass_properties, mesh_digest

logger = logging.getLogger(__name__)

DEFAULT_N_SPHERES = 24
MAX_SPHERES = 2000
# Bump when the algorithm changes, so that stale cache files are not reused.
ALGORITHM_VERSION = 1
# Above this many faces the spheres are fitted to a decimated copy (distances cost faces x points);
# the error is still measured on the full mesh.
WORKING_FACES = 3000
_N_COVER_SAMPLES = 2500
_N_ERROR_SAMPLES = 20000
_MEMORY_CACHE: dict[str, Clump] = {}


class ClumpError(MeshError):
    """A clump cannot be made as asked (e.g. a tolerance finer than the candidates allow)."""


@dataclass(frozen=True)
class ClumpFit:
    """How well a set of spheres follows a mesh surface, m."""

    max_gap: float  # largest distance from a surface point to the envelope, surface outside it
    mean_gap: float
    max_bulge: float  # largest depth of a surface point inside a sphere (sphere sticking out)

    @property
    def max_error(self) -> float:
        return max(self.max_gap, self.max_bulge)


@numba.njit(**JIT_FLAGS)
def _distance_and_winding(points, tri):  # pragma: no cover - compiled
    """Unsigned distance to the triangles and generalised winding number of each point.

    Distance: Ericson, Real-Time Collision Detection (2005), 5.1.5. Winding number: sum of the
    triangles' solid angles (Van Oosterom & Strackee, 1983) over 4 pi; about 1 inside, 0 outside.
    """
    n = points.shape[0]
    dist = np.empty(n)
    wind = np.empty(n)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        omega = 0.0
        for t in range(tri.shape[0]):
            ax, ay, az = tri[t, 0, 0] - px, tri[t, 0, 1] - py, tri[t, 0, 2] - pz
            bx, by, bz = tri[t, 1, 0] - px, tri[t, 1, 1] - py, tri[t, 1, 2] - pz
            cx, cy, cz = tri[t, 2, 0] - px, tri[t, 2, 1] - py, tri[t, 2, 2] - pz
            la = np.sqrt(ax * ax + ay * ay + az * az)
            lb = np.sqrt(bx * bx + by * by + bz * bz)
            lc = np.sqrt(cx * cx + cy * cy + cz * cz)
            det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
            den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc
            den += (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la
            omega += 2.0 * np.arctan2(det, den)
            # Closest point of triangle (a, b, c) to the origin (the point, after the shift).
            abx, aby, abz = bx - ax, by - ay, bz - az
            acx, acy, acz = cx - ax, cy - ay, cz - az
            d1 = -(abx * ax + aby * ay + abz * az)
            d2 = -(acx * ax + acy * ay + acz * az)
            if d1 <= 0.0 and d2 <= 0.0:
                qx, qy, qz = ax, ay, az
            else:
                d3 = -(abx * bx + aby * by + abz * bz)
                d4 = -(acx * bx + acy * by + acz * bz)
                d5 = -(abx * cx + aby * cy + abz * cz)
                d6 = -(acx * cx + acy * cy + acz * cz)
                vc = d1 * d4 - d3 * d2
                vb = d5 * d2 - d1 * d6
                va = d3 * d6 - d5 * d4
                if d3 >= 0.0 and d4 <= d3:
                    qx, qy, qz = bx, by, bz
                elif d6 >= 0.0 and d5 <= d6:
                    qx, qy, qz = cx, cy, cz
                elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                    v = d1 / (d1 - d3)
                    qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
                elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                    w = d2 / (d2 - d6)
                    qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
                elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                    w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                    qx, qy, qz = bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
                else:
                    s = 1.0 / (va + vb + vc)
                    v = vb * s
                    w = vc * s
                    qx = ax + abx * v + acx * w
                    qy = ay + aby * v + acy * w
                    qz = az + abz * v + acz * w
            d = qx * qx + qy * qy + qz * qz
            if d < best:
                best = d
        dist[i] = np.sqrt(best)
        wind[i] = omega / (4.0 * np.pi)
    return dist, wind


def signed_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Distance from each point to the closed surface, positive inside, negative outside."""
    triangles = np.ascontiguousarray(mesh.triangles, dtype=np.float64)
    dist, wind = _distance_and_winding(np.ascontiguousarray(points, dtype=np.float64), triangles)
    return np.where(wind > 0.5, dist, -dist)


def _surface_samples(mesh: trimesh.Trimesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    points, face_index = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points, dtype=np.float64), np.asarray(mesh.face_normals[face_index], dtype=np.float64)


def _medial_candidates(points: np.ndarray, normals: np.ndarray, size: float) -> np.ndarray:
    """Centres of the shrinking balls: approximately the medial axis (step 2 of the algorithm)."""
    tree = cKDTree(points)
    inward = -normals
    radius = np.full(len(points), size)
    own = np.arange(len(points))
    for _ in range(60):
        centre = points + radius[:, None] * inward
        dist, index = tree.query(centre, k=2)
        not_self = index[:, 0] != own
        nearest = np.where(not_self, index[:, 0], index[:, 1])
        nearest_dist = np.where(not_self, dist[:, 0], dist[:, 1])
        inside = nearest_dist < radius * (1.0 - 1e-6)
        if not inside.any():
            break
        pq = points[nearest] - points
        denominator = 2.0 * np.einsum("ij,ij->i", pq, inward)
        # The ball tangent at p through q has radius |pq|^2 / (2 pq.n); q behind the tangent
        # plane (denominator <= 0) cannot limit it.
        with np.errstate(divide="ignore", invalid="ignore"):
            tangent = np.where(denominator > 0, np.einsum("ij,ij->i", pq, pq) / denominator, radius)
        radius = np.where(inside, np.minimum(radius, tangent), radius)
    return points + radius[:, None] * inward


def _grid_candidates(mesh: trimesh.Trimesh, count: int = 1000) -> np.ndarray:
    """About ``count`` points on a grid along the principal axes, centred on the box that bounds
    the mesh in that frame, with an odd number of points per axis so that the centre plane of a
    slab (where its largest inscribed spheres sit) is always on the grid."""
    _, axes = symmetric_eigen(mesh.moment_inertia)
    local = transform(mesh.vertices - mesh.centroid, axes)
    low, high = local.min(axis=0), local.max(axis=0)
    spacing = float(np.prod(high - low) / count) ** (1.0 / 3.0)
    half_counts = np.floor(0.5 * (high - low) / spacing).astype(int)
    axes_points = [
        0.5 * (lo + hi) + spacing * np.arange(-n, n + 1)
        for lo, hi, n in zip(low, high, half_counts, strict=True)
    ]
    grid = np.stack(np.meshgrid(*axes_points, indexing="ij"), axis=-1).reshape(-1, 3)
    return mesh.centroid + transform(grid, axes.T)


def _greedy_cover(
    gaps: np.ndarray, n_spheres: int | None, tolerance: float | None
) -> tuple[list[int], np.ndarray]:
    """Step 3: choose candidate rows of ``gaps`` (candidates x surface points)."""
    limit = n_spheres if n_spheres is not None else MAX_SPHERES
    current = np.full(gaps.shape[1], np.float32(np.max(gaps) + 1.0), dtype=np.float32)
    chosen: list[int] = []
    while len(chosen) < limit:
        worst = int(np.argmax(current))
        if tolerance is not None and current[worst] <= tolerance:
            break
        improves_worst = gaps[:, worst] < current[worst] - 1e-9
        if not improves_worst.any():
            break
        gain = np.maximum(current[None, :] - gaps, 0.0).sum(axis=1)
        gain[~improves_worst] = -1.0
        best = int(np.argmax(gain))
        chosen.append(best)
        current = np.minimum(current, gaps[best])
    return chosen, current


def clump_fit(mesh: trimesh.Trimesh, centres: np.ndarray, radius: np.ndarray, *, seed: int = 1) -> ClumpFit:
    """Gap and bulge of spheres (``centres`` in the mesh's coordinates) against the mesh surface."""
    points, _ = _surface_samples(mesh, _N_ERROR_SAMPLES, seed)
    points = np.vstack([points, mesh.vertices])
    # Chunks keep the points x spheres matrix small when a fine tolerance made many spheres.
    chunk = max(1, 2_000_000 // max(1, len(radius)))
    surplus = np.concatenate(
        [(cdist(points[i : i + chunk], centres) - radius).min(axis=1) for i in range(0, len(points), chunk)]
    )
    gap = np.maximum(surplus, 0.0)
    # A surface point inside a sphere means that sphere crosses the surface there, by at least this.
    bulge = float(max(0.0, -surplus.min()))
    return ClumpFit(max_gap=float(gap.max()), mean_gap=float(gap.mean()), max_bulge=bulge)


def _fit_spheres(
    mesh: trimesh.Trimesh,
    n_spheres: int | None,
    tolerance: float | None,
    min_radius_fraction: float,
    seed: int,
) -> tuple[np.ndarray, np.ndarray]:
    work = mesh
    if len(mesh.faces) > WORKING_FACES:
        try:
            work = decimate(mesh, target_faces=WORKING_FACES)
        except MeshError as exc:
            logger.info("fitting on the full mesh (%d faces): %s", len(mesh.faces), exc)
    size = norm(work.extents)
    points, normals = _surface_samples(work, _N_COVER_SAMPLES, seed)
    centres = _medial_candidates(points, normals, size)
    depth = signed_distance(work, centres)
    grid = _grid_candidates(work)
    grid_depth = signed_distance(work, grid)
    # Grid points only where they are deeper than every medial ball (a cube's centre): elsewhere
    # the medial balls are better, because each touches the surface and so pins the envelope to
    # the outline.
    deeper = grid_depth > depth.max() * 1.005
    centres, depth = np.vstack([centres, grid[deeper]]), np.concatenate([depth, grid_depth[deeper]])
    keep = depth > 0
    if not keep.any():
        raise ClumpError("no interior point found; the mesh is too thin or inside-out")
    centres, depth = centres[keep], depth[keep]
    # Shrink by a hair so that rounding never puts a sphere outside the surface.
    radius = depth * (1.0 - 1e-6)
    keep = radius >= min_radius_fraction * radius.max()
    centres, radius = centres[keep], radius[keep]
    # Near-duplicate candidates only cost time.
    _, unique = np.unique(np.round(centres / (0.02 * radius.max())), axis=0, return_index=True)
    centres, radius = centres[unique], radius[unique]

    cover = np.vstack([points, work.vertices])
    gaps = (cdist(centres, cover) - radius[:, None]).astype(np.float32)
    chosen, current = _greedy_cover(gaps, n_spheres, tolerance)
    if tolerance is not None and current.max() > tolerance:
        raise ClumpError(
            f"a tolerance of {tolerance * 1e3:.3g} mm cannot be reached with inscribed spheres of at "
            f"least {min_radius_fraction:g} x the largest (best: {current.max() * 1e3:.3g} mm after "
            f"{len(chosen)} spheres); allow a larger tolerance or a smaller min_radius_fraction"
        )
    return centres[chosen], radius[chosen]


def _cache_key(mesh: trimesh.Trimesh, **params) -> str:
    digest = hashlib.sha256(mesh_digest(mesh).encode())
    digest.update(repr(sorted(params.items())).encode())
    digest.update(f"v{ALGORITHM_VERSION}".encode())
    return digest.hexdigest()[:32]


def default_cache_dir() -> Path:
    """``$DEMCAL_DATA_DIR/clumps``, with the same default data directory as the service."""
    return Path(os.environ.get("DEMCAL_DATA_DIR", "demcal-data")) / "clumps"


def _save(path: Path, clump: Clump) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    # Write then rename: a concurrent reader (another worker) sees the old file or the whole new one.
    handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(handle, "wb") as stream:
            np.savez(
                stream,
                radius=clump.radius,
                offset=clump.offset,
                mass=clump.mass,
                inertia=clump.inertia,
                volume=clump.volume,
                com=clump.com,
                axes=clump.axes,
                max_error=clump.max_error,
            )
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _load(path: Path, name: str) -> Clump | None:
    try:
        with np.load(path) as data:
            return Clump(
                radius=data["radius"],
                offset=data["offset"],
                mass=float(data["mass"]),
                inertia=data["inertia"],
                volume=float(data["volume"]),
                com=data["com"],
                axes=data["axes"],
                max_error=float(data["max_error"]),
                name=name,
            )
    except (OSError, KeyError, ValueError) as exc:
        logger.warning("ignoring unreadable clump cache file %s: %s", path, exc)
        return None


def _assemble(centres: np.ndarray, radius: np.ndarray, properties, max_error: float, name: str) -> Clump:
    """A Clump from sphere centres in mesh coordinates and the mesh's mass properties: the
    spheres are moved into the principal frame, mass and inertia are the mesh's own."""
    return Clump(
        radius=np.asarray(radius, dtype=np.float64),
        offset=transform(centres - properties.com, properties.principal_axes),
        **properties.body_fields(),
        max_error=max_error,
        name=name,
    )


def make_clump(
    mesh: trimesh.Trimesh,
    *,
    mass: float | None = None,
    density: float | None = None,
    n_spheres: int | None = None,
    tolerance: float | None = None,
    min_radius_fraction: float = 0.25,
    name: str = "",
    cache_dir: str | Path | None | bool = None,
    seed: int = 0,
) -> Clump:
    """The clump of a validated, watertight mesh (metres), with mass properties from the mesh.

    Resolution: ``n_spheres`` (at most that many spheres) or ``tolerance`` (largest gap between
    surface and envelope on the fitting samples, m); neither means ``DEFAULT_N_SPHERES``. Give
    ``mass`` (kg) or ``density`` (kg/m^3). ``cache_dir=False`` disables the disk cache; ``None``
    uses ``default_cache_dir()``.
    """
    if n_spheres is not None and tolerance is not None:
        raise ClumpError("give n_spheres or tolerance, not both")
    if n_spheres is None and tolerance is None:
        n_spheres = DEFAULT_N_SPHERES
    if n_spheres is not None and not 1 <= n_spheres <= MAX_SPHERES:
        raise ClumpError(f"n_spheres must be between 1 and {MAX_SPHERES} (got {n_spheres})")
    if tolerance is not None and not tolerance > 0:
        raise ClumpError(f"tolerance must be a positive length in metres (got {tolerance})")
    if not 0 < min_radius_fraction <= 1:
        raise ClumpError(f"min_radius_fraction must be in (0, 1] (got {min_radius_fraction})")
    properties = mass_properties(mesh, mass=mass, density=density)

    key = _cache_key(
        mesh,
        n_spheres=n_spheres,
        tolerance=tolerance,
        mass=properties.mass,
        min_radius_fraction=min_radius_fraction,
        seed=seed,
    )
    path = None
    if cache_dir is not False:
        path = Path(cache_dir if cache_dir not in (None, True) else default_cache_dir()) / f"{key}.npz"
    cached = _MEMORY_CACHE.get(key)
    if cached is None and path is not None and path.exists():
        cached = _load(path, name)
    if cached is not None:
        _MEMORY_CACHE[key] = cached
        return Clump(**{**cached.__dict__, "name": name})

    centres, radius = _fit_spheres(mesh, n_spheres, tolerance, min_radius_fraction, seed)
    fit = clump_fit(mesh, centres, radius, seed=seed + 1)
    clump = _assemble(centres, radius, properties, fit.max_error, name)
    logger.info(
        "clump %s: %d spheres, max error %.3g mm, mean gap %.3g mm",
        name or key[:8],
        clump.n_spheres,
        fit.max_error * 1e3,
        fit.mean_gap * 1e3,
    )
    _MEMORY_CACHE[key] = clump
    if path is not None:
        _save(path, clump)
    return clump


def deform_clump(
    clump: Clump,
    matrix: np.ndarray,
    mesh: trimesh.Trimesh,
    *,
    mass: float | None = None,
    density: float | None = None,
    name: str = "",
) -> Clump:
    """The clump of ``mesh`` = ``matrix`` applied to the mesh ``clump`` was made from, without
    fitting again: a nearly-identical variant of a body (e.g. dimensions spread by a few %).

    Sphere centres map through ``matrix``; radii shrink by its smallest singular value, because
    the image of a ball of radius r contains the ball of radius r * sigma_min around the image of
    its centre, so inscribed spheres stay inscribed. Mass properties and the error are those of
    the new mesh.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    properties = mass_properties(mesh, mass=mass, density=density)
    centres = transform(clump.com + transform(clump.offset, clump.axes.T), matrix.T)
    radius = clump.radius * smallest_singular_value(matrix)
    fit = clump_fit(mesh, centres, radius)
    return _assemble(centres, radius, properties, fit.max_error, name)
