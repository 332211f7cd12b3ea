"""The per-generation summary (the paper's Fig. 5), in one place for the API's
``GET /studies/{id}/generations`` and the results folder's ``summary.json``: for each batch, its
runs, how many finished, measured and failed (by status), and the median and spread of each
response, the wall time and the cost (each run's own, and the whole protocol's, which f2 ranks)
over the runs that measured (a failed run's values are where it stopped, never a measurement),
with the best f1 stored for its runs. The dashboard draws Fig. 5's medians from it. Given the
experiments' measured values, also each response's Wasserstein-1 distance from the generation's
runs to the experiment: with the feeder's noise (N_t 0-16 over the ten experiments) a median of
single runs can sit on the target by chance or miss it with the right sets, while the distance
says how like the experiment the whole generation behaves.

How near is near enough: ``as_experiment`` gives, for a generation of n measured runs, where a
generation drawn from the experiment itself would land (n values resampled from the measured
ones, :func:`experiment_band`): its median's 5-95 % range and the 95th percentile of its W1. A
generation whose W1 lies at or below that percentile behaves as the experiment does, as far as n runs can
tell (``alike``); with the paper's ten values and 15 runs the median alone strays over 1-4, now and
then 12.

Pure arithmetic on plain runs, so the store's rows and the optimiser's trial records both feed
it; it must not read stores.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.stats import wasserstein_distance

from dem.result import SimulationStatus
from optimizer.objectives import RunTimes, protocol_times
from optimizer.outcomes import count_failures
from optimizer.protocols import TrialRecord


@dataclass(frozen=True)
class Run:
    """One trial as the summary needs it; ``status`` is None until the run finished."""

    generation: int
    status: str | None
    responses: Mapping[str, float | None] = field(default_factory=dict)
    wall_time_s: float | None = None
    cost: float | None = None
    f1: float | None = None  # the objective stored for it (None for a failed set's runs)
    protocol_wall_time_s: float | None = None  # the whole protocol's (objectives.protocol_times)
    protocol_cost: float | None = None

    @classmethod
    def measured(
        cls,
        generation: int,
        status: str | None,
        responses: Mapping[str, float | None],
        times: RunTimes,
        f1: float | None = None,
    ) -> Run:
        """A run with its own and its whole protocol's T and cost (``times``: a result, or a
        stored trial's columns, whose times are None before its result)."""
        return cls(generation, status, responses, times.wall_time_s, times.cost, f1, **protocol_times(times))

    @classmethod
    def of(cls, record: TrialRecord) -> Run:
        result = record.result
        if result is None:
            return cls(record.spec.generation, None)
        return cls.measured(record.spec.generation, result.status.value, result.responses, result)


def spread(values: Iterable[float]) -> dict[str, float] | None:
    """Median, quartiles and range; None for no values."""
    values = list(values)
    if not values:
        return None
    q1, median, q3 = np.percentile(values, [25, 50, 75])
    return {"median": float(median), "q1": float(q1), "q3": float(q3), "min": float(min(values)),
            "max": float(max(values))}


BAND_DRAWS = 4000  # resampled generations per band: the 95th percentile to about +-1 %
BAND_SEED = 20210401  # fixed, so that a band is the same in every view and on every call


def experiment_band(measured: Sequence[float], n: int) -> dict[str, float]:
    """Where a generation of ``n`` runs drawn from the experiment itself lands: the 5 % and 95 %
    points of its median and the 95th percentile of its W1 to the experiment (a bootstrap of the
    measured values; the null distribution a converged generation's figures are judged against)."""
    return dict(_band(tuple(sorted(float(value) for value in measured)), int(n)))


@lru_cache(maxsize=256)
def _band(measured: tuple[float, ...], n: int) -> tuple[tuple[str, float], ...]:
    values, counts = np.unique(measured, return_counts=True)
    rng = np.random.default_rng(BAND_SEED)
    # A resample of n values is a multinomial count over the distinct measured values.
    draws = rng.multinomial(n, counts / counts.sum(), size=BAND_DRAWS)
    below = np.cumsum(draws, axis=1)
    low, high = (n - 1) // 2, n // 2  # the middle order statistics (equal for odd n)
    medians = (values[(below > low).argmax(axis=1)] + values[(below > high).argmax(axis=1)]) / 2
    # W1 between two distributions on the same points: the area between their CDFs.
    gaps = np.abs(below[:, :-1] / n - np.cumsum(counts)[:-1] / counts.sum())
    w1 = gaps @ np.diff(values)
    return (
        ("median_5", float(np.percentile(medians, 5))),
        ("median_95", float(np.percentile(medians, 95))),
        ("w1_95", float(np.percentile(w1, 95))),
    )


def _as_experiment(experiment: Sequence[float], simulated: Sequence[float], w1: float) -> dict[str, Any]:
    """The band for as many runs as simulated, and whether their W1 to the experiment (``w1``) lies
    inside it (``alike``: at or below the band's 95th percentile), the one home of that rule."""
    band: dict[str, Any] = experiment_band(experiment, len(simulated))
    band["alike"] = bool(w1 <= band["w1_95"])
    return band


def per_generation(
    runs: Iterable[Run], measured_by_experiment: Mapping[str, Sequence[float]] | None = None
) -> list[dict[str, Any]]:
    """One entry per generation that has runs, in order (see the module docstring);
    ``measured_by_experiment`` maps a response to the experiment's measured values."""
    experiments = measured_by_experiment or {}
    by_generation: dict[int, list[Run]] = {}
    for run in runs:
        by_generation.setdefault(run.generation, []).append(run)
    summaries = []
    for generation, group in sorted(by_generation.items()):
        done = [run for run in group if run.status is not None]
        ok = [run for run in done if run.status == SimulationStatus.OK.value]
        failed = count_failures(run.status for run in done)
        measured: dict[str, list[float]] = {}
        for run in ok:
            for name, value in run.responses.items():
                if value is not None:
                    measured.setdefault(name, []).append(value)
        f1_values = [run.f1 for run in done if run.f1 is not None]
        w1 = {
            name: float(wasserstein_distance(measured[name], values)) if measured.get(name) else None
            for name, values in experiments.items()
        }
        summaries.append({
            "generation": generation, "trials": len(group), "done": len(done), "ok": len(ok),
            "failed": failed.total, "failed_by_status": failed.by_status,
            "n_remaining": spread(measured.get("n_remaining", [])),
            "responses": {name: spread(values) for name, values in measured.items()},
            "wall_time_s": spread(run.wall_time_s for run in ok if run.wall_time_s is not None),
            "cost": spread(run.cost for run in ok if run.cost is not None),
            "protocol_wall_time_s": spread(
                run.protocol_wall_time_s for run in ok if run.protocol_wall_time_s is not None
            ),
            "protocol_cost": spread(run.protocol_cost for run in ok if run.protocol_cost is not None),
            "best_f1": min(f1_values, default=None),
            "w1_to_experiment": w1,
            "as_experiment": {
                name: _as_experiment(values, measured[name], w1[name]) if measured.get(name) else None
                for name, values in experiments.items()
            },
        })
    return summaries
