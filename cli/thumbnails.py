"""`asset-bake --thumbnails DIR`: thumbnails of every baked asset of a library, in this process.

After the bake (in this process, worker processes or Ray tasks), each asset is loaded from the
cache by its key and rendered with the render options of the one schema (`core/options.py`:
size, views, turntable, method, ...) through this process's single GL context, so a library
of thousands costs one context and one shader compilation, not one process per file.

Files go to DIR under the asset's path relative to the folder it was found in (`gltf/Duck.glb`
-> `DIR/gltf/Duck.glb.png`). `DIR/manifest.json` records per asset its cache key, the options,
the files, the asset's warnings and the seconds spent; a re-run renders only assets whose key
(their content) or options changed, or whose files are gone.
"""
from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any

from core.errors import AssetError
from core.options import RenderOptions

MANIFEST = "manifest.json"
FORMATS = ("png", "jpg", "webp", "gif")


def check_format(fmt: str, options: RenderOptions) -> str | None:
    """Why `fmt` cannot hold these thumbnails, or None."""
    if fmt not in FORMATS:
        return f"--thumbnail-format {fmt}: use one of {', '.join(FORMATS)}"
    if options.turntable and fmt not in ("webp", "gif"):
        return "--turntable writes an animated webp or gif: add --thumbnail-format webp"
    if fmt == "gif" and not options.turntable:
        return "--thumbnail-format gif is for --turntable; use png, jpg or webp"
    return None


class Thumbnails:
    """Renders one asset at a time into `out`, keeping the manifest up to date on disk."""

    def __init__(self, out: Path, cache: str | None, options: RenderOptions, fmt: str,
                 env: str | None, quality: int | None = None):
        self.out, self.cache, self.options, self.fmt = Path(out), cache, options, fmt
        self.env_source, self.quality = env, quality
        self.out.mkdir(parents=True, exist_ok=True)
        self.manifest_path = self.out / MANIFEST
        try:
            self.entries: dict[str, dict] = json.loads(self.manifest_path.read_text())["assets"]
        except FileNotFoundError:
            self.entries = {}
        except (ValueError, KeyError, TypeError):  # unreadable: start over rather than trust it
            self.entries = {}
        # JSON round-trip: the manifest compares what it stored (tuples come back as lists)
        self.signature = json.loads(json.dumps({"options": dataclasses.asdict(options), "format": fmt,
                                                "env": env}, default=str))
        self._envs: dict[int, Any] = {}

    def name_for(self, path: str, folder: str | None) -> str:
        rel = os.path.relpath(path, folder) if folder else os.path.basename(path)
        if rel.startswith(".."):
            rel = os.path.basename(path)
        return Path(rel).as_posix() + "." + self.fmt

    def add(self, result: dict, folder: str | None) -> dict:
        """Thumbnail the asset of one bake result; returns the manifest entry (status
        `rendered`, `kept` when nothing changed, or `failed` with the reason)."""
        path = result["path"]
        entry: dict[str, Any]
        if result.get("status") == "failed" or result.get("kind") != "asset":
            entry = {"asset": path, "status": "failed", "error": result.get("error", "not baked"),
                     "files": [], "warnings": [], "seconds": 0.0}
            self._store(path, entry)
            return entry
        name = self.name_for(path, folder)
        old = self.entries.get(path)
        if (old and old.get("status") != "failed" and old.get("key") == result["key"]
                and old.get("signature") == self.signature
                and all((self.out / f).is_file() for f in old.get("files", []))):
            return {**old, "status": "kept"}
        start = time.perf_counter()
        entry = {"asset": path, "key": result["key"], "signature": self.signature}
        try:
            entry.update(self._render(result["key"], name))
            entry["status"] = "rendered"
        except (AssetError, ValueError, OSError) as exc:
            entry.update(status="failed", error=f"{path}: {exc}", files=[], warnings=[])
        entry["seconds"] = round(time.perf_counter() - start, 4)
        self._store(path, entry)
        return entry

    def _environment(self, asset, options):
        from pipeline.bake import bake_environment
        from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
        from renderer.methods.auto import environment_face_size

        face, _ = environment_face_size(asset, options)
        if face not in self._envs:
            self._envs[face] = bake_environment(self.env_source or DEFAULT_ENVIRONMENT,
                                                self.cache, face_size=face)
        return self._envs[face]

    def _render(self, key: str, name: str) -> dict:
        from pipeline.bake import load_baked
        from renderer import render
        from renderer.sequence import encode_animation, render_turntable, render_views

        asset = load_baked(key, self.cache)
        env = self._environment(asset, self.options)
        target = self.out / name
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(target.name + ".tmp")
        if self.options.turntable:
            data = encode_animation(render_turntable(asset, env, self.options, keep_linear=False),
                                    self.fmt, self.quality)
        else:
            frame = (render_views if self.options.views else render)(asset, env, self.options)
            data = frame.encode(self.fmt, self.quality)
        tmp.write_bytes(data)
        os.replace(tmp, target)  # a reader never sees half a file
        return {"files": [name], "warnings": list(asset.warnings)}

    def _store(self, path: str, entry: dict) -> None:
        self.entries[path] = entry
        tmp = self.manifest_path.with_name(MANIFEST + ".tmp")
        tmp.write_text(json.dumps({"assets": self.entries}, indent=1, sort_keys=True))
        os.replace(tmp, self.manifest_path)
