"""Identifiability: which contact parameters the experiments pin down, and which they do not.

Two views, both from a study's own simulations (no new runs), for each experiment and for all
of a study's experiments together (``study_identifiability``):

- **Sensitivity** of the response: variance-based (Sobol) indices of the surrogate's mean of
  an experiment's response (a count such as N_t through ``2 sqrt(N_t + 3/8)``, which makes
  its noise even; a real value such as an angle as it is) over the search box (the same
  Gaussian process the surrogate search fits, ``optimizer/surrogate.py``), estimated with
  Saltelli's first-order and Jansen's total estimators on a scrambled Sobol sample. A parameter
  with a small total index barely changes the response anywhere in the box: no experiment on
  that response can determine it. The fitted ARD length scale says
  the same in other words (long = flat) and is reported beside it.
- **Spread of the matching sets**: the range of each parameter over the sets that matched,
  as a share of its searched range (log scale for E). A parameter that matches across most of
  its range is not pinned down by this experiment, whatever its global sensitivity (the paper's
  multimodality: the response is sensitive to mu and e together, but they trade off).

Verdict per parameter: ``pinned`` (total index >= 0.1 and the matching sets span less than half
its range), ``not identifiable`` (total index < 0.02: the response ignores it), else ``weak``.
Several experiments together: the most sensitive experiment's index and the spread of the sets
that match them all; a parameter no experiment pins alone but all pin together (two ridges that
cross, as a heap's angle and the feeder's N_t can) is ``pinned_together``.
With fewer than 8 successful simulations or a constant response there is nothing to say, and
the result says why.

This module computes; it must not run simulations or read stores. Deterministic (fixed seeds).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.stats import qmc

from optimizer.objectives import Evaluation
from optimizer.space import ParameterSpace
from optimizer.surrogate import anscombe, fit_gp, length_scales, one_blas_thread

MIN_SIMULATIONS = 8
PINNED_TOTAL = 0.1
IGNORED_TOTAL = 0.02
PINNED_SPREAD = 0.5
BASE_SAMPLES = 1024  # Saltelli's N: N (d + 2) predictions of the surrogate's mean
# The exact GP costs n^3 per likelihood evaluation: fitted on all 10,000 simulations of a long
# study it ran for minutes (benchmarks/api_load.py, --dashboard), while a dashboard waited. A
# smooth response of four parameters is resolved by a few hundred points, so larger studies are
# fitted on an even random subsample of this size (fixed seed: the same answer every time).
MAX_GP_POINTS = 500


def sobol_indices(function, n_genes: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """First-order (Saltelli 2010) and total (Jansen 1999) indices of ``function`` on [0, 1]^d."""
    sample = qmc.Sobol(d=2 * n_genes, scramble=True, seed=seed).random(BASE_SAMPLES)
    a, b = sample[:, :n_genes], sample[:, n_genes:]
    f_a, f_b = function(a), function(b)
    variance = np.var(np.concatenate([f_a, f_b]))
    if variance <= 0:
        return np.zeros(n_genes), np.zeros(n_genes)
    first, total = np.empty(n_genes), np.empty(n_genes)
    for i in range(n_genes):
        ab = a.copy()
        ab[:, i] = b[:, i]
        f_ab = function(ab)
        first[i] = np.mean(f_b * (f_ab - f_a)) / variance
        total[i] = 0.5 * np.mean((f_a - f_ab) ** 2) / variance
    return np.clip(first, 0.0, 1.0), np.clip(total, 0.0, 1.0)


def _verdict(total: float, spread: float | None) -> str:
    if total < IGNORED_TOTAL:
        return "not identifiable"
    if total >= PINNED_TOTAL and (spread is None or spread < PINNED_SPREAD):
        return "pinned"
    return "weak"


def identifiability(
    evaluations: Sequence[Evaluation],
    space: ParameterSpace,
    tolerance: float,
    *,
    response: str = "",
    label: str = "N_t",
    count: bool = True,
    matches: Callable[[Evaluation], bool] | None = None,
) -> dict:
    """Per free parameter: Sobol indices, length scale, the matching sets' range and a verdict.

    ``response`` names the experiment's response in ``Evaluation.responses`` (default: the
    first experiment's, ``n_remaining``); ``count`` says it counts (Anscombe transform);
    ``tolerance`` is the study's match tolerance on f1, which says which sets match unless
    ``matches`` does (one experiment of several)."""
    rows = [
        (space.genes(ev.params), n)
        for ev in evaluations
        if ev.ok
        for n in (ev.responses.get(response, ev.n_remaining) if response else ev.n_remaining)
    ]
    modelled = f"2 sqrt({label} + 3/8)" if count else label
    result: dict = {
        "method": f"Sobol indices of a Gaussian-process mean of {modelled} over the search "
        "box; spread of the matching sets in units of the searched range",
        "simulations": len(rows),
        "parameters": [],
        "reason": "",
    }
    if len(rows) < MIN_SIMULATIONS:
        result["reason"] = f"{len(rows)} successful simulations; at least {MIN_SIMULATIONS} are needed"
        return result
    genes = np.array([gene for gene, _ in rows])
    raw = np.array([n for _, n in rows], dtype=float)
    values = anscombe(raw) if count else raw
    if np.ptp(values) == 0:
        result["reason"] = f"every simulation gave {label} = {rows[0][1]:g}: the response does not vary"
        return result
    if len(genes) > MAX_GP_POINTS:
        pick = np.sort(np.random.default_rng(0).choice(len(genes), MAX_GP_POINTS, replace=False))
        genes, values = genes[pick], values[pick]
    with one_blas_thread():
        model = fit_gp(genes, values, random_state=0)
        first, total = sobol_indices(model.predict, space.n_genes)
    scales = length_scales(model)
    matches = matches or (lambda ev: ev.matches(tolerance))
    matching = np.array([space.genes(ev.params) for ev in evaluations if matches(ev)])
    for i, axis in enumerate(space.axes):
        spread = _matching(matching, i, axis)
        result["parameters"].append(
            {
                "name": axis.name,
                "first_order": round(float(first[i]), 4),
                "total": round(float(total[i]), 4),
                "length_scale": round(float(scales[i]), 4),
                **spread,
                "verdict": _verdict(float(total[i]), spread["matching_spread"]),
            }
        )
    return result


def _matching(matching: np.ndarray, i: int, axis) -> dict:
    """The matching sets' count, range and spread (share of the searched range) on gene ``i``."""
    spread = float(np.ptp(matching[:, i])) if len(matching) >= 2 else None
    found = len(matching) > 0
    return {
        "matching_sets": int(len(matching)),
        "matching_range": [axis.value(matching[:, i].min()), axis.value(matching[:, i].max())]
        if found
        else None,
        "matching_spread": None if spread is None else round(spread, 4),
    }


