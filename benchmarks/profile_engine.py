"""Where a step of the numba engine goes: each stage's kernel timed alone on a state taken from a
run, and for rounded polyhedra the contact geometry split into its parts (broad-phase rejection,
GJK, the crowned contact, the patch's second moments).

    NUMBA_NUM_THREADS=1 python -m benchmarks.profile_engine [--case feeder-polyhedron feeder-clump
        settling-1k settling-10k] [--time 3.0] [--repeats 30] [--config examples/feeder.toml]
        [--clogging]

Each figure is the least CPU time (``time.process_time``) of ``--repeats`` timings of one call,
per step: on a shared machine the least is the figure least disturbed by the others' load.
``compute_forces`` is called with ``hist_dt = 0`` (forces re-evaluated without advancing the
springs), so the state does not move between repeats; it also serves no contact from its kept
row (``dem/kept_contact.py`` keeps none on a step of 0), so every figure is the full
geometry's. The piece pairs that touch are also timed in the order a step takes them (GJK warm
from the pair's simplex, the crown's feature hulls, the rest of the crowned contact, the patch's
moments), each row adding one stage. Not a test: timings depend on the machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from functools import partial
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numba  # noqa: E402
import numpy as np  # noqa: E402

from dem.conf import JIT_FLAGS  # noqa: E402
from dem.convex import feature_hulls, gjk_distance, gjk_query, gjk_scratch, patch_moments, place  # noqa: E402
from dem.crown import crowned_contact  # noqa: E402
from dem.forces import _row, _sphere_pair_forces, _wall_forces, compute_forces  # noqa: E402
from dem.integrate import drift, kick, live_rows, update_omega, update_spheres  # noqa: E402
from dem.neighbours import N_PAIRS, rebuild_lists  # noqa: E402
from dem.rounded_contact import WallFacet, facet_geometry, pair_geometry  # noqa: E402

FEEDER_CONFIG = "examples/feeder-quick.toml"


def feeder_state(
    representation: str, until: float, seed: int = 1, config_path: str = FEEDER_CONFIG, clogging: bool = False
):
    """The feeder's engine (the quick feeder unless ``config_path``; E = 1e7 Pa, and with
    ``clogging`` benchmarks.feeder's e 0.2, mu 0.9) run to ``until`` seconds, or to the end of
    the deposition (the vibration's start, 5 s in both configs) if ``until`` comes before it: the
    insertion and deposition always run whole."""
    from dem.scenarios.base import merged_params
    from dem.scenarios.feeder import _FeederRun
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config(config_path)
    config.items.representation = representation
    config.stages.vibration_time = max(0.0, until - config.stages.vibration_start)
    config.run.stop_when_empty = False
    from benchmarks.feeder import CLOGGING

    params, problem = merged_params(config.params, {"E": 1e7, **(CLOGGING if clogging else {})})
    assert not problem, problem
    run = _FeederRun(config, params, seed, None)
    run.execute(time.monotonic(), None, None, None)
    return run.sim


def settling_state(n: int, steps: int):
    """``benchmarks.dem_spheres``' settling case of about n spheres after ``steps`` steps."""
    sys.path.insert(0, str(Path(__file__).parent))  # dem_spheres imports the liggghts module beside it
    from benchmarks.dem_spheres import build

    sim = build(n)
    sim.run(steps * sim.dt)
    return sim


@numba.njit(**JIT_FLAGS)
def _rounded_pair_geometry(bodies, spheres, pairs, which):
    """The geometry of every listed pair with a rounded piece, without forces: ``which`` 0 the
    whole ``pair_geometry``, 1 GJK only, 2 GJK and the crowned contact (no patch)."""
    from_gjk = 0.0
    sbody, count, start = spheres.body, spheres.core_count, spheres.core_start
    for p in range(pairs.count[N_PAIRS]):
        i, j = pairs.i[p], pairs.j[p]
        if count[i] == 0 and count[j] == 0:
            continue
        dx = spheres.x[i, 0] - spheres.x[j, 0]
        dy = spheres.x[i, 1] - spheres.x[j, 1]
        dz = spheres.x[i, 2] - spheres.x[j, 2]
        rs = spheres.radius[i] + spheres.radius[j]
        if dx * dx + dy * dy + dz * dz >= rs * rs:
            continue
        ba, bb = sbody[i], sbody[j]
        if count[i] > 0:
            va, a = spheres.core, place(start[i], count[i], bodies.rot[ba], bodies.pos[ba])
        else:
            va, a = spheres.x, place(i, 1, spheres.eye, spheres.zero)
        if count[j] > 0:
            vb, b = spheres.core, place(start[j], count[j], bodies.rot[bb], bodies.pos[bb])
        else:
            vb, b = spheres.x, place(j, 1, spheres.eye, spheres.zero)
        ra, rb = spheres.rounding[i], spheres.rounding[j]
        if which == 0:
            axis, simplex = pairs.axis[p].copy(), pairs.simplex[p].copy()
            r = pair_geometry(
                va,
                a,
                ra,
                _row(spheres.crown, i),
                vb,
                b,
                rb,
                _row(spheres.crown, j),
                axis,
                simplex,
                spheres.work,
            )
            from_gjk += r[0]
            continue
        d, ax, ay, az, bx, by, bz = gjk_distance(va, a, vb, b)
        from_gjk += d
        if which == 2 and d > 0.0 and ra + rb - d > 0.0:
            tol = 4.0 * (spheres.crown[i, 2] + spheres.crown[j, 2])
            r = crowned_contact(
                va,
                a,
                _row(spheres.crown, i),
                vb,
                b,
                _row(spheres.crown, j),
                (ax, ay, az),
                (bx, by, bz),
                tol,
                spheres.work,
            )
            from_gjk += r[0]
    return from_gjk


@numba.njit(**JIT_FLAGS)
def _touching_piece_pairs(bodies, spheres, pairs):
    """The listed pairs of two pieces whose rounded surfaces overlap (``pair_geometry``), from a
    copy of each pair's axis and simplex."""
    touching = np.zeros(pairs.count[N_PAIRS], dtype=np.int64)
    n = 0
    count, start = spheres.core_count, spheres.core_start
    for p in range(pairs.count[N_PAIRS]):
        i, j = pairs.i[p], pairs.j[p]
        if count[i] == 0 or count[j] == 0:
            continue
        ba, bb = spheres.body[i], spheres.body[j]
        a = place(start[i], count[i], bodies.rot[ba], bodies.pos[ba])
        b = place(start[j], count[j], bodies.rot[bb], bodies.pos[bb])
        axis, simplex = pairs.axis[p].copy(), pairs.simplex[p].copy()
        r = pair_geometry(
            spheres.core,
            a,
            spheres.rounding[i],
            _row(spheres.crown, i),
            spheres.core,
            b,
            spheres.rounding[j],
            _row(spheres.crown, j),
            axis,
            simplex,
            spheres.work,
        )
        if r[0] > 0.0:
            touching[n] = p
            n += 1
    return touching[:n]


@numba.njit(**JIT_FLAGS)
def _touching_stages(bodies, spheres, pairs, touching, stages):
    """The touching piece pairs' geometry as a step takes it, up to ``stages``: 0 placing the
    cores and copying the pair's simplex, 1 + GJK warm from it, 2 + the crown's feature hulls, 3
    + the rest of the crowned contact (its hulls again), 4 + the patch's moments."""
    total = 0.0
    count, start, work = spheres.core_count, spheres.core_start, spheres.work
    for p in touching:
        i, j = pairs.i[p], pairs.j[p]
        ba, bb = spheres.body[i], spheres.body[j]
        a = place(start[i], count[i], bodies.rot[ba], bodies.pos[ba])
        b = place(start[j], count[j], bodies.rot[bb], bodies.pos[bb])
        simplex = pairs.simplex[p].copy()
        s, lam = gjk_scratch(work)
        total += simplex[0] + s[0, 0]
        if stages < 1:
            continue
        d, ax, ay, az, bx, by, bz = gjk_query(spheres.core, a, spheres.core, b, simplex, s, lam)
        total += d
        crown_a, crown_b = _row(spheres.crown, i), _row(spheres.crown, j)
        tol = 4.0 * (crown_a[2] + crown_b[2])
        if stages == 2:
            n = ((ax - bx) / d, (ay - by) / d, (az - bz) / d)
            total += feature_hulls(spheres.core, a, spheres.core, b, d, n, tol, work)[0]
        if stages < 3:
            continue
        r = crowned_contact(
            spheres.core, a, crown_a, spheres.core, b, crown_b, (ax, ay, az), (bx, by, bz), tol, work
        )
        total += r[0]
        if stages < 4:
            continue
        delta = spheres.rounding[i] + spheres.rounding[j] - r[0]
        total += patch_moments(
            spheres.core, a, spheres.core, b, (ax, ay, az), (bx, by, bz), delta, tol, work
        )[0]
    return total


@numba.njit(**JIT_FLAGS)
def _rounded_facet_geometry(bodies, spheres, walls, wall_pairs):
    """``facet_geometry`` of every listed piece-facet pair (no forces)."""
    facets = walls.facets
    tri_flat = facets.tri.reshape((-1, 3))
    total = 0.0
    for p in range(wall_pairs.count[N_PAIRS]):
        i, f = wall_pairs.i[p], wall_pairs.f[p]
        if spheres.core_count[i] == 0:
            continue
        b = spheres.body[i]
        w = facets.wall[f]
        core = place(spheres.core_start[i], spheres.core_count[i], bodies.rot[b], bodies.pos[b])
        facet = WallFacet(
            facets.tri_start[f],
            facets.tri_count[f],
            (walls.disp[w, 0], walls.disp[w, 1], walls.disp[w, 2]),
            (facets.normal[f, 0], facets.normal[f, 1], facets.normal[f, 2]),
            facets.offset[f],
        )
        r = facet_geometry(
            spheres.core, core, spheres.rounding[i], _row(spheres.crown, i), tri_flat, facet, spheres.work
        )
        total += r[0]
    return total


def _least(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def profile(sim, repeats: int) -> list[tuple[str, float]]:
    """(stage, least CPU seconds of one call) for the simulation's current state."""
    sim._prepare()
    bodies, spheres = sim.bodies.arrays(), sim.spheres.arrays()
    walls, lists, settings = sim._walls, sim._lists, sim._settings
    rebuild_lists(lists, spheres, bodies.active, walls, settings.skin, settings.cell_min)
    mat, grav, lim = settings.material, settings.gravity, settings.overlap_limit
    dt = sim.dt
    saved = {k: np.copy(getattr(bodies, k)) for k in ("pos", "quat", "vel", "angmom", "omega", "rot")}

    def restore():
        for k, v in saved.items():
            getattr(bodies, k)[...] = v

    lb = np.zeros((len(bodies.pos), 3))
    live, live_spheres, rotors = live_rows(bodies.active, spheres.body, bodies.inertia)
    rows = [
        ("compute_forces", lambda: compute_forces(bodies, spheres, mat, walls, lists, grav, lim, 0.0)),
        (
            "  sphere/piece pairs",
            lambda: _sphere_pair_forces(bodies, spheres, lists.pairs, lists.grid.moved2, lim, 0.0),
        ),
        (
            "  sphere/piece-facet pairs",
            lambda: _wall_forces(bodies, spheres, mat, walls, lists, lim, 0.0),
        ),
    ]
    if np.any(sim.spheres.arrays().core_count > 0):
        rows += [
            (
                "    pair_geometry (rounded pairs)",
                lambda: _rounded_pair_geometry(bodies, spheres, lists.pairs, 0),
            ),
            (
                "      GJK only, no cached-axis test",
                lambda: _rounded_pair_geometry(bodies, spheres, lists.pairs, 1),
            ),
            ("      same + crowned_contact", lambda: _rounded_pair_geometry(bodies, spheres, lists.pairs, 2)),
            (
                "    facet_geometry (piece-facet)",
                lambda: _rounded_facet_geometry(bodies, spheres, walls, lists.wall_pairs),
            ),
        ]
        touching = _touching_piece_pairs(bodies, spheres, lists.pairs)
        stages = ("cores placed", "+ GJK (warm)", "+ feature hulls", "+ rest of crown", "+ patch moments")
        rows += [
            (
                f"    {len(touching)} touching piece pairs: {name}",
                partial(_touching_stages, bodies, spheres, lists.pairs, touching, k),
            )
            for k, name in enumerate(stages)
        ]
    rows += [
        ("kick", lambda: kick(bodies, live, 0.5 * dt)),
        ("drift (restored after)", lambda: (drift(bodies, live, rotors, lb, dt), restore())),
        (
            "update_spheres + omega",
            lambda: (
                update_spheres(spheres, bodies, live_spheres, lists.grid),
                update_omega(bodies, live),
            ),
        ),
        (
            "list rebuild (per build)",
            lambda: rebuild_lists(lists, spheres, bodies.active, walls, settings.skin, settings.cell_min),
        ),
    ]
    for _, fn in rows:  # compile
        fn()
    return [(name, _least(fn, repeats)) for name, fn in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", nargs="+", default=["feeder-polyhedron", "feeder-clump"])
    parser.add_argument("--time", type=float, default=3.0, help="feeder: simulated time of the state, s")
    parser.add_argument("--steps", type=int, default=30_000, help="settling: steps before the state")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--config", default=FEEDER_CONFIG, help="feeder: its configuration")
    parser.add_argument("--clogging", action="store_true", help="feeder: e 0.2, mu 0.9")
    args = parser.parse_args()
    for case in args.case:
        if case.startswith("feeder-"):
            sim = feeder_state(case.removeprefix("feeder-"), args.time, 1, args.config, args.clogging)
        else:
            sim = settling_state(int(case.removeprefix("settling-").replace("k", "000")), args.steps)
        n_pairs = int(sim._lists.pairs.count[N_PAIRS])
        n_wall = int(sim._lists.wall_pairs.count[N_PAIRS])
        active = int(np.sum(sim.bodies.active[: sim.bodies.n]))
        print(
            f"{case}: t = {sim.t:.3f} s, {active} bodies, {sim.spheres.n} sphere rows, "
            f"{n_pairs} listed pairs, "
            f"{n_wall} listed wall pairs, {sim.n_contacts} contacts"
        )
        for name, seconds in profile(sim, args.repeats):
            print(f"  {name:<48} {1e6 * seconds:10.1f} us")


if __name__ == "__main__":
    main()
