"""Where every simulation's seed comes from: common random numbers for the search, a separate
stream for the validation.

- Search: replicate r of *every* individual uses the same seed (``trial_seed(study seed, r)``), so
  two parameter sets are compared on the same draws of item shapes and insertion positions
  rather than on different luck (common random numbers; their difference has far less variance).
- Validation: fresh seeds from their own stream, checked against every seed the search could use,
  so a validated set is judged on draws it was never selected on.
"""

from __future__ import annotations

import numpy as np

SEARCH_STREAM = 0
VALIDATION_STREAM = 1


def trial_seed(study_seed: int, replicate: int, stream: int = SEARCH_STREAM) -> int:
    """A simulation's seed, reproducible from the study seed, the replicate and the stream."""
    state = np.random.SeedSequence([study_seed, stream, replicate]).generate_state(1)[0]
    return int(state) & 0x7FFFFFFF


def validation_seeds(study_seed: int, count: int, search_replicates: int) -> list[int]:
    """``count`` seeds of the validation stream that no search replicate (0 .. search_replicates-1)
    uses; a (vanishingly rare) clash of the 31-bit seeds is skipped, not reused."""
    used = {trial_seed(study_seed, r) for r in range(search_replicates)}
    seeds: list[int] = []
    k = 0
    while len(seeds) < count:
        seed = trial_seed(study_seed, k, VALIDATION_STREAM)
        if seed not in used and seed not in seeds:
            seeds.append(seed)
        k += 1
    return seeds
