r"""Rounded polyhedra (sphero-polyhedra): a rigid body's shape as convex cores swept by a sphere.

A piece is the Minkowski sum of a convex polyhedron, its *core*, and a ball of radius r (the
*rounding*): flat faces, edges rounded with radius r, no gaps. A body is one piece (a phone, a
box) or a union of convex pieces (a camera: body slab and lens barrel). Contacts are computed
between cores (``dem/convex.py``): overlap ``delta = r_a + r_b - distance``.

From a mesh (``make_polyhedron``): each convex piece (the mesh's convex hull unless pieces are
given) is shrunk by r, exactly: a convex polytope ``{x : n_i . x <= h_i}`` swept by a ball of
radius r after its faces moved inwards by r, ``{x : n_i . x <= h_i - r}``, is the polytope with
its edges and corners rounded (radius r), so faces stay where they were. r is the user's, or
``ROUNDING_FRACTION`` of the piece's thinnest dimension. Mass, centre of mass and inertia come
from the mesh (``dem.mesh.mass_properties``), as for clumps.

Non-convex meshes need pieces: ``convex_pieces`` documents the decomposition used (CoACD,
Wei et al., SIGGRAPH 2022); built-in items pass their known parts. This module builds
geometry; it computes no forces.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from dem.convex import MAX_FEATURE, gjk_distance, place
from dem.frames import smallest_singular_value, transform
from dem.mesh import MeshError, mass_properties

ROUNDING_FRACTION = 0.25  # default r as a fraction of a piece's thinnest dimension
MAX_CORE_VERTICES = 48  # a core with more vertices is simplified (support queries cost O(n))
# A simplified core lies within this fraction of the rounding r of the full core (Hausdorff
# distance; simplify_core). 0 keeps every vertex (farthest-point sampling down to
# MAX_CORE_VERTICES beyond), as cores were made before.
CORE_TOLERANCE = 0.1
# A mesh whose convex hull lies within this fraction of its size (the bounding box's diagonal) of
# its surface is one convex piece (``convex_pieces``): a scan's noise or a decimation leaves a
# convex item's mesh slightly non-convex (a phone scanned with 0.05 mm of noise: CoACD cut it
# into 3 pieces), and each piece costs a contact pair and a seam without adding shape.
CONVEX_TOLERANCE = 0.01
# The crown of a core's faces (dem/crown.py) as its height at the edge of a face as wide as the
# piece, per unit of that width: R = size / (8 CROWN).
CROWN = 5e-4


class PolyhedronError(MeshError):
    """A rounded polyhedron cannot be made as asked; the message says what to change."""


@dataclass(frozen=True)
class Polyhedron:
    """Convex cores (one per piece) and mass properties of one rigid body.

    ``core`` holds every piece's vertices in the principal frame (origin at the centre of mass,
    ``diag(inertia)`` the inertia tensor), piece k being rows ``piece_start[k]`` to
    ``piece_start[k] + piece_count[k]``; ``com`` and ``axes`` place that frame in the mesh.
    """

    core: np.ndarray  # (n, 3) m
    piece_start: np.ndarray  # (p,)
    piece_count: np.ndarray  # (p,)
    rounding: float  # r, m
    mass: float
    inertia: np.ndarray  # (3,)
    volume: float
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axes: np.ndarray = field(default_factory=lambda: np.eye(3))
    name: str = ""

    def __post_init__(self) -> None:
        if len(self.piece_count) and int(np.max(self.piece_count)) > MAX_FEATURE:
            raise PolyhedronError(
                f"a piece has {int(np.max(self.piece_count))} core vertices, more than the contact "
                f"kernels' {MAX_FEATURE}; simplify it (make_polyhedron keeps {MAX_CORE_VERTICES})"
            )

    @property
    def n_pieces(self) -> int:
        return int(len(self.piece_start))

    def piece(self, k: int) -> np.ndarray:
        return self.core[self.piece_start[k] : self.piece_start[k] + self.piece_count[k]]

    def piece_centre(self, k: int) -> np.ndarray:
        """Centre of piece k's bounding sphere (body frame): the middle of its bounding box."""
        core = self.piece(k)
        return 0.5 * (core.min(axis=0) + core.max(axis=0))

    def piece_reach(self, k: int) -> float:
        """Radius of piece k's bounding sphere about ``piece_centre(k)``, rounding included."""
        return float(np.linalg.norm(self.piece(k) - self.piece_centre(k), axis=1).max()) + self.rounding

    def core_reach(self, k: int) -> float:
        """Distance of piece k's furthest core vertex from the body's centre (rounding excluded)."""
        return float(np.linalg.norm(self.piece(k), axis=1).max())

    def crown(self, k: int) -> tuple[float, float, float]:
        """Piece k's crown ``phi(x) = kappa (|x|^2 - h^2)`` about the centre of mass (``dem/crown.py``):
        ``(kappa, kappa h^2, kappa reach^2)``, kappa = 1 / (2 R) with R = size / (8 CROWN), h the
        distance of the nearest face plane of the core (0 if the centre is outside the core),
        reach that of the furthest core vertex."""
        core = self.piece(k)
        kappa = 4.0 * CROWN / (2.0 * self.piece_reach(k))
        try:
            planes = ConvexHull(core).equations  # n . x + c <= 0 inside
            h = max(0.0, float(np.min(-planes[:, 3])))
        except QhullError:  # a flat core: no inside
            h = 0.0
        reach = self.core_reach(k)
        return kappa, kappa * h * h, kappa * reach * reach

    @property
    def equivalent_diameter(self) -> float:
        """Diameter of the sphere of equal volume: the body's contact size in the contact law."""
        return float((6.0 * self.volume / np.pi) ** (1.0 / 3.0))

    def surface_mesh(self, sections: int = 8) -> trimesh.Trimesh:
        """The rounded shape (body frame) as a triangle mesh, for pictures and checks."""
        ball = trimesh.creation.icosphere(subdivisions=1 if sections <= 8 else 2, radius=self.rounding)
        parts = []
        for k in range(self.n_pieces):
            points = (self.piece(k)[:, None, :] + ball.vertices[None, :, :]).reshape(-1, 3)
            parts.append(trimesh.convex.convex_hull(points))
        return trimesh.util.concatenate(parts)

    @classmethod
    def box(cls, size, rounding: float, density: float, name: str = "box") -> Polyhedron:
        """A box of outer ``size`` with edges rounded by ``rounding``; mass properties are the
        sharp box's (those of its mesh, as ``make_polyhedron`` takes them)."""
        size = np.asarray(size, dtype=np.float64)
        if not 0 < rounding < 0.5 * size.min():
            raise PolyhedronError(f"rounding must be in (0, {0.5 * size.min()}) m, got {rounding}")
        half = 0.5 * size - rounding
        core = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
        volume = float(np.prod(size))
        mass = density * volume
        a, b, c = size
        inertia = mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        return cls(core, np.array([0]), np.array([8]), float(rounding), mass, inertia, volume, name=name)


