"""Unit quaternions (w, x, y, z) rotating body-frame vectors into the world frame, and the
free-rigid-body rotation step used by the integrator.

The rotation step is the symplectic splitting of the free rotor (Dullweber, Leimkuhler &
McLachlan, J. Chem. Phys. 107 (1997) 5840): the body turns exactly about each principal axis in
turn, 1 (h/2), 2 (h/2), 3 (h), 2 (h/2), 1 (h/2). The world-frame angular momentum is the state,
so it is conserved to rounding when no torque acts, and the energy error stays bounded (no drift).
A body with equal principal moments (a sphere) needs no splitting: it turns exactly about its
world-frame L by |L| h / I in one step (``isotropic_rotor_step``), which needs neither the
body-frame L nor a square root for the small angles of most steps.
Kernels only: nothing here knows about bodies, contacts or walls.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from dem.conf import JIT_FLAGS
from dem.frames import norm

# Below this half angle (rad) the Taylor series of sin and cos, to the terms kept, are exact to
# rounding; they are several times cheaper than the libm calls. Coefficients are multiplied, not
# divided: a division costs several multiplications' latency in this dependent chain.
_SERIES_HALF_ANGLE = 1e-2
_S3, _S5, _S7 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0
_C2, _C4, _C6, _C8 = -0.5, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0


@numba.njit(inline="always", **JIT_FLAGS)
def _sinc_cos_series(x2):
    """(sin(x) / x, cos(x)) for x * x = x2 < _SERIES_HALF_ANGLE**2."""
    return 1.0 + x2 * (_S3 + x2 * (_S5 + x2 * _S7)), 1.0 + x2 * (_C2 + x2 * (_C4 + x2 * (_C6 + x2 * _C8)))


@numba.njit(**JIT_FLAGS)
def half_angle_sin_cos(angle):
    """(sin(angle/2), cos(angle/2))."""
    x = 0.5 * angle
    if abs(x) < _SERIES_HALF_ANGLE:
        sinc, c = _sinc_cos_series(x * x)
        return x * sinc, c
    return math.sin(x), math.cos(x)


@numba.njit(inline="always", **JIT_FLAGS)
def _renormalise(q):
    """q / |q| for a q within rounding of unit length: one Newton step for 1 / sqrt(|q|^2) from 1
    (its error is of order (|q|^2 - 1)^2), no square root or division."""
    scale = 1.5 - 0.5 * (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    q[0] *= scale
    q[1] *= scale
    q[2] *= scale
    q[3] *= scale


@numba.njit(inline="always", **JIT_FLAGS)
def to_matrix(q, out):
    """Rotation matrix of the unit quaternion q into out (3, 3)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@numba.njit(**JIT_FLAGS)
def _turn_about_body_axis(q, lb, axis, angle):
    """Turn the body by ``angle`` about its own principal ``axis``: q <- q (x) exp(angle/2 e_axis),
    and the body-frame angular momentum turns the opposite way (the world vector is fixed)."""
    s, c = half_angle_sin_cos(angle)
    w, x, y, z = q[0], q[1], q[2], q[3]
    if axis == 0:
        q[0] = w * c - x * s
        q[1] = x * c + w * s
        q[2] = y * c + z * s
        q[3] = z * c - y * s
        i, j = 1, 2
    elif axis == 1:
        q[0] = w * c - y * s
        q[1] = x * c - z * s
        q[2] = y * c + w * s
        q[3] = z * c + x * s
        i, j = 2, 0
    else:
        q[0] = w * c - z * s
        q[1] = x * c + y * s
        q[2] = y * c - x * s
        q[3] = z * c + w * s
        i, j = 0, 1
    # cos(angle), sin(angle) from the half-angle values: no further libm call.
    ca = c * c - s * s
    sa = 2.0 * s * c
    li, lj = lb[i], lb[j]
    lb[i] = ca * li + sa * lj
    lb[j] = -sa * li + ca * lj


# The splitting's turns: (principal axis, fraction of the step).
_TURNS = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


@numba.njit(inline="always", **JIT_FLAGS)
def free_rotor_steps(quat, lb, inertia, rows, h):
    """Advance by h the orientations quat[b] of the rows b in ``rows`` with their body-frame angular
    momenta lb[b] and principal moments inertia[b] (quat and lb updated in place).

    Each turn is taken for every row before the next turn: a turn waits on the one before it (a
    division, the series, the turned L: about 70 cycles of latency, five times a step), and the
    rows' chains, side by side in the loop, overlap in the processor instead of following one
    another (``benchmarks/README.md``, engine speed session 12). A row's arithmetic is the same."""
    for axis, part in _TURNS:
        for b in rows:
            _turn_about_body_axis(quat[b], lb[b], axis, part * h * lb[b, axis] / inertia[b, axis])
    for b in rows:
        _renormalise(quat[b])


@numba.njit(inline="always", **JIT_FLAGS)
def isotropic_rotor_step(q, angmom, inertia, h):
    """Advance orientation q by h for a body with equal principal moments ``inertia`` and
    world-frame angular momentum ``angmom``: q <- exp(|L| h / (2 I) L / |L|) (x) q, exact."""
    lx, ly, lz = angmom[0], angmom[1], angmom[2]
    half = 0.5 * h / inertia  # half angle per unit |L|
    l2 = lx * lx + ly * ly + lz * lz
    if l2 == 0.0:
        return
    x2 = half * half * l2  # (half angle)^2
    if x2 < _SERIES_HALF_ANGLE * _SERIES_HALF_ANGLE:
        sinc, c = _sinc_cos_series(x2)
        s_per_l = half * sinc  # sin(half angle) / |L|
    else:
        length = math.sqrt(l2)
        s_per_l = math.sin(half * length) / length
        c = math.cos(half * length)
    ax, ay, az = lx * s_per_l, ly * s_per_l, lz * s_per_l
    w, x, y, z = q[0], q[1], q[2], q[3]
    q[0] = c * w - ax * x - ay * y - az * z
    q[1] = c * x + w * ax + ay * z - az * y
    q[2] = c * y + w * ay + az * x - ax * z
    q[3] = c * z + w * az + ax * y - ay * x
    _renormalise(q)


def matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion (numpy convenience for drivers and tests)."""
    out = np.empty((3, 3))
    to_matrix(np.asarray(q, dtype=np.float64) / norm(q), out)
    return out


def from_axis_angle(axis, angle: float) -> np.ndarray:
    """Quaternion turning by ``angle`` (rad) about ``axis``."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / norm(axis)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])


def matrices(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of n quaternions (n, 4), scalar first (numpy, for drivers and
    pictures: the same matrix as ``to_matrix``)."""
    q = np.asarray(quat, dtype=float)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )
