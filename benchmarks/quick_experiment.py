"""The synthetic experiment of the README's main job (``examples/study-quick.toml``): the hidden
truth simulated on seeds the study never uses, printed as the ``measured`` list to paste.

    python benchmarks/quick_experiment.py [--seeds 8] [--workers 2]

The truth clogs: on the quick feeder with 2.5 s of vibration some items are still in the tray,
so the target is a non-zero N_t and the study has something to find.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from optimizer.protocols import TrialSpec
from optimizer.study import load_study_file
from worker.local import LocalPoolExecutor

ROOT = Path(__file__).resolve().parent.parent
TRUTH = {"E": 5.0e6, "nu": 0.3, "e": 0.5, "mu": 0.5}
FIRST_SEED = 900_001  # far from the study's seeds, which come from a SeedSequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    scenario = load_study_file(ROOT / "examples" / "study-quick.toml").scenario
    specs = [
        TrialSpec(f"truth-{seed}", "truth", 0, 0, 0, seed, TRUTH, scenario)
        for seed in range(FIRST_SEED, FIRST_SEED + args.seeds)
    ]
    executor = LocalPoolExecutor(args.workers)
    started = time.monotonic()
    results = {}
    try:
        executor.submit(specs)
        while len(results) < len(specs):
            for outcome in executor.poll(timeout=1.0):
                results[outcome.trial_id] = outcome.result
    finally:
        executor.close()
    counts = [results[spec.trial_id].n_remaining for spec in specs]
    print(f"truth {TRUTH}, seeds {FIRST_SEED}..{FIRST_SEED + args.seeds - 1}")
    print(f"statuses {[results[spec.trial_id].status.value for spec in specs]}")
    print(f"measured = {counts}   # median {statistics.median(counts):g}")
    print(f"{time.monotonic() - started:.0f} s")


if __name__ == "__main__":
    main()
