"""/assets: upload, list, inspect, delete, and thumbnails."""
from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Request, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError

from core.options import REPEATABLE
from service.assets import BadParameter, NotFound
from service.http.deps import client_of, get_service
from service.http.models import MEDIA_TYPES, AssetInfo, AssetList, Deleted, ErrorDetail, ThumbnailParams, render_options
from service.records import AssetRecord
from service.thumbnails import ThumbnailService

router = APIRouter(prefix="/assets", tags=["assets"])
Service = Annotated[ThumbnailService, Depends(get_service)]
ERRORS: dict[int | str, dict[str, Any]] = {code: {"model": ErrorDetail}
                                          for code in (401, 403, 404, 413, 415, 421, 422, 500, 503, 504)}


def asset_info(rec: AssetRecord) -> AssetInfo:
    fields = rec.model_dump(include=set(AssetInfo.model_fields))
    return AssetInfo(**fields, thumbnail=f"/assets/{rec.id}/thumbnail")


async def _chunks(file: UploadFile):
    while chunk := await file.read(1 << 20):
        yield chunk


@router.post("", status_code=201, response_model=AssetInfo,
             responses={200: {"model": AssetInfo, "description": "the same bytes were uploaded before"},
                        **ERRORS})
async def upload_asset(request: Request, service: Service, file: UploadFile = File(..., description="the asset, or a .zip of it"),
                       main: str | None = Form(None, description="file to ingest inside a .zip")):
    """Store an asset and bake it in the background. The id is the content hash: uploading the
    same bytes again answers 200 with the existing asset and bakes nothing."""
    rec, created = await service.assets.add_asset(file.filename or "", _chunks(file), main, client_of(request))
    return JSONResponse(asset_info(rec).model_dump(), status_code=201 if created else 200)


@router.get("", response_model=AssetList)
async def list_assets(service: Service):
    recs = sorted(service.store.assets.values(), key=lambda r: r.created)
    return AssetList(assets=[asset_info(r) for r in recs])


@router.get("/{asset_id}", response_model=AssetInfo, responses=ERRORS)
async def get_asset(asset_id: str, service: Service):
    rec = service.store.assets.get(asset_id)
    if rec is None:
        raise NotFound(asset_id)
    return asset_info(rec)


@router.delete("/{asset_id}", response_model=Deleted, responses=ERRORS)
async def delete_asset(asset_id: str, service: Service):
    await service.delete_asset(asset_id)
    return Deleted(id=asset_id)


def _query_parameters(model) -> list[dict]:
    """OpenAPI query parameters from a pydantic model (the route parses the query itself)."""
    schema = model.model_json_schema()
    return [{"name": name, "in": "query", "required": False,
             "description": prop.pop("description", ""), "schema": prop}
            for name, prop in schema["properties"].items()]


@router.get("/{asset_id}/thumbnail", response_class=Response,
            openapi_extra={"parameters": _query_parameters(ThumbnailParams)}, responses={
    200: {"content": {t: {} for t in MEDIA_TYPES.values()}, "description": "the image"},
    202: {"model": ErrorDetail, "description": "still baking: retry after Retry-After seconds"},
    304: {"description": "If-None-Match matched"}, **ERRORS})
async def thumbnail(asset_id: str, request: Request, service: Service):
    """The asset rendered with these parameters; cached on disk by (asset, normalised
    parameters, renderer version) and served from there without a worker once made.

    This is the hot path: the query is validated here with the pydantic model directly,
    which costs a fraction of FastAPI's per-parameter query-model machinery."""
    try:
        query: dict[str, Any] = dict(request.query_params)
        for name in REPEATABLE & query.keys():  # variant_set=A&variant_set=B: every value, in order
            query[name] = request.query_params.getlist(name)
        params: Any = ThumbnailParams.model_validate(query)  # fields made by create_model
        options = render_options(params)
    except ValidationError as exc:
        raise RequestValidationError([dict(e, loc=("query", *e["loc"])) for e in
                                      exc.errors(include_url=False, include_context=False)]) from None
    except ValueError as exc:  # parameters that are valid alone but not together (format, turntable)
        raise BadParameter(str(exc)) from None
    if asset_id not in service.store.assets:
        raise NotFound(asset_id)
    options = service.admit(options)
    env_identity, env_source = service.assets.resolve_environment(params.env)
    if params.env is None:  # the asset's own lighting may replace it (pipeline.lighting)
        env_identity += " (default)"
    key = service.thumbnail_key(asset_id, options, env_identity)
    hit = service.cached(asset_id, key, params.format)
    outcome = "hit"
    if hit is None:
        outcome = "miss"
        service.check_may_render(service.store.assets[asset_id], options, client_of(request),
                                 request.scope.get("state", {}).get("anonymous", False))
        hit = await service.render(asset_id, options, params.format, key, env_source, client_of(request),
                                   env_default=params.env is None)
    data, etag, plan = hit
    headers = {"ETag": etag, "Cache-Control": f"public, max-age={service.settings.cache_max_age}",
               "X-Render-Plan": plan.to_json()}
    if_none_match = request.headers.get("if-none-match")
    if if_none_match and _matches(if_none_match, etag):
        service.metrics.thumbnail("not_modified")
        return Response(status_code=304, headers=headers)
    service.metrics.thumbnail(outcome)
    return Response(data, media_type=MEDIA_TYPES[params.format], headers=headers)


def _matches(header: str, etag: str) -> bool:
    """If-None-Match uses the weak comparison (RFC 9110 13.1.2)."""
    if header.strip() == "*":
        return True
    return any(t.strip().removeprefix("W/") == etag for t in header.split(","))
