"""Principal axes and changes of frame of bodies, computed in our own arithmetic so that their last
bit is the same on every machine.

numpy hands ``@``, ``np.linalg.eigh``, ``svd`` and ``det`` to OpenBLAS / LAPACK, and OpenBLAS
picks its kernels by CPU (or by ``OPENBLAS_CORETYPE``): with fused multiply-adds on one machine and
without on another, a clump's sphere offsets or principal axes differ by 1e-17, and the feeder,
being chaotic, then gives other trials. Here every product is a fixed sequence of numpy
element-wise multiplications and additions (each correctly rounded, in a fixed order, whatever the
SIMD width), and the 3 x 3 symmetric eigen-decomposition is a cyclic Jacobi iteration in Python
floats (Golub & Van Loan, Matrix Computations, 4th ed., section 8.5; the rotation in the form of
Numerical Recipes' ``jacobi``, section 11.1). Nothing here calls BLAS or LAPACK.

This module must stay small and exact-by-construction: no numba (its kernels are compiled for
the host CPU), no ``np.dot`` / ``@`` / ``np.linalg`` / ``einsum``.
"""

from __future__ import annotations

import math

import numpy as np

_MAX_SWEEPS = 50
_OFF_DIAGONAL = ((0, 1), (0, 2), (1, 2))


def transform(points, matrix) -> np.ndarray:
    """``points @ matrix`` for points (..., k) and a (k, m) matrix, summed in the order of k."""
    points = np.asarray(points, dtype=np.float64)
    matrix = np.asarray(matrix, dtype=np.float64)
    total = points[..., 0, None] * matrix[0]
    for k in range(1, matrix.shape[0]):
        total = total + points[..., k, None] * matrix[k]
    return total


def _rotate(a, v, p: int, q: int) -> None:
    """One Jacobi rotation zeroing a[p][q] (a symmetric, lists of floats), accumulated into v."""
    apq = a[p][q]
    theta = 0.5 * (a[q][q] - a[p][p]) / apq
    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
    if theta < 0.0:
        t = -t
    c = 1.0 / math.sqrt(t * t + 1.0)
    s = t * c
    tau = s / (1.0 + c)
    a[p][p] -= t * apq
    a[q][q] += t * apq
    a[p][q] = a[q][p] = 0.0
    r = 3 - p - q  # the third index
    arp, arq = a[r][p], a[r][q]
    a[r][p] = a[p][r] = arp - s * (arq + tau * arp)
    a[r][q] = a[q][r] = arq + s * (arp - tau * arq)
    for k in range(3):
        vkp, vkq = v[k][p], v[k][q]
        v[k][p] = vkp - s * (vkq + tau * vkp)
        v[k][q] = vkq + s * (vkp - tau * vkq)


def symmetric_eigen(matrix) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and orthonormal eigenvectors (columns) of a symmetric 3 x 3 matrix.

    Cyclic Jacobi: rotations zero each off-diagonal element in turn until all are exactly zero (an
    element too small to change either diagonal element it couples is set to zero, as in Numerical
    Recipes), which takes a handful of sweeps. Repeated eigenvalues need no care: a diagonal
    matrix is returned as it is (identity vectors), and any orthonormal basis of a repeated
    eigenvalue's space is an answer. Each vector's largest component (the first of equal ones) is
    made positive, so the result does not depend on the signs the iteration happened to produce.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"a finite 3 x 3 matrix is needed (got shape {m.shape})")
    a = [[0.5 * (float(m[i, j]) + float(m[j, i])) for j in range(3)] for i in range(3)]
    v = [[1.0 if i == j else 0.0 for j in range(3)] for i in range(3)]
    for _ in range(_MAX_SWEEPS):
        if a[0][1] == 0.0 and a[0][2] == 0.0 and a[1][2] == 0.0:
            break
        for p, q in _OFF_DIAGONAL:
            g = 100.0 * abs(a[p][q])
            if abs(a[p][p]) + g == abs(a[p][p]) and abs(a[q][q]) + g == abs(a[q][q]):
                a[p][q] = a[q][p] = 0.0
            elif a[p][q] != 0.0:
                _rotate(a, v, p, q)
    order = sorted(range(3), key=lambda k: (a[k][k], k))
    values = np.array([a[k][k] for k in order])
    vectors = np.array([[v[i][k] for k in order] for i in range(3)])
    for k in range(3):
        column = vectors[:, k]
        if column[int(np.argmax(np.abs(column)))] < 0.0:
            vectors[:, k] = -column
    return values, vectors


def determinant(matrix) -> float:
    """det of a 3 x 3 matrix: the triple product of its columns, c0 . (c1 x c2)."""
    m = [[float(x) for x in row] for row in np.asarray(matrix, dtype=np.float64)]
    return (
        m[0][0] * (m[1][1] * m[2][2] - m[2][1] * m[1][2])
        - m[1][0] * (m[0][1] * m[2][2] - m[2][1] * m[0][2])
        + m[2][0] * (m[0][1] * m[1][2] - m[1][1] * m[0][2])
    )


def principal_axes(inertia) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (ascending) and axes (columns, a right-handed rotation) of an inertia
    tensor."""
    moments, axes = symmetric_eigen(inertia)
    if determinant(axes) < 0.0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes


def smallest_singular_value(matrix) -> float:
    """The smallest singular value of a 3 x 3 matrix: the root of the smallest eigenvalue of
    M^T M (ample for the near-identity scalings items are deformed by)."""
    m = np.asarray(matrix, dtype=np.float64)
    values, _ = symmetric_eigen(transform(m.T, m))
    return math.sqrt(max(float(values[0]), 0.0))


def dot(a, b) -> float:
    """a . b of two vectors, summed in order (``a @ b`` calls BLAS ``dot``)."""
    total = 0.0
    xs, ys = np.asarray(a, dtype=np.float64).tolist(), np.asarray(b, dtype=np.float64).tolist()
    for x, y in zip(xs, ys, strict=True):
        total += x * y
    return total


def norm(vector) -> float:
    """Euclidean length of a vector, summed in order (``np.linalg.norm`` calls BLAS ``dot``)."""
    return math.sqrt(dot(vector, vector))
