"""Make the README's dashboard pictures: ``docs/dashboard-study.png`` and ``docs/dashboard-replay.png``.

    python tests/dashboard/screenshots.py [--snapshots RUN_DIR] [--out docs]

RUN_DIR is a snapshot directory of a real feeder run (``demcal simulate CONFIG --snapshots
RUN_DIR``; its ``summary.json`` holds the result); without it only the study picture is made.
The script seeds a paper-sized synthetic study (50 + 9 x 15 trials, some of them failed, see
``seed.py``) through the real store, makes that real run one of its trials (parameters, result
and snapshots), serves the real app and photographs the study page and that trial's page in
headless Debian Chromium at laptop size. Not part of the test suite.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from dem.result import SimulationResult  # noqa: E402
from tests.dashboard.conftest import CHROMIUM, CHROMIUM_ARGS, REPO, serving  # noqa: E402
from tests.dashboard.seed import migrated_store, seed_study  # noqa: E402

REPLAY_INDIVIDUAL = 57  # a generation-1 individual: the run shows up among the GA's trials


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--snapshots", type=Path, help="snapshot directory of a real run")
    parser.add_argument("--out", type=Path, default=REPO / "docs")
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from api.settings import load_settings

    real = {}
    if args.snapshots:
        summary = json.loads((args.snapshots / "summary.json").read_text())
        real[REPLAY_INDIVIDUAL] = SimulationResult.model_validate(summary)
    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{Path(tmp) / 'demcal.db'}"
        store = migrated_store(url)
        # With failures, as real studies have them: soft sets blow up, a few time out.
        study = seed_study(
            store, population=50, offspring=15, generations=9, real_results=real, failing=True
        )
        trial = study.trial_ids[REPLAY_INDIVIDUAL]
        settings = load_settings(database_url=url, data_dir=Path(tmp) / "data")
        if args.snapshots:
            shutil.copytree(args.snapshots, settings.snapshot_root / trial)
        with serving(settings) as base, sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            context = browser.new_context(viewport={"width": 1440, "height": 900})
            context.add_init_script(f"localStorage.setItem('demcal.apiKey', {study.api_key!r})")
            page = context.new_page()
            page.goto(f"{base}/studies/{study.study_id}")
            page.wait_for_function("() => performance.getEntriesByName('demcal:plots-drawn').length > 0")
            # The panels that load on their own: the progress plot and the identifiability table
            # (a slow first build), so that the picture shows them, not "Loading…".
            page.wait_for_function("() => document.getElementById('progress-plot')?.data?.[0]?.x?.length > 0")
            basis = "document.querySelector('#identifiability-basis')?.textContent ?? ''"
            page.wait_for_function(f"() => !['', 'Loading…'].includes({basis})", timeout=300_000)
            page.wait_for_timeout(500)
            page.screenshot(path=str(args.out / "dashboard-study.png"), full_page=True)
            print(f"wrote {args.out / 'dashboard-study.png'}")
            if not args.snapshots:
                return
            page.goto(f"{base}/trials/{trial}")
            page.wait_for_selector("#trial[data-loaded='1']")
            # A moment of the run where items are still moving, not the (often empty) last frame.
            frames = int(page.get_attribute("#trial", "data-replay-frames"))
            page.fill("#replay-frame", str(int(frames * 0.55)))
            page.dispatch_event("#replay-frame", "input")
            page.screenshot(path=str(args.out / "dashboard-replay.png"), full_page=True)
            print(f"wrote {args.out / 'dashboard-replay.png'}")


if __name__ == "__main__":
    main()
