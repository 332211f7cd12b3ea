"""Where every simulation's seed comes from: common random numbers for the search, a separate
stream for the validation.

- Search, ``common_seeds``:
  - ``"generation"`` (the default): replicate r of *every* individual of a batch uses the same
    seed, so the sets of one generation are compared on the same draws of item shapes and
    insertion positions rather than on different luck (common random numbers; their difference
    has far less variance), and each batch draws new seeds;
  - ``"study"``: replicate r has one seed for the whole study. The search can then fit that one
    draw: the paper's study converged on sets whose median N_t was 3 on the search's seed and 12
    or 1.5 on fresh seeds (benchmarks/README.md, calibration 17);
  - ``"trial"``: every simulation its own seed, as repeated experiments are. A generation then
    samples the draws as the experiment did, where a generation sharing one draw moves with it
    (medians 13, 1, 2, 1, 11 over generations 2-6 of calibration 18); comparisons of siblings
    lose the common draw, which the neighbours' pooling (``optimizer/neighbours.py``) makes up.
  Batch 0 of ``"generation"`` keeps the seeds of ``"study"``.
- Validation: fresh seeds from their own stream, none of which the search used, so a validated
  set is judged on draws it was never selected on.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

CommonSeeds = Literal["generation", "study", "trial"]
STUDY_WIDE_SEEDS: CommonSeeds = "study"  # the rule of every study stored before the setting (0011)
SEARCH_STREAM = 0
VALIDATION_STREAM = 1


def trial_seed(study_seed: int, replicate: int, stream: int = SEARCH_STREAM) -> int:
    """A simulation's seed, reproducible from the study seed, the replicate and the stream."""
    return _seed([study_seed, stream, replicate])


def search_seed(
    study_seed: int, replicate: int, batch: int, individual: int, common_seeds: CommonSeeds
) -> int:
    """The seed of one search simulation under the study's ``common_seeds``."""
    if common_seeds == "trial":
        # individual + 1: SeedSequence pads its entropy with zeros, so a trailing 0 would be no word
        return _seed([study_seed, SEARCH_STREAM, replicate, batch, individual + 1])
    # Batch 0 is the study-wide seed in both other modes (_seed([s, 0, r, 0]) equals it anyway, by
    # the same padding; written out so that the rule does not rest on numpy's).
    if batch == 0 or common_seeds == "study":
        return trial_seed(study_seed, replicate)
    if common_seeds == "generation":
        return _seed([study_seed, SEARCH_STREAM, replicate, batch])
    raise ValueError(f"common_seeds: {common_seeds!r} is none of generation, study, trial")


def validation_seeds(study_seed: int, count: int, used: set[int]) -> list[int]:
    """``count`` seeds of the validation stream that the search did not use (``used``: the seeds
    of its stored trials); a (vanishingly rare) clash of the 31-bit seeds is skipped, not reused."""
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
