"""/environments: bundled panoramas and uploaded ones."""
from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, UploadFile
from fastapi.responses import JSONResponse

from service.http.deps import get_service
from service.http.models import EnvironmentInfo, EnvironmentList, ErrorDetail
from service.thumbnails import ThumbnailService

router = APIRouter(prefix="/environments", tags=["environments"])
Service = Annotated[ThumbnailService, Depends(get_service)]


@router.get("", response_model=EnvironmentList)
async def list_environments(service: Service):
    default = service.assets.default_environment()
    envs = [EnvironmentInfo(name=n, source="bundled", default=n == default)
            for n in service.assets.bundled_environments()]
    envs += [EnvironmentInfo(name=r.name, source="uploaded", id=r.id)
             for r in sorted(service.store.environments.values(), key=lambda r: r.created)]
    return EnvironmentList(environments=envs)


@router.post("", status_code=201, response_model=EnvironmentInfo,
             responses={code: {"model": ErrorDetail} for code in (401, 403, 409, 413, 415, 421, 422, 503)})
async def upload_environment(service: Service,
                             file: UploadFile = File(..., description="equirectangular panorama: .jpg .png (sRGB) or .hdr .exr (linear)"),
                             name: str | None = Form(None, description="name for `env=`; default the file's stem")):
    """Store a panorama; it is prefiltered at once, so a bad file is refused here."""
    async def chunks():
        while chunk := await file.read(1 << 20):
            yield chunk
    rec, created = await service.assets.add_environment(file.filename or "", chunks(), name)
    info = EnvironmentInfo(name=rec.name, source="uploaded", id=rec.id)
    return JSONResponse(info.model_dump(), status_code=201 if created else 200)
