"""The dashboard's HTML pages: ``/`` (studies), ``/studies/{id}``, ``/trials/{id}`` and ``/new``.

Each page is a server-rendered shell (Jinja2, autoescaped) that names what it shows and loads one
script; the script reads everything else from the JSON API under ``/api/v1`` with the user's API
key, exactly like any other client. So the shells need no key and touch no database: they must
never render study data, or the API's owner rules would be bypassed.
"""

from __future__ import annotations

import re
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import HTMLResponse
from jinja2 import Environment, FileSystemLoader, select_autoescape

from api import __version__
from api.dashboard.assets import AssetTable

TEMPLATE_DIR = Path(__file__).parent / "templates"

# The shells change with the code, not with the data; a short private cache keeps navigation
# snappy while a new deployment shows up within a minute.
PAGE_CACHE = "private, max-age=60"

# Trial ids are ``{study_id}-i{individual:05d}-r{replicate:02d}`` (optimizer.protocols.trial_id),
# so a trial's page knows its study without asking the database.
TRIAL_ID = re.compile(r"^(?P<study>.+)-i\d+-r\d+$")


def study_of_trial(trial_id: str) -> str | None:
    """The study id inside a trial id, or None when the id does not have the trial-id shape."""
    match = TRIAL_ID.match(trial_id)
    return match.group("study") if match else None


def page_router(assets: AssetTable, api_prefix: str = "/api/v1") -> APIRouter:
    """The four page routes, rendering templates with ``static_url`` for versioned assets."""
    env = Environment(
        loader=FileSystemLoader(TEMPLATE_DIR),
        autoescape=select_autoescape(["html"]),
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.globals.update(static_url=assets.url, version=__version__, api_prefix=api_prefix)
    router = APIRouter(include_in_schema=False)

    def render(template: str, **context) -> HTMLResponse:
        html = env.get_template(template).render(**context)
        return HTMLResponse(html, headers={"Cache-Control": PAGE_CACHE})

    @router.get("/", response_class=HTMLResponse)
    def studies_page() -> HTMLResponse:
        return render("studies.html", title="Studies", nav="studies")

    @router.get("/new", response_class=HTMLResponse)
    def new_study_page() -> HTMLResponse:
        return render("new.html", title="New study", nav="new")

    @router.get("/studies/{study_id}", response_class=HTMLResponse)
    def study_page(study_id: str) -> HTMLResponse:
        return render("study.html", title=f"Study {study_id}", nav="studies", study_id=study_id)

    @router.get("/trials/{trial_id}", response_class=HTMLResponse)
    def trial_page(trial_id: str) -> HTMLResponse:
        return render(
            "trial.html", title=f"Trial {trial_id}", nav="studies", trial_id=trial_id,
            study_id=study_of_trial(trial_id),
        )

    return router
