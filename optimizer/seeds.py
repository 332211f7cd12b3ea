"""Where every simulation's seed comes from: common random numbers for the search, a separate
stream for the validation.

- Search: replicate r of *every* individual of a batch uses the same seed, so the sets of one
  generation are compared on the same draws of item shapes and insertion positions rather than on
  different luck (common random numbers; their difference has far less variance).
- Each batch draws new common seeds (``common_seeds = "generation"``, the default); batch 0 keeps
  the seeds of ``"study"``, where replicate r has one seed for the whole study. Why: with one seed
  for the whole study the search fits that one draw. The paper's study converged on sets whose
  median N_t was 3 on the search's seed and 12 or 1.5 on fresh seeds (benchmarks/README.md,
  calibration 17). With a new draw per generation, the survivors (re-estimated with their
  neighbours' runs before every survival, ``optimizer/neighbours.py``) are judged on many draws.
- Validation: fresh seeds from their own stream, checked against every seed the search could use,
  so a validated set is judged on draws it was never selected on.
"""

from __future__ import annotations

import numpy as np

SEARCH_STREAM = 0
VALIDATION_STREAM = 1


def trial_seed(study_seed: int, replicate: int, stream: int = SEARCH_STREAM) -> int:
    """A simulation's seed, reproducible from the study seed, the replicate and the stream."""
    return _seed([study_seed, stream, replicate])


def search_seed(study_seed: int, replicate: int, batch: int, per_generation: bool) -> int:
    """The common seed of replicate ``replicate`` in search batch ``batch``."""
    if batch == 0 or not per_generation:
        return trial_seed(study_seed, replicate)
    return _seed([study_seed, SEARCH_STREAM, replicate, batch])


def search_seeds(study_seed: int, replicates: int, batches: int, per_generation: bool) -> set[int]:
    """Every seed the search may use: replicates 0 .. replicates-1 in batches 0 .. batches-1."""
    return {
        search_seed(study_seed, replicate, batch, per_generation)
        for replicate in range(replicates)
        for batch in range(batches)
    }


def validation_seeds(study_seed: int, count: int, used: set[int]) -> list[int]:
    """``count`` seeds of the validation stream that the search never uses (``used``); a
    (vanishingly rare) clash of the 31-bit seeds is skipped, not reused."""
    seeds: list[int] = []
    k = 0
    while len(seeds) < count:
        seed = trial_seed(study_seed, k, VALIDATION_STREAM)
        if seed not in used and seed not in seeds:
            seeds.append(seed)
        k += 1
    return seeds


def _seed(entropy: list[int]) -> int:
    return int(np.random.SeedSequence(entropy).generate_state(1)[0]) & 0x7FFFFFFF
