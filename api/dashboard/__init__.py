"""The web dashboard that ``demcal serve`` shows at ``/``: server-rendered page shells, their
static assets (plotly.min.js from the installed plotly wheel, no Node build), and the two JSON
routes the API lacks for it: a trial's snapshot replay and TOML-to-JSON for the new-study form.

The pages read study data only through the public JSON API under ``/api/v1`` with the user's API
key, like any other client; this package must not query the store for them. ``create_app``
includes :func:`dashboard_router` once.
"""

from __future__ import annotations

from fastapi import APIRouter

from api.dashboard.assets import AssetTable, asset_router
from api.dashboard.definition import router as definition_router
from api.dashboard.pages import page_router
from api.dashboard.replay import router as replay_router


def dashboard_router() -> APIRouter:
    """Pages at ``/``, ``/new``, ``/studies/{id}``, ``/trials/{id}``; assets at ``/static``;
    the replay JSON under ``/api/v1``; ``POST /dashboard/definition`` for TOML uploads."""
    assets = AssetTable()
    router = APIRouter()
    router.include_router(asset_router(assets))
    router.include_router(page_router(assets))
    router.include_router(replay_router)
    router.include_router(definition_router)
    return router
