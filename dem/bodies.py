"""State of the rigid bodies and of their spheres, as structure-of-arrays containers.

``Bodies`` holds one row per body (pose, momenta, mass properties, contact size); ``Spheres`` one
row per sphere, stored contiguously body after body, so that a body's spheres are
``sphere_start[b] : sphere_start[b] + sphere_count[b]``. The angular state is the world-frame
angular momentum ``angmom``; ``omega`` (world frame) is derived from it and kept current by the
kernels. Arrays grow by reallocation when bodies are added between runs; the kernels never
allocate. ``arrays()`` hands the kernels the rows in use as a ``BodyArrays`` / ``SphereArrays``
named tuple (numba passes one as cheaply as its arrays). This module does no physics.

A rounded polyhedron (``dem/polyhedra.py``) takes one sphere row per convex piece: the piece's
bounding sphere (``radius`` its reach, ``offset`` its centre) serves the neighbour search, and
``core_start``/``core_count`` point at the piece's core vertices in ``core`` (body frame), with
``rounding`` its r, and ``half`` the half sizes of the core's box about ``offset`` (body axes), a
tighter bound than the sphere for the contact kernels' rejections. A clump's spheres have
``core_count`` 0, ``rounding`` = ``radius`` and ``half`` 0. Every row has its ``reach``: how far
its material points lie from the body's centre (a piece's farthest core vertex plus r, a sphere's
offset plus radius), which bounds how far they move as the body turns (``dem/kept_contact.py``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dem.clump import Clump
from dem.convex import scratch
from dem.frames import transform
from dem.polyhedra import Polyhedron


class BodyArrays(NamedTuple):
    """What the kernels read and write of the bodies (rows in use only)."""

    pos: np.ndarray  # (n, 3) centre of mass, m
    vel: np.ndarray  # (n, 3)
    quat: np.ndarray  # (n, 4) orientation, body to world
    angmom: np.ndarray  # (n, 3) world-frame angular momentum
    omega: np.ndarray  # (n, 3) world-frame angular velocity, derived from angmom
    rot: np.ndarray  # (n, 3, 3) rotation matrix of quat
    force: np.ndarray  # (n, 3)
    torque: np.ndarray  # (n, 3)
    mass: np.ndarray  # (n,)
    inertia: np.ndarray  # (n, 3) principal moments
    diameter: np.ndarray  # (n,) contact diameter of the contact law
    active: np.ndarray  # (n,) bool
    material: np.ndarray  # (n,) int64 index into the simulation's MaterialTable


class SphereArrays(NamedTuple):
    """What the kernels read and write of the spheres (rows in use only)."""

    body: np.ndarray  # (n,) owning body
    radius: np.ndarray  # (n,)
    offset: np.ndarray  # (n, 3) centre in the body frame
    x: np.ndarray  # (n, 3) world centre, written by the kernels
    rounding: np.ndarray  # (n,) r of a polyhedron piece; a sphere's radius
    core_start: np.ndarray  # (n,) int64 first core vertex of a piece
    core_count: np.ndarray  # (n,) int64 its number of core vertices; 0 for a clump's sphere
    crown: np.ndarray  # (n, 3) a piece's crown (dem.polyhedra.Polyhedron.crown); 0 for a sphere
    half: np.ndarray  # (n, 3) half sizes of a piece's core box about offset, body axes; 0 for a sphere
    reach: np.ndarray  # (n,) farthest material point of the row from its body's centre
    core: np.ndarray  # (m, 3) every piece's core vertices, body frame
    eye: np.ndarray  # (3, 3) identity: the rotation of points given in world coordinates
    zero: np.ndarray  # (3,)
    work: np.ndarray  # scratch of the contact patch (dem.convex.scratch)


class Bodies:
    """Per-body arrays; ``n`` rows are in use, ``active`` is False once a body is removed."""

    _FIELDS = {
        "pos": (3,),
        "quat": (4,),
        "vel": (3,),
        "angmom": (3,),
        "omega": (3,),
        "force": (3,),
        "torque": (3,),
        "rot": (3, 3),
        "mass": (),
        "inertia": (3,),
        "diameter": (),
        "sphere_start": (),
        "sphere_count": (),
        "active": (),
        "clump_type": (),
        "material": (),
    }
    _DTYPES = {
        "sphere_start": np.int64,
        "sphere_count": np.int64,
        "active": np.bool_,
        "clump_type": np.int64,
        "material": np.int64,
    }

    def __init__(self) -> None:
        self.n = 0
        for name, shape in self._FIELDS.items():
            setattr(self, "_" + name, np.zeros((0, *shape), dtype=self._DTYPES.get(name, np.float64)))

    def __getattr__(self, name: str):
        if name in Bodies._FIELDS:
            return self.__dict__["_" + name][: self.n]
        raise AttributeError(name)

    def arrays(self) -> BodyArrays:
        """Views of the rows in use, for the kernels."""
        return BodyArrays(*(self.__dict__["_" + name][: self.n] for name in BodyArrays._fields))

    def append(self, **values) -> int:
        if self.n == len(self._pos):
            capacity = max(16, 2 * self.n)
            for name in self._FIELDS:
                old = self.__dict__["_" + name]
                new = np.zeros((capacity, *old.shape[1:]), dtype=old.dtype)
                new[: self.n] = old[: self.n]
                self.__dict__["_" + name] = new
        i = self.n
        for name, value in values.items():
            self.__dict__["_" + name][i] = value
        self.n += 1
        return i


def sphere_rows(shape: Clump | Polyhedron):
    """(radius, offset, rounding, core_start, core_count, crown, half, reach) of a shape's sphere
    rows; core_start is relative to the shape's own ``core``."""
    if isinstance(shape, Polyhedron):
        n = shape.n_pieces
        pieces = [shape.piece(k) for k in range(n)]
        return (
            np.array([shape.piece_reach(k) for k in range(n)]),
            np.array([shape.piece_centre(k) for k in range(n)]),
            np.full(n, shape.rounding),
            np.asarray(shape.piece_start, dtype=np.int64),
            np.asarray(shape.piece_count, dtype=np.int64),
            np.array([shape.crown(k) for k in range(n)]).reshape(n, 3),
            np.array([0.5 * (core.max(axis=0) - core.min(axis=0)) for core in pieces]).reshape(n, 3),
            np.array([shape.core_reach(k) + shape.rounding for k in range(n)]),
        )
    n = shape.n_spheres
    radius = np.asarray(shape.radius, dtype=np.float64)
    offset = np.asarray(shape.offset, dtype=np.float64)
    zero = np.zeros(n, np.int64)
    reach = np.sqrt(np.sum(offset**2, axis=1)) + radius
    return radius, offset, radius, zero, zero, np.zeros((n, 3)), np.zeros((n, 3)), reach


