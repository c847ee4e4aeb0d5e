"""What the service stores about each upload: typed records, kept as record.json on disk.

Frozen: a change is a new record (`model_copy(update=...)`) written whole, so a reader never
sees half an update. Unknown fields in an old record.json are ignored.
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict

AssetStatus = Literal["baking", "ready", "failed"]


class AssetRecord(BaseModel):
    model_config = ConfigDict(frozen=True, extra="ignore")

    id: str
    name: str                       # the uploaded file's (safe) name
    root: str                       # the file ingested, relative to the upload's src/ folder
    size: int                       # uploaded bytes
    stored_bytes: int = 0           # bytes kept on disk (unreferenced zip members dropped)
    owner: str | None = None        # "key:<fingerprint>" of the API key that uploaded it
    status: AssetStatus = "baking"
    reason: str | None = None       # why the bake failed
    created: float
    updated: float | None = None
    format: str = ""
    triangles: int = 0
    materials: int = 0
    transmissive: bool = False      # some material transmits (the cost estimate's wyman case)
    emitters: int = 0               # emissive triangles as rendered (the ray tracer samples them: cost)
    warnings: list[str] = []
    bake_key: str | None = None


class EnvironmentRecord(BaseModel):
    model_config = ConfigDict(frozen=True, extra="ignore")

    id: str
    name: str                       # the value of `env=`
    file: str
    size: int
    created: float
