"""dem/frames.py: the principal frames of bodies in our own arithmetic, checked against LAPACK and
against the analytic frames of symmetric bodies; and a feeder run that is the same to the last
bit whichever OpenBLAS kernels the machine picks."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from dem.frames import determinant, principal_axes, smallest_singular_value, symmetric_eigen, transform
from dem.quaternion import from_axis_angle, matrix

ROOT = Path(__file__).resolve().parents[2]


def random_rotation(rng) -> np.ndarray:
    return matrix(from_axis_angle(rng.normal(size=3), rng.uniform(0.0, np.pi)))


def test_jacobi_eigen_decomposition_matches_lapack_to_1e_12():
    rng = np.random.default_rng(12)
    for _ in range(200):
        a = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-8, 2)
        a = a + a.T

        values, vectors = symmetric_eigen(a)
        lapack_values, lapack_vectors = np.linalg.eigh(a)

        scale = np.abs(lapack_values).max()
        assert np.abs(values - lapack_values).max() <= 1e-12 * scale
        # Distinct eigenvalues: the same vectors up to their sign.
        signs = np.sign(np.sum(vectors * lapack_vectors, axis=0))
        assert np.abs(vectors - lapack_vectors * signs).max() <= 1e-12 * scale / np.diff(lapack_values).min()
        assert np.abs(vectors.T @ vectors - np.eye(3)).max() <= 1e-14


def test_sphere_inertia_is_its_own_principal_frame():
    moment = 2.0 / 5.0 * 0.05 * 0.01**2  # solid sphere, 50 g, r = 10 mm

    values, axes = principal_axes(np.eye(3) * moment)

    assert values.tolist() == [moment] * 3
    assert axes.tolist() == np.eye(3).tolist()


def test_square_rod_principal_axis_is_the_rod_axis_and_its_cross_section_any_orthonormal_pair():
    # A rod of square section a x a and length l: I_axis = m a^2 / 6, I_cross = m (a^2 + l^2) / 12
    # twice (a repeated eigenvalue), turned to an arbitrary orientation.
    m, a, length = 0.2, 0.01, 0.1
    cross = m * (a * a + length * length) / 12.0
    own = np.diag([m * a * a / 6.0, cross, cross])
    rng = np.random.default_rng(3)
    for _ in range(20):
        rotation = random_rotation(rng)
        inertia = rotation @ own @ rotation.T

        values, axes = principal_axes(inertia)

        assert values == pytest.approx(np.sort(np.diag(own)), rel=1e-12)
        assert abs(abs(axes[:, 0] @ rotation[:, 0]) - 1.0) <= 1e-12
        assert np.abs(axes.T @ axes - np.eye(3)).max() <= 1e-14
        assert determinant(axes) == pytest.approx(1.0, abs=1e-14)
        assert np.abs(axes @ np.diag(values) @ axes.T - inertia).max() <= 1e-12 * values.max()


def test_transform_and_singular_value_match_numpy():
    rng = np.random.default_rng(5)
    points, m = rng.normal(size=(50, 3)), rng.normal(size=(3, 3))

    bound = 3e-14 * np.abs(points).max() * np.abs(m).max()
    assert np.abs(transform(points, m) - points @ m).max() <= bound
    assert smallest_singular_value(m) == pytest.approx(np.linalg.svd(m, compute_uv=False).min(), rel=1e-10)
    assert determinant(m) == pytest.approx(np.linalg.det(m), rel=1e-12)


_FEEDER_STATE = textwrap.dedent(
    """
    import hashlib, sys, tempfile, time, os
    os.environ["DEMCAL_DATA_DIR"] = tempfile.mkdtemp()  # clumps built here, not read from a cache
    import numpy as np
    from dem.scenarios.feeder import _FeederRun
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config("examples/feeder-quick.toml")
    config.stages.vibration_start = 0.6
    config.stages.vibration_time = 0.05
    run = _FeederRun(config, {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}, 0, None)
    run.execute(time.monotonic(), None, None, None)
    shapes = [getattr(item.shape, k) for item in run.items for k in ("offset", "radius", "axes", "inertia")]
    b = run.sim.bodies
    arrays = [*shapes, run.tray.vertices, np.array([run.sim.dt]), b.pos, b.quat, b.vel, b.omega]
    data = b"".join(np.ascontiguousarray(a, dtype=float).tobytes() for a in arrays)
    print(hashlib.sha256(data).hexdigest())
    """
)


def test_feeder_run_is_bit_identical_whatever_openblas_kernels():
    # Prescott's kernels have no fused multiply-add, Haswell's have: numpy's @, norm and eigh
    # differ in the last bit between them, and so did every clump's offsets.
    digests = {}
    for core in ("Prescott", "Haswell"):
        env = {**os.environ, "OPENBLAS_CORETYPE": core, "NUMBA_NUM_THREADS": "1"}
        command = [sys.executable, "-c", _FEEDER_STATE]
        done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
        assert done.returncode == 0, done.stderr
        digests[core] = done.stdout.strip()

    assert digests["Prescott"] == digests["Haswell"]