def shrink_convex(points: np.ndarray, rounding: float) -> np.ndarray:
    """Vertices of the convex hull of ``points`` with every face moved inwards by ``rounding``."""
    hull = ConvexHull(points)
    equations = hull.equations.copy()  # rows (n, c): n . x + c <= 0 inside
    equations[:, 3] += rounding
    centre = points[hull.vertices].mean(axis=0)
    depth = -(transform(equations[:, :3], centre[:, None])[:, 0] + equations[:, 3])
    if depth.min() <= 1e-9 * np.ptp(points, axis=0).max():
        raise PolyhedronError(
            f"rounding {rounding:.4g} m leaves no core: the piece is thinner than 2 r; use a smaller rounding"
        )
    core = HalfspaceIntersection(equations, centre).intersections
    scale = float(np.ptp(core, axis=0).max())
    keys = np.round(core / max(scale * 1e-9, 1e-15)).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    core = core[np.sort(first)]
    return core[ConvexHull(core).vertices] if len(core) > 3 else core


def face_loop_order(core: np.ndarray) -> np.ndarray:
    """Rows of ``core`` (a convex polytope's vertices) reordered so that its largest faces, in
    turn while their vertices are free, are runs of consecutive rows going round the face
    (counter-clockwise about its outward normal), the other vertices after them. A contact's
    feature lists its vertices in row order, so a whole face (a phone's top, 20 of its 40) comes as
    its outline, whose hull ``dem.convex._hull2`` takes without sorting. The same polytope: only
    the rows' order changes."""
    core = np.asarray(core, dtype=np.float64)
    if len(core) <= 3:
        return np.arange(len(core))
    try:
        hull = ConvexHull(core)
    except QhullError:  # flat: no faces
        return np.arange(len(core))
    scale = float(np.ptp(core, axis=0).max())
    keys = np.round(hull.equations / np.array([1e-9, 1e-9, 1e-9, 1e-9 * scale])).astype(np.int64)
    _, face = np.unique(keys, axis=0, return_inverse=True)
    face = np.ravel(face)
    faces = [np.unique(hull.simplices[face == f]) for f in range(face.max() + 1)]
    normals = [hull.equations[np.flatnonzero(face == f)[0], :3] for f in range(len(faces))]
    used = np.zeros(len(core), dtype=bool)
    order: list[int] = []
    for f in sorted(range(len(faces)), key=lambda f: (-len(faces[f]), f)):
        rows = faces[f]
        if len(rows) < 3 or used[rows].any():
            continue
        n = normals[f]
        e1 = core[rows[1]] - core[rows[0]]
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        rel = core[rows] - core[rows].mean(axis=0)
        angle = np.arctan2(rel @ e2, rel @ e1)
        order.extend(int(k) for k in rows[np.argsort(angle, kind="stable")])
        used[rows] = True
    order.extend(int(k) for k in np.flatnonzero(~used))
    return np.array(order)


