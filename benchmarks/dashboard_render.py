"""How long the dashboard's study page takes to show a study of 10,000 trials (goal: < 2 s).

Seeds a finished synthetic study through the real SQL store (SQLite file in a temporary
directory), serves the real app with uvicorn, opens the study page in headless Debian Chromium
and reads two marks the page sets itself (study.js): from navigation start to the Pareto front
drawn (``demcal:pareto-drawn``) and to all three plots drawn (``demcal:plots-drawn``); the first
visit has a cold browser cache, the next ones have plotly.min.js cached. Prints the figures and
the machine's load average (the figures mean little on a busy machine); not a test.

    python benchmarks/dashboard_render.py [--trials 10000] [--runs 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

# The repository root instead of benchmarks/: benchmarks/queue.py would shadow the standard
# library's queue module that uvicorn imports.
sys.path[0] = str(Path(__file__).resolve().parents[1])

from tests.dashboard.conftest import CHROMIUM, CHROMIUM_ARGS, serving  # noqa: E402
from tests.dashboard.seed import migrated_store, seed_study  # noqa: E402

DRAWN = "() => performance.getEntriesByName('demcal:plots-drawn').length > 0"
# When the last page of trials had arrived: what the API costs, before any drawing.
TRIALS_LOADED = (
    "() => Math.max(...performance.getEntriesByType('resource')"
    ".filter((r) => r.name.includes('/trials?')).map((r) => r.responseEnd))"
)
MARKS = (
    "() => ['demcal:pareto-drawn', 'demcal:plots-drawn']"
    ".map((n) => performance.getEntriesByName(n)[0].startTime)"
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10_000)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from api.settings import load_settings

    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{Path(tmp) / 'demcal.db'}"
        store = migrated_store(url)
        generations = 19
        per_generation = args.trials // (generations + 1)
        started = time.perf_counter()
        study = seed_study(
            store, population=per_generation, offspring=per_generation, generations=generations
        )
        print(f"seeded {len(study.trial_ids)} trials in {time.perf_counter() - started:.1f} s")
        settings = load_settings(database_url=url, data_dir=Path(tmp) / "data")
        with serving(settings) as base, sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            context = browser.new_context(viewport={"width": 1440, "height": 900})
            context.add_init_script(f"localStorage.setItem('demcal.apiKey', {study.api_key!r})")
            page = context.new_page()
            timings = []
            for run in range(args.runs):
                page.goto(f"{base}/studies/{study.study_id}")
                page.wait_for_function(DRAWN, timeout=60_000)
                points = page.evaluate("() => document.getElementById('pareto-plot').data[0].x.length")
                pareto, everything = (ms / 1000 for ms in page.evaluate(MARKS))
                loaded = page.evaluate(TRIALS_LOADED) / 1000
                timings.append((pareto, everything))
                cache = "cold cache" if run == 0 else "warm cache"
                print(
                    f"run {run + 1} ({cache}): {points} points; after navigation, trials loaded at "
                    f"{loaded:.2f} s, Pareto front drawn at {pareto:.2f} s, all plots at {everything:.2f} s"
                )
            browser.close()
        warm = timings[1:] or timings
        print(
            f"study page, {len(study.trial_ids)} trials: Pareto front cold {timings[0][0]:.2f} s, warm "
            f"median {statistics.median(t[0] for t in warm):.2f} s; all plots warm median "
            f"{statistics.median(t[1] for t in warm):.2f} s (goal < 2 s); load average "
            f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
        )


if __name__ == "__main__":
    main()
