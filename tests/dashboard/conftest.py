"""Fixtures for the dashboard's browser tests: the real app (``create_app``, dashboard included)
on a migrated SQLite file seeded through the real store, served by uvicorn in a thread on a free
port, and headless Debian Chromium driven by Playwright.

No browser is ever downloaded: Chromium must be ``/usr/bin/chromium`` (Debian's ``chromium``
package; ``.ci/run`` installs it). Without it the tests skip with a reason, or fail with
``CI=true``. Screenshots go to ``test-artifacts/`` (gitignored); the README's pictures come
from ``tests/dashboard/screenshots.py``.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from api.store import SqlStore
from tests.conftest import missing
from tests.dashboard.seed import SeededStudy, migrated_store, seed_study, snapshot_run

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    # WebGL (plotly's scattergl, used above 1,500 points) runs on SwiftShader without a GPU.
    "--enable-unsafe-swiftshader",
]
REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts"
RETAINED_IN_REPLAY = [i % 4 == 0 for i in range(12)]


@dataclass
class Dashboard:
    base_url: str
    study: SeededStudy
    store: SqlStore

    def url(self, path: str) -> str:
        return self.base_url + path


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextlib.contextmanager
def serving(settings, start_within_s: float = 20.0) -> Iterator[str]:
    """The app of ``settings`` served by uvicorn in a thread on 127.0.0.1:<free port>; yields its
    base URL (the browser tests, ``screenshots.py`` and ``benchmarks/dashboard_render.py``)."""
    import uvicorn

    from api.app import create_app

    port = _free_port()
    config = uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + start_within_s
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError(f"uvicorn did not start the dashboard within {start_within_s:g} s")
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)


@pytest.fixture(scope="session")
def dashboard(tmp_path_factory):
    """The app on a seeded SQLite store, listening on 127.0.0.1:<free port> until the session ends."""
    from api.settings import load_settings

    root = tmp_path_factory.mktemp("dashboard")
    url = f"sqlite:///{root / 'demcal.db'}"
    store = migrated_store(url)
    study = seed_study(store)
    study.replay_trial_id = study.trial_ids[5]
    settings = load_settings(database_url=url, data_dir=root / "data")
    snapshot_run(settings.snapshot_root / study.replay_trial_id, len(RETAINED_IN_REPLAY), RETAINED_IN_REPLAY)
    with serving(settings) as base_url:
        yield Dashboard(base_url, study, store)
    store.engine.dispose()


@pytest.fixture(scope="session")
def browser():
    """Headless Debian Chromium; skipped (failed with CI=true) when it is not installed."""
    if not CHROMIUM.is_file():
        missing(
            "Chromium", f"{CHROMIUM} is missing: install Debian's chromium and chromium-driver (see .ci/run)"
        )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture(scope="session")
def browser_context(browser, dashboard):
    """One laptop-sized browser profile whose localStorage holds the seeded owner's API key.
    Shared by the tests so that plotly.min.js comes from the HTTP cache after the first page,
    as it does for a user; the pages keep no other state."""
    context = browser.new_context(viewport={"width": 1440, "height": 900})
    context.add_init_script(f"localStorage.setItem('demcal.apiKey', {dashboard.study.api_key!r})")
    yield context
    context.close()


@pytest.fixture
def page(browser_context):
    """A fresh tab; page errors are collected in ``page.errors`` so a test can assert there were none."""
    tab = browser_context.new_page()
    tab.set_default_timeout(15_000)
    tab.errors = []
    tab.on("pageerror", lambda error: tab.errors.append(str(error)))
    yield tab
    tab.close()


def save_screenshot(page, name: str) -> Path:
    """A full-page PNG under test-artifacts/, for a person to look at after a run."""
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)
    return path
