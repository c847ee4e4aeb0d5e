"""GET /: the asset page (service/static: cards with live status, upload with progress, a detail
view with render controls); GET /static/NAME: its script and style. No CDN: works offline."""
from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse

from service.assets import NotFound
from service.http.models import ThumbnailParams

router = APIRouter(tags=["pages"])
STATIC = Path(__file__).resolve().parent.parent / "static"
_FILES = {"page.js": "text/javascript", "page.css": "text/css"}
_CONTROLS = ("yaw", "pitch", "method", "background", "shadow", "size")


@lru_cache(maxsize=1)
def _page() -> str:
    """index.html with the thumbnail defaults (one declaration: core.options) inlined."""
    fields = ThumbnailParams.model_fields
    defaults = {name: fields[name].default for name in _CONTROLS}
    script = ('<script id="defaults" type="application/json">'
              + json.dumps(defaults).replace("<", "\\u003c") + "</script>\n")
    return (STATIC / "index.html").read_text().replace('<script src="/static/page.js">',
                                                      script + '<script src="/static/page.js">')


@router.get("/", response_class=HTMLResponse, include_in_schema=False)
async def index():
    return HTMLResponse(_page())


@router.get("/favicon.ico", include_in_schema=False)
async def favicon():
    return FileResponse(STATIC / "icon.svg", media_type="image/svg+xml", headers={"Cache-Control": "max-age=86400"})


@router.get("/static/{name}", include_in_schema=False)
async def static(name: str):
    if name not in _FILES:
        raise NotFound(name)
    return FileResponse(STATIC / name, media_type=_FILES[name], headers={"Cache-Control": "no-cache"})
