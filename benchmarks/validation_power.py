"""How often does the end-of-study validation (``optimizer/validation.py``) tell a wrong set
from the truth on the full feeder? Size and power of its permutation test, by statistic.

The populations are real full-feeder runs at 24 spheres per item: the truth's 20 runs (seeds
1000-1009 and 5000-5009, ``benchmarks/full-feeder-truth-res24.json``) and the fresh and search
runs of the sets the searches found (``benchmarks/full-feeder-calibration-res24.json``). Each
draw takes 10 "measured" values from the truth's runs and n "fresh" values from a set's runs
(with replacement) and applies the test at level 0.1; the share of ``not reproduced`` is the
test's size for the truth and its power for the others. No simulation runs: a few seconds.

    python -m benchmarks.validation_power [--draws 600] [--fresh 10,20,30]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from optimizer.noise import anderson_darling_pairs, permutation_quantile, wasserstein_pairs
from optimizer.study import NOISE_FLOOR_QUANTILE

ROOT = Path(__file__).resolve().parent
# W1 is the validation's statistic; Anderson-Darling the alternative it was compared with.
STATISTICS = {"W1": wasserstein_pairs, "Anderson-Darling": anderson_darling_pairs}


def populations() -> dict[str, list[int]]:
    truth = json.loads((ROOT / "full-feeder-truth-res24.json").read_text())["results"]
    found = {"truth (E 1e7, nu 0.3, e 0.3, mu 0.7)": [run["n_remaining"] for run in truth.values()]}
    methods = json.loads((ROOT / "full-feeder-calibration-res24.json").read_text())["methods"]
    for method, search in methods.items():
        for row in search.get("validated", []):
            params = ", ".join(f"{k} {v:.2g}" for k, v in row["params"].items())
            found[f"{method} {row['role']} #{row['individual']} ({params})"] = row["n_remaining"]
    return found


def rejection_rate(truth, population, statistic, fresh: int, draws: int, seed: int) -> float:
    rng = np.random.default_rng(seed)
    rejected = 0
    for draw in range(draws):
        measured = rng.choice(truth, 10).astype(float)
        sample = rng.choice(population, fresh).astype(float)
        value = statistic(sample[None, :], measured[None, :])[0]
        limit = permutation_quantile(sample, measured, statistic, NOISE_FLOOR_QUANTILE, draw)
        rejected += value > limit + 1e-9
    return rejected / draws


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=600)
    parser.add_argument("--fresh", default="10,20,30", help="Fresh seeds per check, comma-separated.")
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args()
    sets = populations()
    truth = np.asarray(next(iter(sets.values())))
    print(f"share 'not reproduced' over {args.draws} draws (10 measured values from the truth's 20 runs)")
    print("| set (its runs) | fresh seeds | " + " | ".join(STATISTICS) + " |")
    print("| --- | --- |" + " --- |" * len(STATISTICS))
    for name, runs in sets.items():
        for fresh in (int(n) for n in args.fresh.split(",")):
            rates = [
                rejection_rate(truth, np.asarray(runs), statistic, fresh, args.draws, args.seed)
                for statistic in STATISTICS.values()
            ]
            figures = " | ".join(f"{rate:.3f}" for rate in rates)
            print(f"| {name}: {sorted(runs)} | {fresh} | {figures} |", flush=True)


if __name__ == "__main__":
    main()
