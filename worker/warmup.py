"""Warm a worker process before its first trial, so that no trial's T includes a compile.

The engine's kernels are numba functions: the first call in a process compiles them, or loads
them from numba's on-disk cache, and builds the item clumps' caches. Measured on the 2-core
machine with a warm disk cache: the first tiny feeder trial of a process took T = 6.3 s, the
second 0.48 s (13 s against 0.5 s end to end). In a study that first T would sit beside ones of
a few seconds and rank the individual that happened to be first on a fresh worker as slow. So
every worker (the local pool's processes, ``demcal worker``) runs one tiny feeder simulation
(two items, 0.3 s simulated, every kernel path: clump build, insertion, sphere-sphere and
sphere-wall contacts, the moving tray) before it takes a trial.

Must not: touch a store or a queue; it only runs the engine once.
"""

from __future__ import annotations

import logging
import time

logger = logging.getLogger(__name__)

WARMUP_SCENARIO = {
    "items": {"counts": {"smartphone": 1, "camera": 1}, "resolution": 4},
    "stages": {"insertion_time": 0.05, "vibration_start": 0.15, "vibration_time": 0.15},
    "run": {"stop_when_empty": False},
}
WARMUP_PARAMS = {"E": 1e6, "nu": 0.3, "e": 0.5, "mu": 0.5}


def warm_up() -> float:
    """Run the tiny simulation; returns its seconds. Never raises: a failed warm-up only means
    the first trial compiles, which it reports in its own result."""
    started = time.monotonic()
    try:
        from dem.scenarios.feeder import run_feeder
        from dem.scenarios.feeder_config import FeederConfig

        result = run_feeder(FeederConfig.model_validate(WARMUP_SCENARIO), dict(WARMUP_PARAMS), seed=0)
        if not result.ok:
            logger.warning("warm-up simulation ended %s: %s", result.status.value, result.message)
    except Exception:
        logger.exception("warm-up failed; the first trial will include the kernels' compile")
    seconds = time.monotonic() - started
    logger.info("kernels warm in %.1f s", seconds)
    return seconds
