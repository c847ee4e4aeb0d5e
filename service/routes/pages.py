"""GET /: an upload form and a grid of the stored assets' thumbnails."""
from __future__ import annotations

import html
from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.responses import HTMLResponse

from ..core import ThumbnailService
from ..deps import get_service

router = APIRouter(tags=["pages"])

_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>asset-preview</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>
 body {{ font: 14px system-ui, sans-serif; margin: 1.5rem; background: #f4f4f4; color: #222 }}
 form {{ margin-bottom: 1.5rem; display: flex; gap: .5rem; align-items: center; flex-wrap: wrap }}
 .grid {{ display: grid; grid-template-columns: repeat(auto-fill, minmax(256px, 1fr)); gap: 1rem }}
 figure {{ margin: 0; background: #fff; border-radius: 6px; overflow: hidden; box-shadow: 0 1px 3px #0002 }}
 figure img {{ width: 100%; aspect-ratio: 1; display: block; background: #ddd }}
 figcaption {{ padding: .5rem .7rem; display: flex; justify-content: space-between; gap: .5rem }}
 .failed {{ color: #b00 }} .baking {{ color: #a60 }} small {{ color: #777 }}
</style></head><body>
<h1>asset-preview</h1>
<form id="upload"><input type="file" name="file" required>
 <input type="password" id="key" placeholder="API key (if set)">
 <button>Upload</button> <span id="msg"></span>
 <span style="margin-left:auto"><a href="/docs">API</a> · <a href="/metrics">metrics</a> · {count} assets</span></form>
<div class="grid">{cards}</div>
<script>
// A thumbnail of an asset still baking answers 202: try again a little later.
document.querySelectorAll("img[data-src]").forEach(img => {{
  let tries = 0;
  img.onerror = () => {{ if (tries++ < 60) setTimeout(() => img.src = img.dataset.src + "&t=" + tries, 3000); }};
  img.src = img.dataset.src;
}});
// While assets are arriving (seeding at start-up, other uploaders), show them as they land.
setInterval(async () => {{
  const r = await fetch("/assets");
  if (r.ok && (await r.json()).assets.length !== {count}) location.reload();
}}, 4000);
document.getElementById("upload").onsubmit = async e => {{
  e.preventDefault();
  const msg = document.getElementById("msg"), key = document.getElementById("key").value;
  msg.textContent = "uploading...";
  const r = await fetch("/assets", {{method: "POST", body: new FormData(e.target),
    headers: key ? {{Authorization: "Bearer " + key}} : {{}}}});
  const body = await r.json();
  if (r.ok) location.reload(); else msg.textContent = "error " + r.status + ": " + body.detail;
}};
</script></body></html>
"""


@router.get("/", response_class=HTMLResponse, include_in_schema=False)
async def index(service: Annotated[ThumbnailService, Depends(get_service)]):
    cards = []
    for rec in sorted(service.store.assets.values(), key=lambda r: r.created):
        name = html.escape(rec.name)
        status = rec.status
        note = html.escape(rec.reason or "") if status == "failed" else f"{rec.triangles:,} triangles"
        img = "" if status == "failed" else f'<img alt="{name}" data-src="/assets/{rec.id}/thumbnail?size=256">'
        cards.append(f'<figure>{img}<figcaption><span>{name}<br><small>{note}</small></span>'
                     f'<span class="{status}">{status}</span></figcaption></figure>')
    return HTMLResponse(_PAGE.format(cards="".join(cards), count=len(cards)))