def thinnest_dimension(points: np.ndarray) -> float:
    """Smallest extent of ``points`` along the principal axes of their hull's oriented box."""
    obb = trimesh.convex.convex_hull(points).bounding_box_oriented
    return float(np.min(obb.primitive.extents))


def convex_departure(mesh: trimesh.Trimesh, n_samples: int = 2000, seed: int = 1) -> float:
    """Largest distance from the surface of the mesh's convex hull to the mesh (m), sampled at
    ``n_samples`` points spread evenly over the hull: 0 for a convex mesh, else the depth of its
    deepest concavity (a camera's corner beside its lens barrel)."""
    points, _ = trimesh.sample.sample_surface_even(mesh.convex_hull, n_samples, seed=seed)
    _, distance, _ = trimesh.proximity.closest_point(mesh, points)
    return float(np.max(distance))


def convex_pieces(
    mesh: trimesh.Trimesh, max_pieces: int = 8, threshold: float = 0.05
) -> list[trimesh.Trimesh]:
    """The mesh itself if it is convex, or its hull within ``CONVEX_TOLERANCE`` of its size of
    it (``convex_departure``), else its approximate convex decomposition by CoACD (Wei, Liu,
    Wang & Luo, "Approximate convex decomposition for 3D meshes with collision-aware concavity
    and tree search", SIGGRAPH 2022): at most ``max_pieces`` pieces, each within ``threshold``
    (relative to the mesh size) of convex. Seconds per mesh: decompose once per kind and map the
    pieces to variants (``deform_polyhedron``)."""
    size = float(np.linalg.norm(mesh.extents))
    if mesh.is_convex or convex_departure(mesh) <= CONVEX_TOLERANCE * size:
        return [mesh]
    try:
        import coacd
    except ImportError as exc:
        raise PolyhedronError(
            "non-convex mesh: install coacd to decompose it, or give its convex pieces"
        ) from exc
    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        threshold=threshold,
        max_convex_hull=max_pieces,
    )
    if not parts:
        raise PolyhedronError("CoACD returned no convex pieces; check that the mesh is watertight")
    return [trimesh.Trimesh(vertices=v, faces=f) for v, f in parts]


