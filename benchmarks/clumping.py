"""How long clump generation takes: a phone box, a 10k-face scan-like mesh, and the 30-item
default feeder set (cold, then from the cache). Prints seconds, sphere counts and errors.

Run: ``python benchmarks/clumping.py``. The JIT compile of the distance kernel is paid before
timing starts.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np
import trimesh

from dem.clumping import make_clump, signed_distance
from dem.scenarios.items import default_items


def _timed(label, function):
    start = time.perf_counter()
    result = function()
    print(f"{label:<48s} {time.perf_counter() - start:6.2f} s")
    return result


def main() -> None:
    signed_distance(trimesh.creation.box((1, 1, 1)), np.zeros((1, 3)))
    phone = trimesh.creation.box((0.146, 0.071, 0.008))
    for n in (12, 24, 40):
        clump = _timed(
            f"phone box, {n} spheres", lambda n=n: make_clump(phone, mass=0.17, n_spheres=n, cache_dir=False)
        )
        print(f"    max error {clump.max_error * 1e3:.2f} mm")
    rng = np.random.default_rng(0)
    scan = trimesh.creation.icosphere(subdivisions=5, radius=0.04)
    scan.vertices *= [1.6, 1.0, 0.5]
    scan.vertices += rng.normal(0.0, 2e-4, scan.vertices.shape)
    print(f"scan-like ellipsoid: {len(scan.faces)} faces")
    clump = _timed(
        "scan-like mesh, 24 spheres", lambda: make_clump(scan, mass=0.15, n_spheres=24, cache_dir=False)
    )
    print(f"    max error {clump.max_error * 1e3:.2f} mm")
    with tempfile.TemporaryDirectory() as cache:
        for label in ("30 default items, resolution 24, cold", "30 default items, resolution 24, cached"):
            items = _timed(
                label, lambda: default_items(np.random.default_rng(1), resolution=24, cache_dir=cache)
            )
        for kind in ("smartphone", "feature_phone", "camera"):
            errors = [item.shape.max_error * 1e3 for item in items if item.kind == kind]
            print(f"    {kind:<14s} spheres {items[[i.kind for i in items].index(kind)].shape.n_spheres}, "
                  f"max error {min(errors):.1f}-{max(errors):.1f} mm")


if __name__ == "__main__":
    main()
