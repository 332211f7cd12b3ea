"""The dashboard's static assets: our own CSS/JS from ``api/dashboard/static/`` and plotly.min.js
straight out of the installed plotly wheel, served under ``/static`` with caching headers.

Caching rule: pages link every asset with a version in the URL (a content hash for our files,
plotly's version for plotly), so a URL always names the same bytes and may be cached for a year
as ``immutable``. A request without the current version (an old page, a hand-typed URL) gets the
bytes with ``no-cache`` and an ETag, so the browser revalidates instead of keeping stale code.
Large text assets are gzip-compressed once in memory, because plotly.min.js is 4.8 MB raw and
about a third of that compressed; the app has no compression middleware of its own.

Nothing here reads request data as a path: only names in a fixed table are served, so no
``..`` or absolute path can reach the file system. Nothing is copied into the repository.
"""

from __future__ import annotations

import gzip
import hashlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import plotly
from fastapi import APIRouter, HTTPException, Request, Response

STATIC_DIR = Path(__file__).parent / "static"
PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
PLOTLY_NAME = "vendor/plotly.min.js"

IMMUTABLE = "public, max-age=31536000, immutable"
REVALIDATE = "no-cache"

MEDIA_TYPES = {
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
    ".png": "image/png",
}
COMPRESSIBLE = {".js", ".css", ".svg"}


@dataclass
class Asset:
    """One servable file: its bytes (read once), their version, and a gzip copy when worth it."""

    path: Path
    version: str

    @cached_property
    def body(self) -> bytes:
        return self.path.read_bytes()

    @cached_property
    def gzipped(self) -> bytes | None:
        if self.path.suffix not in COMPRESSIBLE:
            return None
        # mtime=0 makes the compressed bytes depend on the content only, like the ETag.
        return gzip.compress(self.body, compresslevel=6, mtime=0)

    @property
    def etag(self) -> str:
        return f'"{self.version}"'

    @property
    def media_type(self) -> str:
        return MEDIA_TYPES.get(self.path.suffix, "application/octet-stream")


def _content_version(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


class AssetTable:
    """Every asset the dashboard may serve, by URL name, with the versioned URL pages link to."""

    def __init__(self, static_dir: Path = STATIC_DIR, plotly_js: Path = PLOTLY_JS) -> None:
        self._assets: dict[str, Asset] = {}
        for path in sorted(static_dir.rglob("*")):
            if path.is_file() and path.suffix in MEDIA_TYPES:
                name = path.relative_to(static_dir).as_posix()
                self._assets[name] = Asset(path, _content_version(path))
        if plotly_js.is_file():
            # The wheel's version names its bytes; hashing 4.8 MB at every start is not needed.
            self._assets[PLOTLY_NAME] = Asset(plotly_js, f"plotly-{plotly.__version__}")

    def get(self, name: str) -> Asset | None:
        return self._assets.get(name)

    def url(self, name: str) -> str:
        """The URL a page links: ``/static/<name>?v=<version>``; unknown names fail loudly."""
        asset = self._assets.get(name)
        if asset is None:
            raise KeyError(f"no dashboard asset named {name!r}")
        return f"/static/{name}?v={asset.version}"


def asset_router(table: AssetTable) -> APIRouter:
    """``GET /static/{name}`` for the names in ``table``, with ETag, 304 and gzip."""
    router = APIRouter(include_in_schema=False)

    @router.get("/static/{name:path}")
    def static_asset(name: str, request: Request, v: str | None = None) -> Response:
        asset = table.get(name)
        if asset is None:
            raise HTTPException(status_code=404, detail=f"no dashboard asset named {name!r}")
        headers = {
            "Cache-Control": IMMUTABLE if v == asset.version else REVALIDATE,
            "ETag": asset.etag,
            "Vary": "Accept-Encoding",
        }
        if asset.etag in request.headers.get("if-none-match", ""):
            return Response(status_code=304, headers=headers)
        body = asset.body
        if asset.gzipped is not None and "gzip" in request.headers.get("accept-encoding", ""):
            body = asset.gzipped
            headers["Content-Encoding"] = "gzip"
        return Response(content=body, media_type=asset.media_type, headers=headers)

    return router
