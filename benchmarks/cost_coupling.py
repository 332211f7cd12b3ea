"""How much a feeder run's cost says about its outcome rather than its parameters, read off
finished studies: the cost per step of the full 65 s protocol and the cost per item-step, by
N_t class, and a least-squares fit of log cost on log10 E and N_t.

A run that empties the tray stops early and carries fewer items a step, so its raw cost is lower
at the same E; a time objective built on it rewards emptying the tray (calibration section 16).
The work per item-step is what the parameters set. Item-seconds of archived runs take each item
as inserted on the protocol's schedule (item i at i x insertion_time / n); the feeder now records
the real times (``SimulationResult.full_load_factor``).

    python -m benchmarks.cost_coupling benchmarks/paper-study-*.archive.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from dem.scenarios.feeder import full_load_factor

CLASSES = ((0, 0), (1, 3), (4, 8), (9, 30))


def runs(archive: dict) -> np.ndarray:
    """(log10 E, N_t, ln cost per full-protocol step, ln cost per item-step) of every ok run."""
    scenario = archive["scenarios"][0] if archive.get("scenarios") else {}
    stages = scenario.get("stages", {}) if isinstance(scenario, dict) else {}
    insertion = float(stages.get("insertion_time", 1.0))
    end = float(stages.get("vibration_start", 5.0)) + float(stages.get("vibration_time", 60.0))
    rows = []
    for trial in archive["trials"]:
        result = trial.get("result") or {}
        if trial.get("status") != "ok" or not result.get("cost"):
            continue
        times = result["discharge_times"]
        scheduled = [i * insertion / len(times) for i in range(len(times))]
        protocol_item_seconds = sum(end - t for t in scheduled)
        item_seconds = protocol_item_seconds / full_load_factor(scheduled, times, result["sim_time"], end)
        rows.append((
            np.log10(trial["params"]["E"]),
            result["n_remaining"],
            np.log(result["cost"] * result["dt"] / end),
            np.log(result["cost"] * result["dt"] / item_seconds),
        ))
    return np.array(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("archives", nargs="+", type=Path, help="study archives (demcal studies archive)")
    args = parser.parse_args()
    for path in args.archives:
        table = runs(json.loads(path.read_text()))
        if len(table) == 0:
            print(f"{path.name}: no measured runs")
            continue
        log_e, n_t, per_step, per_item_step = table.T
        fit = np.c_[np.ones(len(table)), log_e, n_t > 0, n_t]
        coef, *_ = np.linalg.lstsq(fit, per_step, rcond=None)
        print(f"{path.name}: {len(table)} measured runs; ln(cost) = {coef[1]:.2f} log10 E "
              f"+ {coef[2]:.2f} [N_t > 0] + {coef[3]:.3f} N_t + const")
        empty = (n_t == 0)
        base_step, base_item = per_step[empty].mean(), per_item_step[empty].mean()
        print("  N_t class   runs   cost per protocol step   cost per item-step   (relative to N_t = 0)")
        for low, high in CLASSES:
            chosen = (n_t >= low) & (n_t <= high)
            if chosen.any():
                print(f"  {low:>2}-{high:<2}      {chosen.sum():>4}   "
                      f"{np.exp(per_step[chosen].mean() - base_step):>22.2f}   "
                      f"{np.exp(per_item_step[chosen].mean() - base_item):>18.3f}")


if __name__ == "__main__":
    main()
