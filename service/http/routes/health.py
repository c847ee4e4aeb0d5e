"""Liveness, readiness and Prometheus metrics."""
from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse, PlainTextResponse

from service.http.deps import get_service
from service.http.metrics import CONTENT_TYPE
from service.http.models import Health, Ready
from service.thumbnails import ThumbnailService

router = APIRouter(tags=["operations"])
Service = Annotated[ThumbnailService, Depends(get_service)]


@router.get("/healthz", response_model=Health)
async def healthz():
    """The server process answers (it does not look at the workers)."""
    return Health()


@router.get("/readyz", response_model=Ready, responses={503: {"model": Ready}})
async def readyz(service: Service):
    """Ready when a render worker has answered since it (re)started; lists the workers."""
    pool = service.pool
    body = Ready(ready=pool.ready, renderer_version=service.renderer_version,
                 gl_renderer=pool.info.gl_renderer if pool.info else None, queue=pool.pending, workers=pool.status())
    return JSONResponse(body.model_dump(), status_code=200 if body.ready else 503)


@router.get("/metrics", response_class=PlainTextResponse)
async def metrics(service: Service):
    """Prometheus text format 0.0.4."""
    return PlainTextResponse(service.metrics.render_text(), media_type=CONTENT_TYPE)
