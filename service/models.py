"""Pydantic models for every request and response (they are the OpenAPI schema at /docs)."""
from __future__ import annotations

import re
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from pipeline.panorama import srgb_to_linear

AssetStatus = Literal["baking", "ready", "failed"]
ImageFormat = Literal["png", "jpeg", "webp"]
MEDIA_TYPES = {"png": "image/png", "jpeg": "image/jpeg", "webp": "image/webp"}
_HEX = re.compile(r"^#?([0-9a-fA-F]{6})$")


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


class Ready(BaseModel):
    ready: bool = Field(description="a render worker has answered since it (re)started")
    renderer_version: str | None = None
    gl_renderer: str | None = None
    queue: int = Field(description="renders waiting or running")
    workers: list[WorkerStatus]


class ThumbnailParams(BaseModel):
    """Query parameters of GET /assets/{id}/thumbnail. Colours are sRGB hex `RRGGBB`."""
    model_config = ConfigDict(extra="forbid")

    size: int = Field(256, ge=1, description="width and height, unless those are given")
    width: int | None = Field(None, ge=1)
    height: int | None = Field(None, ge=1)
    format: ImageFormat = "png"
    env: str | None = Field(None, description="environment name (GET /environments); default bundled")
    yaw: float = Field(30.0, ge=-3600, le=3600, description="degrees; positive turns toward +X")
    pitch: float = Field(15.0, ge=-90, le=90, description="degrees; positive looks down from above")
    fov: float = Field(40.0, gt=1, lt=170, description="vertical field of view, degrees")
    method: Literal["auto", "opaque", "single", "wyman"] = "auto"
    background: str = Field("env", description="env | transparent | RRGGBB")
    tonemap: Literal["neutral", "aces", "none"] = "neutral"
    exposure: float = Field(0.0, ge=-16, le=16, description="stops")
    base_color: str | None = Field(None, description="override base colour, RRGGBB")
    metallic: float | None = Field(None, ge=0, le=1)
    roughness: float | None = Field(None, ge=0, le=1)
    ior: float | None = Field(None, ge=1, le=3)
    transmission: float | None = Field(None, ge=0, le=1)
    budget_ms: float | None = Field(None, gt=0, le=600_000, description=(
        "time budget for method=auto: lets it ray trace objects where raster refraction fails"))

    @field_validator("background")
    @classmethod
    def _background(cls, v: str) -> str:
        v = v.strip().lower()
        if v in ("env", "transparent"):
            return v
        m = _HEX.match(v)
        if not m:
            raise ValueError("background must be env, transparent or a colour RRGGBB")
        return "#" + m.group(1).lower()

    @field_validator("base_color")
    @classmethod
    def _base_color(cls, v: str | None) -> str | None:
        if v is None:
            return None
        m = _HEX.match(v.strip())
        if not m:
            raise ValueError("base_color must be a colour RRGGBB")
        return m.group(1).lower()

    def dimensions(self) -> tuple[int, int]:
        return self.width or self.size, self.height or self.size


def srgb_hex_to_linear(hex6: str) -> tuple[float, float, float]:
    """'rrggbb' (sRGB, as people pick colours) -> linear RGB, as the renderer shades."""
    rgb8 = np.array([int(hex6[i:i + 2], 16) for i in (0, 2, 4)], np.uint8)
    return tuple(round(float(c), 6) for c in srgb_to_linear(rgb8))