def make_polyhedron(
    mesh: trimesh.Trimesh,
    *,
    mass: float | None = None,
    density: float | None = None,
    rounding: float | None = None,
    pieces: list[trimesh.Trimesh] | None = None,
    name: str = "",
    core_tolerance: float = CORE_TOLERANCE,
) -> Polyhedron:
    """The rounded polyhedron of a watertight mesh (metres), mass properties from the mesh.

    ``pieces`` (convex meshes in the mesh's coordinates) default to ``convex_pieces(mesh)``;
    ``rounding`` to ``ROUNDING_FRACTION`` of the thinnest piece's thinnest dimension;
    ``core_tolerance`` (a fraction of the rounding) bounds how far each simplified core departs
    from the full one (``simplify_core``); 0 keeps the full core (up to ``MAX_CORE_VERTICES``).
    """
    properties = mass_properties(mesh, mass=mass, density=density)
    pieces = convex_pieces(mesh) if pieces is None else pieces
    if not pieces:
        raise PolyhedronError("no convex pieces given")
    hulls = [np.asarray(trimesh.convex.convex_hull(np.asarray(p.vertices)).vertices) for p in pieces]
    if rounding is None:
        rounding = ROUNDING_FRACTION * min(thinnest_dimension(h) for h in hulls)
    if not rounding > 0:
        raise PolyhedronError(f"rounding must be a positive length in metres, got {rounding}")
    if not 0 <= core_tolerance < 1:
        raise PolyhedronError(f"core_tolerance is a fraction of the rounding in [0, 1), got {core_tolerance}")
    cores, starts, counts = [], [], []
    for hull in hulls:
        core = shrink_convex(hull, rounding)
        if core_tolerance > 0:
            core = core[simplify_core(core, core_tolerance * rounding)]
        elif len(core) > MAX_CORE_VERTICES:
            core = _simplify(core)
        core = core[face_loop_order(core)]
        starts.append(sum(counts))
        counts.append(len(core))
        cores.append(core)
    return _assemble(np.concatenate(cores), np.array(starts), np.array(counts), rounding, properties, name)


def _assemble(mesh_core, starts, counts, rounding, properties, name) -> Polyhedron:
    """A Polyhedron from cores in mesh coordinates and the mesh's mass properties: the cores are
    moved into the principal frame, mass and inertia are the mesh's own."""
    return Polyhedron(
        core=np.ascontiguousarray(transform(mesh_core - properties.com, properties.principal_axes)),
        piece_start=np.asarray(starts, dtype=np.int64),
        piece_count=np.asarray(counts, dtype=np.int64),
        rounding=float(rounding),
        **properties.body_fields(),
        name=name,
    )