class Spheres:
    """Per-sphere arrays: owning body, radius, body-frame offset, world position, and for the
    pieces of rounded polyhedra their rounding and core vertices."""

    _ARRAYS = (
        "_body",
        "_radius",
        "_offset",
        "_x",
        "_rounding",
        "_core_start",
        "_core_count",
        "_crown",
        "_half",
        "_reach",
    )

    def __init__(self) -> None:
        self.n = 0
        self._body = np.zeros(0, dtype=np.int64)
        self._radius = np.zeros(0)
        self._offset = np.zeros((0, 3))
        self._x = np.zeros((0, 3))
        self._rounding = np.zeros(0)
        self._core_start = np.zeros(0, dtype=np.int64)
        self._core_count = np.zeros(0, dtype=np.int64)
        self._crown = np.zeros((0, 3))
        self._half = np.zeros((0, 3))
        self._reach = np.zeros(0)
        self._core = np.zeros((1, 3))  # one dummy row: never empty
        self._n_core = 0
        self._eye, self._zero, self._work = np.eye(3), np.zeros(3), scratch()

    @property
    def body(self) -> np.ndarray:
        return self._body[: self.n]

    @property
    def radius(self) -> np.ndarray:
        return self._radius[: self.n]

    @property
    def offset(self) -> np.ndarray:
        return self._offset[: self.n]

    @property
    def x(self) -> np.ndarray:
        return self._x[: self.n]

    @property
    def rounding(self) -> np.ndarray:
        return self._rounding[: self.n]

    @property
    def core_count(self) -> np.ndarray:
        return self._core_count[: self.n]

    def arrays(self) -> SphereArrays:
        """Views of the rows in use, for the kernels."""
        return SphereArrays(
            self.body,
            self.radius,
            self.offset,
            self.x,
            self.rounding,
            self._core_start[: self.n],
            self.core_count,
            self._crown[: self.n],
            self._half[: self.n],
            self._reach[: self.n],
            self._core,
            self._eye,
            self._zero,
            self._work,
        )

    def append(self, body: int, shape: Clump | Polyhedron, rot: np.ndarray, position: np.ndarray) -> int:
        radius, offset, rounding, core_start, core_count, crown, half, reach = sphere_rows(shape)
        k = len(radius)
        if self.n + k > len(self._radius):
            capacity = max(64, 2 * (self.n + k))
            for name in self._ARRAYS:
                old = getattr(self, name)
                new = np.zeros((capacity, *old.shape[1:]), dtype=old.dtype)
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
        start = self.n
        self._body[start : start + k] = body
        self._radius[start : start + k] = radius
        self._offset[start : start + k] = offset
        self._x[start : start + k] = position + transform(offset, rot.T)
        self._rounding[start : start + k] = rounding
        self._core_count[start : start + k] = core_count
        self._crown[start : start + k] = crown
        self._half[start : start + k] = half
        self._reach[start : start + k] = reach
        if isinstance(shape, Polyhedron):
            vertices = np.asarray(shape.core, dtype=np.float64)
            if self._n_core + len(vertices) > len(self._core):
                grown = np.zeros((max(256, 2 * (self._n_core + len(vertices))), 3))
                grown[: self._n_core] = self._core[: self._n_core]
                self._core = grown
            self._core[self._n_core : self._n_core + len(vertices)] = vertices
            self._core_start[start : start + k] = self._n_core + core_start
            self._n_core += len(vertices)
        self.n += k
        return start
