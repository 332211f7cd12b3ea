"""Unit quaternions (w, x, y, z) rotating body-frame vectors into the world frame, and the
free-rigid-body rotation step used by the integrator.

The rotation step is the symplectic splitting of the free rotor (Dullweber, Leimkuhler &
McLachlan, J. Chem. Phys. 107 (1997) 5840): the body turns exactly about each principal axis in
turn, 1 (h/2), 2 (h/2), 3 (h), 2 (h/2), 1 (h/2). The world-frame angular momentum is the state,
so it is conserved to rounding when no torque acts, and the energy error stays bounded (no drift).
Kernels only: nothing here knows about bodies, contacts or walls.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from dem.conf import JIT_FLAGS


@numba.njit(**JIT_FLAGS)
def half_angle_sin_cos(angle):
    """(sin(angle/2), cos(angle/2)); Taylor series for small angles, where most steps are, because
    it is exact to rounding there and several times cheaper than the libm calls."""
    x = 0.5 * angle
    if abs(x) < 1e-2:
        x2 = x * x
        s = x * (1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0)))
        c = 1.0 - x2 / 2.0 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0 * (1.0 - x2 / 56.0)))
        return s, c
    return math.sin(x), math.cos(x)


@numba.njit(**JIT_FLAGS)
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


@numba.njit(**JIT_FLAGS)
def free_rotor_step(q, lb, inertia, h):
    """Advance orientation q by h with body-frame angular momentum lb (both updated in place)."""
    if inertia[0] == inertia[1] and inertia[1] == inertia[2]:
        # Isotropic body: the exact solution is one turn about L.
        wx = lb[0] / inertia[0]
        wy = lb[1] / inertia[0]
        wz = lb[2] / inertia[0]
        rate = math.sqrt(wx * wx + wy * wy + wz * wz)
        if rate == 0.0:
            return
        s, c = half_angle_sin_cos(rate * h)
        ax, ay, az = wx / rate * s, wy / rate * s, wz / rate * s
        w, x, y, z = q[0], q[1], q[2], q[3]
        q[0] = w * c - x * ax - y * ay - z * az
        q[1] = w * ax + x * c + y * az - z * ay
        q[2] = w * ay - x * az + y * c + z * ax
        q[3] = w * az + x * ay - y * ax + z * c
    else:
        _turn_about_body_axis(q, lb, 0, 0.5 * h * lb[0] / inertia[0])
        _turn_about_body_axis(q, lb, 1, 0.5 * h * lb[1] / inertia[1])
        _turn_about_body_axis(q, lb, 2, h * lb[2] / inertia[2])
        _turn_about_body_axis(q, lb, 1, 0.5 * h * lb[1] / inertia[1])
        _turn_about_body_axis(q, lb, 0, 0.5 * h * lb[0] / inertia[0])
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    q[0] /= norm
    q[1] /= norm
    q[2] /= norm
    q[3] /= norm


def matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion (numpy convenience for drivers and tests)."""
    out = np.empty((3, 3))
    to_matrix(np.asarray(q, dtype=np.float64) / np.linalg.norm(q), out)
    return out


def from_axis_angle(axis, angle: float) -> np.ndarray:
    """Quaternion turning by ``angle`` (rad) about ``axis``."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
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
