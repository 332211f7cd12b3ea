"""State of the rigid bodies and of their spheres, as structure-of-arrays containers.

``Bodies`` holds one row per body (pose, momenta, mass properties, contact size); ``Spheres`` one
row per sphere, stored contiguously body after body, so that a body's spheres are
``sphere_start[b] : sphere_start[b] + sphere_count[b]``. The angular state is the world-frame
angular momentum ``angmom``; ``omega`` (world frame) is derived from it and kept current by the
kernels. Arrays grow by reallocation when bodies are added between runs; the kernels never
allocate. This module does no physics.
"""

from __future__ import annotations

import numpy as np

from dem.clump import Clump


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
    }
    _DTYPES = {"sphere_start": np.int64, "sphere_count": np.int64, "active": np.bool_, "clump_type": np.int64}

    def __init__(self) -> None:
        self.n = 0
        for name, shape in self._FIELDS.items():
            setattr(self, "_" + name, np.zeros((0, *shape), dtype=self._DTYPES.get(name, np.float64)))

    def __getattr__(self, name: str):
        if name in Bodies._FIELDS:
            return self.__dict__["_" + name][: self.n]
        raise AttributeError(name)

    def raw(self, name: str) -> np.ndarray:
        """The full (capacity-sized) array, for the kernels."""
        return self.__dict__["_" + name]

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


class Spheres:
    """Per-sphere arrays: owning body, radius, body-frame offset, world position."""

    def __init__(self) -> None:
        self.n = 0
        self._body = np.zeros(0, dtype=np.int64)
        self._radius = np.zeros(0)
        self._offset = np.zeros((0, 3))
        self._x = np.zeros((0, 3))

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

    def append(self, body: int, clump: Clump, x: np.ndarray) -> int:
        k = clump.n_spheres
        if self.n + k > len(self._radius):
            capacity = max(64, 2 * (self.n + k))
            for name in ("_body", "_radius", "_offset", "_x"):
                old = getattr(self, name)
                new = np.zeros((capacity, *old.shape[1:]), dtype=old.dtype)
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
        start = self.n
        self._body[start : start + k] = body
        self._radius[start : start + k] = clump.radius
        self._offset[start : start + k] = clump.offset
        self._x[start : start + k] = x
        self.n += k
        return start
