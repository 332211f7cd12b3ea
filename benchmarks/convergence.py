"""Convergence of the feeder's N_t with the items' shape resolution (issue 12).

Runs the paper's full protocol (``examples/feeder.toml``: 30 items, 65 s, ``stop_when_empty``)
for every seed, parameter set and clump resolution, interleaved (seed outermost) so that a run cut
short still has a sample in every cell, and prints one line per run plus a summary table:

    NUMBA_NUM_THREADS=1 nice -n 10 python benchmarks/convergence.py \
        [--seeds 10] [--first-seed 0] [--resolutions 12 24 48] [--sets empties clogs] [--polyhedra]

``--first-seed 5 --seeds 5`` runs seeds 5-9 only, to add seeds to columns run before (the seed
fixes the item set, positions and orientations, so seed k is the same sample whichever run draws
it). ``--polyhedra`` adds a column of rounded-polyhedral items (resolution "poly");
``--resolutions`` with no value leaves the clumps out.

Parameter sets: ``empties`` (E 1e7, e 0.5, mu 0.5: the tray empties at 12 spheres) and ``clogs``
(E 1e7, e 0.2, mu 0.9: items stay behind at 12 spheres).
"""

from __future__ import annotations

import argparse
import statistics
import time

from dem.scenarios.feeder import run_feeder
from dem.scenarios.feeder_config import load_feeder_config

SETS = {
    "empties": {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5},
    "clogs": {"E": 1e7, "nu": 0.3, "e": 0.2, "mu": 0.9},
}


def run_order(first_seed: int, seeds: int, sets: list[str], shapes: list[str]) -> list[tuple[int, str, str]]:
    """(seed, set, shape) in the order they run: seed outermost, so every cell fills evenly."""
    return [
        (seed, name, shape)
        for seed in range(first_seed, first_seed + seeds)
        for name in sets
        for shape in shapes
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="examples/feeder.toml")
    parser.add_argument("--seeds", type=int, default=10, help="how many seeds")
    parser.add_argument("--first-seed", type=int, default=0, help="the first seed run")
    parser.add_argument("--resolutions", type=int, nargs="*", default=[12, 24, 48])
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    parser.add_argument("--polyhedra", action="store_true", help="a rounded-polyhedron column too")
    args = parser.parse_args()
    base = load_feeder_config(args.config)
    shapes = [(str(r), {"representation": "clump", "resolution": r}) for r in args.resolutions]
    if args.polyhedra:
        shapes.append(("poly", {"representation": "polyhedron"}))
    results: dict[tuple[str, str], list[int]] = {}  # N_t of the runs that ended ok
    failed: dict[tuple[str, str], list[str]] = {}  # the others' statuses: never an N_t value
    items_of = dict(shapes)
    for seed, name, resolution in run_order(args.first_seed, args.seeds, args.sets, list(items_of)):
        items = items_of[resolution]
        config = base.model_copy(update={"items": base.items.model_copy(update=items)})
        started = time.perf_counter()
        r = run_feeder(config, SETS[name], seed)
        results.setdefault((name, resolution), [])
        if r.ok:
            results[(name, resolution)].append(r.n_remaining)
        else:
            failed.setdefault((name, resolution), []).append(r.status.value)
        print(
            f"{name} res {resolution:>4} seed {seed}: N_t = {r.n_remaining}/{r.n_items}, "
            f"{r.status.value}, t_end {r.sim_time:.1f} s, "
            f"{time.perf_counter() - started:.0f} s wall",
            flush=True,
        )
    print("| set | resolution | runs ok | N_t values | mean | sd | not measured |")
    print("|---|---|---|---|---|---|---|")
    for (name, resolution), values in sorted(results.items()):
        mean = statistics.mean(values) if values else float("nan")
        sd = statistics.stdev(values) if len(values) > 1 else float("nan")
        others = ", ".join(failed.get((name, resolution), [])) or "-"
        print(f"| {name} | {resolution} | {len(values)} | {values} | {mean:.1f} | {sd:.1f} | {others} |")


if __name__ == "__main__":
    main()
