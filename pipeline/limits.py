"""Limits on untrusted input and the pipeline's own knobs: flags, then ASSET_PREVIEW_* variables,
then defaults (core.config.FromEnv; one declaration per knob, read once per process)."""
from __future__ import annotations

import dataclasses
from functools import lru_cache
from pathlib import Path

from core.config import FromEnv
from core.schema import knob


@dataclasses.dataclass(frozen=True, init=False)
class Limits(FromEnv):
    max_file_bytes: int = knob(512 * 2**20, ge=0, description="any single file read")
    max_vertices: int = knob(20_000_000, ge=0, description="vertices in one asset")
    max_triangles: int = knob(20_000_000, ge=0, description="triangles in one asset")
    max_texture_pixels: int = knob(8192 * 8192, ge=0, description="per image, checked from the header")
    max_textures: int = knob(512, ge=0, description="textures in one asset")
    max_udim_tiles: int = knob(100, ge=0, description="tiles of one UDIM texture (1001-1100 all)")
    max_unpacked_bytes: int = knob(1 * 2**30, ge=0, description="usdz / zip / decoded images in total")
    max_archive_files: int = knob(10_000, ge=0, description="members of an uploaded .zip")
    max_archive_ratio: float = knob(200.0, ge=1, description="unpacked bytes per byte of an uploaded .zip "
                                     "(a bomb inflates far more; real assets 1-10x)")
    max_archive_depth: int = knob(32, ge=0, description="folders deep a .zip member may sit")
    max_name_length: int = knob(255, ge=0, description="characters in one .zip member's name part")
    max_nodes: int = knob(1_000_000, ge=0, description="scene graph nodes / USD prims")
    ingest_seconds: float = knob(120.0, ge=0, description="time bound of reading one asset (IngestTimeout past it)")


@dataclasses.dataclass(frozen=True, init=False)
class PipelineSettings(FromEnv):
    """Where bakes go, and `asset-bake`'s defaults (the service passes its own)."""
    cache: Path = knob(Path(".cache"), description="bake cache folder")
    cache_max_bytes: str | None = knob(None, description="bake cache cap (e.g. 2G, binary units); LRU eviction past it")
    bake_workers: int = knob(1, ge=1, description="`asset-bake` processes")
    executor: str = knob("local", pattern="^(local|ray)$", description="local processes or Ray")
    face_size: int = knob(256, ge=8, description="environment cube face size `asset-bake` bakes")


DEFAULT = Limits.defaults()  # the declared defaults, whatever the environment says


@lru_cache(maxsize=1)
def pipeline_settings() -> PipelineSettings:
    """The environment's pipeline settings, read once."""
    return PipelineSettings()
