"""Pydantic models for every request and response (they are the OpenAPI schema at /docs)."""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model

from core.options import RenderOptions, from_request, request_fields
from core.schema import pydantic_field

AssetStatus = Literal["baking", "ready", "failed"]
ImageFormat = Literal["png", "jpeg", "webp", "gif"]
MEDIA_TYPES = {"png": "image/png", "jpeg": "image/jpeg", "webp": "image/webp", "gif": "image/gif"}


class ErrorDetail(BaseModel):
    detail: str = Field(description="what went wrong; for a rejected asset `FILE: REASON`")


class AssetInfo(BaseModel):
    id: str = Field(description="SHA-256 (first 32 hex digits) of the uploaded bytes")
    name: str = Field(description="uploaded file name")
    format: str = Field(description="format the pipeline read (gltf, usd, ply, ...)")
    triangles: int
    materials: int
    status: AssetStatus
    reason: str | None = Field(None, description="why the bake failed, when it did")
    size: int = Field(description="uploaded bytes")
    created: float = Field(description="Unix time of the upload")
    warnings: list[str] = []
    thumbnail: str = Field(description="URL of the default thumbnail")


class AssetList(BaseModel):
    assets: list[AssetInfo]


class CostEstimate(BaseModel):
    method: str = Field(description="the method asked for (auto, opaque, ..., raytrace)")
    width: int
    height: int
    estimated_ms: float = Field(description="the admission model's estimate (renderer.methods.auto)")
    ceiling_ms: float = Field(description="the most this caller may be rendered, by estimate")
    cached: bool = Field(description="already rendered: served at once, whatever it cost")
    refused: str | None = Field(None, description="why a thumbnail with these parameters would be refused")


class Deleted(BaseModel):
    id: str
    deleted: bool = True


class EnvironmentInfo(BaseModel):
    name: str = Field(description="value for the thumbnail's `env` parameter")
    source: Literal["bundled", "uploaded"]
    id: str | None = Field(None, description="content hash of an uploaded panorama")
    default: bool = False


class EnvironmentList(BaseModel):
    environments: list[EnvironmentInfo]


class Health(BaseModel):
    status: Literal["ok"] = "ok"


class WorkerStatus(BaseModel):
    index: int
    pid: int | None
    alive: bool
    busy: bool
    op: str | None = Field(None, description="job running now (render, bake, ...)")
    busy_seconds: float | None = None
    jobs: int
    restarts: int
    rss_bytes: int | None = Field(None, description="the worker's resident memory after its last job")


class Ready(BaseModel):
    ready: bool = Field(description="a render worker has answered since it (re)started")
    renderer_version: str | None = None
    gl_renderer: str | None = None
    queue: int = Field(description="renders waiting or running")
    workers: list[WorkerStatus]


def _thumbnail_params() -> type[BaseModel]:
    """Query parameters of GET /assets/{id}/thumbnail: the flat render request
    (core.options.request_fields, the single schema) plus the image format and the
    environment, which choose what is encoded and what is baked rather than how it renders."""
    fields: dict[str, Any] = {name: pydantic_field(info) for name, info in request_fields().items()}
    fields["format"] = (ImageFormat, Field("png", description="image encoding"))
    fields["env"] = (str | None, Field(None, description=(
        "environment name (GET /environments); default the bundled one")))
    model = create_model("ThumbnailParams", __config__=ConfigDict(extra="forbid", allow_inf_nan=False), **fields)
    model.__doc__ = _thumbnail_params.__doc__
    return model


ThumbnailParams = _thumbnail_params()


def render_options(params: BaseModel) -> RenderOptions:
    """The RenderOptions of validated thumbnail parameters (ValueError when they conflict)."""
    fmt = params.model_dump(include={"format"})["format"]
    options = from_request(params.model_dump(exclude={"format", "env"}))
    if options.animate and fmt not in ("webp", "gif", "png"):
        raise ValueError("animate needs format webp, gif or png (APNG)")
    if options.turntable and not options.animate and fmt not in ("webp", "gif"):
        raise ValueError("turntable needs format webp or gif (an animated image)")
    if fmt == "gif" and not (options.turntable or options.animate):
        raise ValueError("format gif is for turntables; use png, jpeg or webp")
    return options
