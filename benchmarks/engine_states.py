"""Final engine states of short reference runs, saved and compared bit for bit: the check that an
engine change meant to be exact (a speed-up) changes no result.

    NUMBA_NUM_THREADS=1 python -m benchmarks.engine_states save before.npz
    (change the engine; clear the numba cache of dem/)
    NUMBA_NUM_THREADS=1 python -m benchmarks.engine_states save after.npz
    python -m benchmarks.engine_states compare before.npz after.npz

The runs: the quick feeder (``examples/feeder-quick.toml``, seed 1, E = 1e7 Pa) to t = 3 s with
rounded polyhedra and with 12-sphere clumps (chaotic: any change at rounding level shows), and
1,024 settling spheres of ``benchmarks.dem_spheres`` for 5,000 steps. Saved per run: every body's
position, quaternion, velocity, angular momentum and omega, the time, cost, builds and contacts.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

FIELDS = ("pos", "quat", "vel", "angmom", "omega", "active")


def _state(prefix: str, sim) -> dict[str, np.ndarray]:
    out = {f"{prefix}.{k}": np.array(getattr(sim.bodies, k)) for k in FIELDS}
    out[f"{prefix}.scalars"] = np.array([sim.t, sim.cost, sim.n_builds, sim.n_contacts], dtype=float)
    return out


def save(path: str) -> None:
    from benchmarks.profile_engine import feeder_state, settling_state

    runs = {
        "feeder-polyhedron": lambda: feeder_state("polyhedron", 3.0),
        "feeder-clump": lambda: feeder_state("clump", 3.0),
        "settling-1k": lambda: settling_state(1000, 5000),
    }
    states: dict[str, np.ndarray] = {}
    for name, run in runs.items():
        cpu = time.process_time()
        states.update(_state(name, run()))
        print(f"{name}: {time.process_time() - cpu:.1f} s CPU (compilation included)", flush=True)
        np.savez(path, **states)  # after each run: a later failure keeps the earlier ones


def compare(a: str, b: str) -> bool:
    x, y = np.load(a), np.load(b)
    same = True
    for key in sorted(set(x.files) | set(y.files)):
        if key not in x.files or key not in y.files:
            print(f"{key}: only in one file")
            same = False
            continue
        u, v = x[key], y[key]
        if u.shape == v.shape and np.array_equal(u, v):
            continue
        same = False
        diff = np.max(np.abs(u.astype(float) - v.astype(float))) if u.shape == v.shape else float("nan")
        print(f"{key}: differs (largest difference {diff:.3g})")
    print("bit-identical" if same else "NOT bit-identical")
    return same


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("save").add_argument("path")
    cmp = sub.add_parser("compare")
    cmp.add_argument("a")
    cmp.add_argument("b")
    args = parser.parse_args()
    if args.command == "save":
        save(args.path)
    else:
        sys.exit(0 if compare(args.a, args.b) else 1)


if __name__ == "__main__":
    main()
