"""Truth pilot for the full-feeder calibration benchmark: simulate one hidden parameter set on
the paper's feeder (``examples/feeder.toml``, 30 items) over the experiment's seeds and over
fresh seeds, and cache every result in a JSON file that ``benchmarks/calibration.py`` reads.

The experiment's seeds make the synthetic experiment (the ten "measured" N_t); the fresh seeds
give the truth's own W1 against it: the best any recommendation can be expected to do, since the
truth itself scatters that much from seed to seed. A truth is useful when the feeder clogs
(median N_t between 2 and 8), so that the target is not the trivial "the tray empties".

    NUMBA_NUM_THREADS=1 nice -n 10 python benchmarks/truth_pilot.py --workers 2 \
        --truth "E=1e7,nu=0.3,e=0.2,mu=0.9" --out benchmarks/full-feeder-truth.json

Results already in the file for the same truth, config and seed are kept (a restart resumes).
Several ``--truth`` options screen candidates in one pool (``--screen 3``: the first three
experiment seeds each, so a chosen truth keeps them); each truth then gets its own file, the
``--out`` name with the truth appended (``...-E1e7-e0.3-mu0.65.json``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from scipy.stats import wasserstein_distance

from dem.scenarios.feeder import run_feeder
from dem.scenarios.feeder_config import load_feeder_config

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENT_SEEDS = range(1000, 1010)
FRESH_SEEDS = range(5000, 5010)


def parse_params(text: str) -> dict[str, float]:
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}
    for item in filter(None, text.split(",")):
        name, _, value = item.partition("=")
        params[name.strip()] = float(value)
    return params


def _run(config_path: str, params: dict[str, float], seed: int) -> dict:
    result = run_feeder(load_feeder_config(config_path), params, seed)
    return result.model_dump(mode="json")


def load_cache(path: Path, truth: dict[str, float], config: str) -> dict:
    if path.exists():
        data = json.loads(path.read_text())
        if data.get("truth") == truth and data.get("config") == config:
            return data
    return {"truth": truth, "config": config, "results": {}}


def summary(values: list[int]) -> str:
    return (
        f"median {statistics.median(values):g}, mean {statistics.mean(values):.2f}, values {sorted(values)}"
    )


def report(truth: dict[str, float], cache: dict) -> None:
    done = cache["results"]
    experiment = [done[str(s)]["n_remaining"] for s in EXPERIMENT_SEEDS if str(s) in done]
    seeds = f"{EXPERIMENT_SEEDS.start}-{EXPERIMENT_SEEDS.stop - 1}"
    print(f"truth {truth}, experiment (seeds {seeds}): {summary(experiment)}")
    if all(str(s) in done for s in FRESH_SEEDS):
        fresh = [done[str(s)]["n_remaining"] for s in FRESH_SEEDS]
        print(f"fresh seeds {FRESH_SEEDS.start}-{FRESH_SEEDS.stop - 1}: {summary(fresh)}")
        print(f"truth's own W1 (fresh vs experiment): {wasserstein_distance(fresh, experiment):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--truth", action="append", help='e.g. "E=1e7,e=0.3,mu=0.65"; repeat to screen')
    parser.add_argument("--config", default="examples/feeder.toml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="benchmarks/full-feeder-truth.json")
    parser.add_argument("--experiment-only", action="store_true", help="Skip the fresh seeds.")
    parser.add_argument("--screen", type=int, default=0, help="Only the first N experiment seeds.")
    args = parser.parse_args()
    truths = [parse_params(text) for text in args.truth or ["E=1e7,nu=0.3,e=0.2,mu=0.9"]]
    seeds = list(EXPERIMENT_SEEDS) + ([] if args.experiment_only else list(FRESH_SEEDS))
    if args.screen:
        seeds = seeds[: args.screen]
    caches = {}
    for truth in truths:
        out = Path(args.out)
        if len(truths) > 1:
            tag = "-".join(f"{name}{value:g}" for name, value in truth.items() if name != "nu")
            out = out.with_name(f"{out.stem}-{tag}{out.suffix}")
        caches[out] = (truth, load_cache(out, truth, args.config))
    started = time.monotonic()
    with ProcessPoolExecutor(args.workers) as pool:
        futures = {}
        for out, (truth, cache) in caches.items():
            todo = [seed for seed in seeds if str(seed) not in cache["results"]]
            print(f"truth {truth} on {args.config}: {len(todo)} of {len(seeds)} seeds to run", flush=True)
            for seed in todo:
                futures[pool.submit(_run, str(ROOT / args.config), truth, seed)] = (out, seed)
        for future in as_completed(futures):
            out, seed = futures[future]
            truth, cache = caches[out]
            result = future.result()
            cache["results"][str(seed)] = result
            out.write_text(json.dumps(cache, indent=1))
            print(
                f"{out.name} seed {seed}: N_t = {result['n_remaining']} ({result['status']}), "
                f"{result['wall_time_s']:.0f} s wall, cost {result['cost']:.3g}",
                flush=True,
            )
    for truth, cache in caches.values():
        report(truth, cache)
    print(f"{time.monotonic() - started:.0f} s wall")


if __name__ == "__main__":
    main()