def hull_distances(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Distance of each point to the convex hull of ``vertices`` (0 inside), m."""
    eye, origin = np.eye(3), np.zeros(3)
    points = np.ascontiguousarray(points, dtype=np.float64)
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    hull = place(0, len(vertices), eye, origin)
    return np.array(
        [gjk_distance(points, place(k, 1, eye, origin), vertices, hull)[0] for k in range(len(points))]
    )


def simplify_core(core: np.ndarray, tolerance: float) -> np.ndarray:
    """Rows of ``core`` (the vertices of a convex polytope), ascending, whose hull lies within
    ``tolerance`` (m) of the whole: greedy insertion. It starts from the vertices extreme along the
    eight diagonals (+-1, +-1, +-1) of the core's box and adds the vertex furthest from the kept
    hull until none is further than ``tolerance``. Vertices tied with the furthest (within 1e-9 of
    the core's size) are added together, and the start is symmetric, so a mirror-symmetric core
    stays symmetric (a phone's top and bottom faces keep the same outline). The kept hull is inside
    the core, so the distance of the core's furthest vertex from it is their Hausdorff distance.
    At most ``MAX_CORE_VERTICES`` are kept: where the tolerance needs more, the insertion stops
    before the group that would not fit, further than ``tolerance`` from the core."""
    core = np.asarray(core, dtype=np.float64)
    if len(core) <= 4:
        return np.arange(len(core))
    tie = 1e-9 * float(np.ptp(core, axis=0).max())
    centre = 0.5 * (core.min(axis=0) + core.max(axis=0))
    kept: set[int] = set()
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            for sz in (-1.0, 1.0):
                height = (core - centre) @ np.array([sx, sy, sz])
                kept.update(np.flatnonzero(height >= height.max() - tie).tolist())
    while len(kept) < min(len(core), MAX_CORE_VERTICES):
        rows = np.array(sorted(kept))
        distance = hull_distances(core, core[rows])
        distance[rows] = -1.0
        furthest = float(distance.max())
        if furthest <= tolerance:
            break
        ties = np.flatnonzero(distance >= furthest - tie)
        if len(kept) + len(ties) > MAX_CORE_VERTICES:
            break
        kept.update(int(k) for k in ties)
    return np.array(sorted(kept))


def _simplify(core: np.ndarray) -> np.ndarray:
    """At most MAX_CORE_VERTICES vertices: farthest-point sampling of the hull's vertices (keeps
    the extreme ones, so the core shrinks by at most the spacing's sagitta)."""
    chosen = [int(np.argmax(np.linalg.norm(core - core.mean(axis=0), axis=1)))]
    distance = np.linalg.norm(core - core[chosen[0]], axis=1)
    while len(chosen) < MAX_CORE_VERTICES:
        k = int(np.argmax(distance))
        chosen.append(k)
        distance = np.minimum(distance, np.linalg.norm(core - core[k], axis=1))
    return core[np.sort(chosen)]


def deform_polyhedron(
    poly: Polyhedron, matrix: np.ndarray, mesh: trimesh.Trimesh, *, mass: float, name: str = ""
) -> Polyhedron:
    """The polyhedron of ``mesh`` = ``matrix`` applied to the mesh ``poly`` was made from: cores
    map through ``matrix`` (still convex), the rounding scales by its smallest singular value;
    mass properties are the new mesh's."""
    matrix = np.asarray(matrix, dtype=np.float64)
    properties = mass_properties(mesh, mass=mass)
    mesh_core = transform(poly.com + transform(poly.core, poly.axes.T), matrix.T)
    rounding = poly.rounding * smallest_singular_value(matrix)
    return _assemble(mesh_core, poly.piece_start, poly.piece_count, rounding, properties, name)


def surface_gap(poly: Polyhedron, mesh: trimesh.Trimesh, n_samples: int = 4000, seed: int = 1):
    """(largest, mean) distance from points on the mesh surface to the rounded shape's surface, m:
    how far the shape departs from the mesh (compare ``dem.clumping.clump_fit``)."""
    from dem.convex import gjk_distance, place

    points, _ = trimesh.sample.sample_surface_even(mesh, n_samples, seed=seed)
    local = np.ascontiguousarray(transform(np.asarray(points) - poly.com, poly.axes))
    eye, origin = np.eye(3), np.zeros(3)
    gaps = np.empty(len(local))
    for s in range(len(local)):
        nearest = min(
            gjk_distance(local, place(s, 1, eye, origin), poly.core, place(start, count, eye, origin))[0]
            for start, count in zip(poly.piece_start, poly.piece_count, strict=True)
        )
        gaps[s] = abs(nearest - poly.rounding)
    return float(gaps.max()), float(gaps.mean())