def study_identifiability(evaluations: Sequence[Evaluation], definition, space: ParameterSpace) -> dict:
    """``identifiability`` of a study, for every experiment and for all of them together.

    ``experiments``: one result per experiment, its declared response modelled as it is (a count
    through the Anscombe transform), its matching sets those within that experiment's own
    tolerance. The top level is the study's: per parameter, the most sensitive experiment's
    indices (``response`` names it), the spread of the sets that match every experiment (the
    study's own match), its verdict, the experiments that pin it alone (``pinned_by``), and
    ``pinned_together`` when the experiments pin it only jointly (each alone leaves a ridge of
    equally good values, their intersection does not). With one experiment the top level is
    that experiment's result."""
    declared = definition.declared_responses()
    tolerance = definition.match_tolerance()
    per_experiment = []
    for experiment in definition.experiments:
        name = experiment.response
        response = declared.get(name)
        result = identifiability(
            evaluations, space, tolerance, response=name,
            label=(response.label or name) if response else name,
            count=response.integer if response else True,
            matches=_matches(experiment),
        )
        per_experiment.append({"response": name, **result})
    first = per_experiment[0]
    study = {key: first[key] for key in ("method", "simulations", "reason")}
    study["experiments"] = per_experiment
    study["parameters"] = _together(evaluations, space, tolerance, per_experiment)
    return study


def _matches(experiment) -> Callable[[Evaluation], bool]:
    """Whether a set matches this one experiment (its own distance within its own tolerance)."""
    from optimizer.objectives import experiment_distance

    def matches(ev: Evaluation) -> bool:
        values = ev.responses.get(experiment.response) or []
        if not ev.ok or not values:
            return False
        return experiment_distance(values, experiment) <= experiment.tolerance + 1e-9

    return matches


def _together(evaluations, space: ParameterSpace, tolerance: float, per_experiment: list[dict]) -> list[dict]:
    """Per parameter: what the experiments say together (see ``study_identifiability``)."""
    assessed = [
        ({row["name"]: row for row in result["parameters"]}, result["response"])
        for result in per_experiment
        if result["parameters"]
    ]
    if not assessed:
        return []
    matching = np.array([space.genes(ev.params) for ev in evaluations if ev.matches(tolerance)])
    rows = []
    for i, axis in enumerate(space.axes):
        candidates = [(by_name[axis.name], response) for by_name, response in assessed]
        best, response = max(candidates, key=lambda pair: pair[0]["total"])
        spread = _matching(matching, i, axis)
        pinned_by = [name for row, name in candidates if row["verdict"] == "pinned"]
        verdict = _verdict(best["total"], spread["matching_spread"])
        rows.append(
            {
                **{key: best[key] for key in ("name", "first_order", "total", "length_scale")},
                "response": response,
                **spread,
                "verdict": verdict,
                "pinned_by": pinned_by,
                "pinned_together": verdict == "pinned" and not pinned_by,
            }
        )
    return rows
