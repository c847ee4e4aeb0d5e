"""Limits on untrusted input, from flags, then ASSET_PREVIEW_* variables, then defaults."""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Limits:
    max_file_bytes: int = 512 * 2**20          # any single file read
    max_vertices: int = 20_000_000
    max_triangles: int = 20_000_000
    max_texture_pixels: int = 8192 * 8192      # per image, checked from the header
    max_textures: int = 512
    max_unpacked_bytes: int = 1 * 2**30        # usdz / zip / decoded images in total
    max_archive_files: int = 10_000
    max_nodes: int = 1_000_000
    ingest_seconds: float = 120.0

    @classmethod
    def from_env(cls, **overrides) -> "Limits":
        """Defaults, overridden by ASSET_PREVIEW_<FIELD> variables, overridden by arguments."""
        values: dict[str, Any] = {}
        for field in dataclasses.fields(cls):
            raw = os.environ.get(f"ASSET_PREVIEW_{field.name.upper()}")
            if raw is not None:
                values[field.name] = float(raw) if field.type == "float" else int(float(raw))
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)


DEFAULT = Limits()
