"""The figures the README quotes from simulations, simulated again: each figure runs what the
README says was run, and ``--check`` names every README or example line that no longer holds
(exit 1), so that a change to the engine cannot leave the documentation describing another one.
``tests/test_readme_figures.py`` runs the check.

    python docs/figures.py            # print the figures
    python docs/figures.py --check    # and compare them with README.md and examples/
    python docs/figures.py --picture  # also redraw docs/clogged-run.png from the clogged run

Figures:

- the quick study's synthetic experiment (``examples/study-quick.toml``, ``measured``): its hidden
  truth simulated on seeds the study never uses, the list to paste into the example;
- the clogged run of the feeder section: the quick feeder, seed ``CLOGGED_SEED``, E = 1e7 Pa, mu = 0.5
  (the first seed whose run clogs on this engine: a change of engine can make it empty, and the
  check then says so).

All runs go through the local pool, as a calibration's do. This script prints and compares; it
changes a file only with ``--picture``.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import sys
import tempfile
import tomllib
from pathlib import Path

# The feeder is chaotic: a difference of 1e-17 in a clump's sphere offsets changes every figure.
# Clumps are therefore built afresh in a folder of their own, never read from a cache another
# process filled. No OpenBLAS kernel set needs naming: the principal frames are computed in
# dem/frames.py, whose last bit does not depend on the kernels OpenBLAS picks for the CPU.
os.environ["DEMCAL_DATA_DIR"] = tempfile.mkdtemp(prefix="demcal-figures-")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from optimizer.protocols import TrialSpec  # noqa: E402  (the repository root is on the path now)
from optimizer.study import load_study_file  # noqa: E402
from worker.local import LocalPoolExecutor  # noqa: E402

README = ROOT / "README.md"
QUICK_STUDY = ROOT / "examples" / "study-quick.toml"
WALL_STUDY = ROOT / "examples" / "study-wall.toml"  # the quick study's experiment, walls searched apart
QUICK_FEEDER = ROOT / "examples" / "feeder-quick.toml"
PICTURE = ROOT / "docs" / "clogged-run.png"
NEW_STUDY_FORM = ROOT / "api" / "dashboard" / "static" / "new.js"  # starts from the quick study

TRUTH = {"E": 5.0e6, "nu": 0.3, "e": 0.5, "mu": 0.5}
FIRST_SEED = 900_001  # far from the study's seeds, which come from a SeedSequence
TRUTH_SEEDS = 8
CLOGGED = {"E": 1.0e7, "nu": 0.3, "e": 0.5, "mu": 0.5}
CLOGGED_SEED = 1


def _specs(snapshot_dir: Path) -> tuple[list[TrialSpec], TrialSpec]:
    quick = load_study_file(QUICK_STUDY).scenario.model_dump(mode="json")
    truth = [
        TrialSpec(f"truth-{seed}", "figures", 0, 0, 0, seed, TRUTH, quick)
        for seed in range(FIRST_SEED, FIRST_SEED + TRUTH_SEEDS)
    ]
    feeder = tomllib.loads(QUICK_FEEDER.read_text())
    clogged = TrialSpec("clogged", "figures", 0, 0, 0, CLOGGED_SEED, CLOGGED, feeder, keep_snapshots=True)
    return truth, clogged


def simulate(workers: int, snapshot_root: Path) -> dict:
    """Every figure's simulations at once on the local pool; the figures as a dict."""
    truth, clogged = _specs(snapshot_root)
    specs = [*truth, clogged]
    executor = LocalPoolExecutor(workers, snapshot_root=snapshot_root)
    results = {}
    try:
        executor.submit(specs)
        while len(results) < len(specs):
            for outcome in executor.poll(timeout=1.0):
                results[outcome.trial_id] = outcome.result
    finally:
        executor.close()
    failed = {tid: f"{r.status.value}: {r.message}" for tid, r in results.items() if not r.ok}
    if failed:
        raise RuntimeError(f"figure runs failed: {failed}")
    return {
        "measured": [results[spec.trial_id].n_remaining for spec in truth],
        "clogged_n_t": results[clogged.trial_id].n_remaining,
        "clogged_snapshots": snapshot_root / clogged.trial_id,
    }


def _words(text: str) -> str:
    return " ".join(text.split())


def stale(figures: dict) -> list[str]:
    """The documented statements that the figures contradict, each with what holds instead."""
    readme = _words(README.read_text())
    measured = figures["measured"]
    listed = ", ".join(str(n) for n in measured)
    problems = []
    claim = f"measured N_t = {listed} on {len(measured)} seeds"
    if claim not in readme:
        found = re.search(r"measured N_t = [\d, ]+ on \d+ seeds", readme)
        problems.append(f"README.md says {found.group(0) if found else 'no measured list'}; now {claim}")
    for study in (QUICK_STUDY, WALL_STUDY):
        example = tomllib.loads(study.read_text())["experiment"]["measured"]
        if example != measured:
            problems.append(f"examples/{study.name} has measured = {example}; now {measured}")
    starter = re.search(r"measured = \[([\d, ]*)\]", NEW_STUDY_FORM.read_text())
    if starter is None or starter.group(1) != listed:
        problems.append(f"the new-study form's starter (new.js) is not measured = [{listed}]")
    if figures["clogged_n_t"] == 0:
        problems.append(f"the clogged run (seed {CLOGGED_SEED}) empties the tray now; pick a seed that clogs")
    clogged = f"quick config, seed {CLOGGED_SEED}, E = 1e7 Pa, mu = 0.5: N_t = {figures['clogged_n_t']},"
    if clogged not in readme:
        found = re.search(r"quick config, seed \d+, E = [^:]+: N_t = \d+,", readme)
        said = found.group(0) if found else "nothing of the clogged run"
        problems.append(f"README.md says {said}; now {clogged}")
    return problems


def draw_picture(snapshots: Path) -> Path:
    from dem.scenarios.render import default_times, load_run, render_png

    run = load_run(snapshots)
    return render_png(run, default_times(run), PICTURE)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare with README.md and examples/")
    parser.add_argument("--picture", action="store_true", help=f"redraw {PICTURE.relative_to(ROOT)}")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        figures = simulate(args.workers, Path(tmp))
        measured = figures["measured"]
        print(f"quick study's experiment: truth {TRUTH}, seeds {FIRST_SEED}..{FIRST_SEED + TRUTH_SEEDS - 1}")
        print(f"  measured = {measured}   # median {statistics.median(measured):g}")
        print(f"clogged run: quick feeder, seed {CLOGGED_SEED}, {CLOGGED}: N_t = {figures['clogged_n_t']}")
        if args.picture:
            print(f"wrote {draw_picture(figures['clogged_snapshots'])}")
    if not args.check:
        return 0
    problems = stale(figures)
    for problem in problems:
        print(f"STALE: {problem}")
    print("every figure holds" if not problems else f"{len(problems)} figure(s) no longer hold")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
