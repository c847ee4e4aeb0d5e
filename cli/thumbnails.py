"""`asset-bake --thumbnails DIR`: thumbnails of every baked asset of a library.

Each asset is rendered where it was baked: `Renderer` runs right after the bake, in the same
process (the driver with --workers 1, a pool process with --workers N, a Ray task with
--executor ray), so the bake entry it loads was just written on that machine and the render
costs no transfer. Every such process keeps its one headless GL context (gl/context.py) and
its environments across assets, so a library of thousands costs one context and one shader
compilation per worker process, not one per file.

A render goes through the content-addressed cache: its key hashes the asset's key, the
environment's key, every render option, the file format and quality, and the renderer's
version; the encoded file is stored as the cache entry `thumbnails/<key>/` (built in the
cache's tmp/ and renamed into place, so a process killed mid-render leaves no entry, only a
tmp/ leftover the cache sweeps). The driver alone then puts the file into DIR (a hard link to
the entry's file where the filesystem allows, else a copy; written under a temporary name and
renamed), so a lost worker node cannot leave half a thumbnail in DIR either.

Files go to DIR under the asset's path relative to the folder it was found in (`gltf/Duck.glb`
-> `DIR/gltf/Duck.glb.png`). `DIR/manifest.json` records the render settings once, and per asset its
cache key, the thumbnail's key, the digest of the settings, the files, the asset's warnings,
the seconds its render took and which process (and Ray node) rendered it. A re-run
renders only assets whose key (their content) or options changed: an unchanged asset whose
file is in DIR is `kept` (not even loaded), one whose file is gone but whose render is in
the cache is `cached` (put back from there), the rest are `rendered`. (`kept` compares the
asset's key and the options, environment name included, not the environment file's bytes:
after editing a panorama in place, re-run with the same options into a fresh DIR.)
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from core.errors import AssetError
from core.options import RenderOptions

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"
FORMATS = ("png", "jpg", "webp", "gif")
# Bumped when what a thumbnail entry holds changes (the renderer's own version covers pixels).
THUMBNAIL_FORMAT = 1
MANIFEST_EVERY_S = 0.5


def check_format(fmt: str, options: RenderOptions) -> str | None:
    """Why `fmt` cannot hold these thumbnails, or None."""
    if fmt not in FORMATS:
        return f"--thumbnail-format {fmt}: use one of {', '.join(FORMATS)}"
    if options.turntable and fmt not in ("webp", "gif"):
        return "--turntable writes an animated webp or gif: add --thumbnail-format webp"
    if fmt == "gif" and not options.turntable:
        return "--thumbnail-format gif is for --turntable; use png, jpg or webp"
    return None


# Environments of this process by (source, cache, face size): kept across the assets a worker
# renders, like its GL context.
_ENVS: dict[tuple, Any] = {}


@dataclasses.dataclass(frozen=True)
class Renderer:
    """What to render after a bake; small and picklable, it travels with the tasks. Called
    as `renderer(result, known)` on the bake result where the bake ran; `known` is what the
    driver's DIR already holds for this asset with these options ({"key": asset key,
    "thumbnail": its key}): the same asset key then means nothing to do, not even a load.
    Returns the result with a `render` record; never raises."""

    options: RenderOptions
    fmt: str
    env: str | None
    quality: int | None
    cache: str  # absolute: the same cache root on every node

    def __call__(self, result: dict, known: dict | None = None) -> dict:
        if result.get("kind") != "asset" or result.get("status") not in ("baked", "cached"):
            return result
        if known and known.get("key") == result["key"]:
            return {**result, "render": {"status": "kept", "key": known["thumbnail"], "seconds": 0.0}}
        start = time.perf_counter()
        try:
            record = self._thumbnail(result["key"])
        except (AssetError, ValueError, OSError) as exc:
            record = {"status": "failed", "error": f"{result['path']}: {exc}"}
        except Exception as exc:  # a bug or a GL failure: this asset fails, the job goes on
            log.exception("%s: unexpected error while rendering", result["path"])
            record = {"status": "failed",
                      "error": f"{result['path']}: render failed ({type(exc).__name__}: {exc})"}
        record["seconds"] = round(time.perf_counter() - start, 4)
        record["by"] = _worker()
        return {**result, "render": record}

    def _thumbnail(self, asset_key: str) -> dict:
        from pipeline.bake import load_baked
        from pipeline.cache import Cache

        cache = Cache(self.cache)
        asset = load_baked(asset_key, cache)
        env = self._environment(asset)
        key = self.key(asset_key, env.key)
        entry = cache.load("thumbnails", key, lazy=lambda name: True)
        if entry is not None:
            return {"status": "cached", "key": key, "warnings": entry.manifest.get("warnings", [])}
        data = self._render(asset, env)
        name = f"thumbnail.{self.fmt}"
        cache.store("thumbnails", key, {"kind": "thumbnail", "asset": asset_key, "environment": env.key,
                                        "warnings": list(asset.warnings)}, {name: data})
        return {"status": "rendered", "key": key, "warnings": list(asset.warnings)}

    def key(self, asset_key: str, env_key: str) -> str:
        from renderer import RENDERER_VERSION

        norm = {"format": THUMBNAIL_FORMAT, "asset": asset_key, "environment": env_key,
                "options": self.options.key_dict(), "file": self.fmt, "quality": self.quality,
                "renderer": str(RENDERER_VERSION)}
        return hashlib.sha256(json.dumps(norm, sort_keys=True, default=str).encode()).hexdigest()

    def _environment(self, asset):
        from pipeline.bake import bake_environment
        from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
        from renderer.methods.auto import environment_face_size

        face, _ = environment_face_size(asset, self.options)
        ident = (self.env, self.cache, face)
        if ident not in _ENVS:
            _ENVS[ident] = bake_environment(self.env or DEFAULT_ENVIRONMENT, self.cache, face_size=face)
        return _ENVS[ident]

    def _render(self, asset, env) -> bytes:
        from renderer import render
        from renderer.sequence import encode_animation, render_turntable, render_views

        if self.options.turntable:
            return encode_animation(render_turntable(asset, env, self.options, keep_linear=False),
                                    self.fmt, self.quality)
        frame = (render_views if self.options.views else render)(asset, env, self.options)
        return frame.encode(self.fmt, self.quality)


def _worker() -> dict:
    """Which process (and Ray node, in a Ray task) rendered: in the manifest, for operators."""
    out: dict[str, Any] = {"pid": os.getpid()}
    if "ray" in sys.modules:  # never imported for it: only a Ray worker has it loaded
        ray = sys.modules["ray"]
        if ray.is_initialized():
            out["node"] = ray.get_runtime_context().get_node_id()
    return out


class Thumbnails:
    """The driver's side: DIR and its manifest. `add` takes each result as it arrives (a
    `render` record made where the asset was baked) and puts its file into DIR."""

    def __init__(self, out: Path, cache: str | None, options: RenderOptions, fmt: str,
                 env: str | None, quality: int | None = None):
        from pipeline.cache import default_cache_dir

        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.renderer = Renderer(options, fmt, env, quality,
                                 str(Path(cache or default_cache_dir()).absolute()))
        self.manifest_path = self.out / MANIFEST
        try:
            self.entries: dict[str, dict] = json.loads(self.manifest_path.read_text())["assets"]
        except FileNotFoundError:
            self.entries = {}
        except (ValueError, KeyError, TypeError):  # unreadable: start over rather than trust it
            self.entries = {}
        from renderer import RENDERER_VERSION

        # The settings in full once at the top of the manifest (the last run's); each entry
        # holds their digest, which is what a re-run compares.
        self.settings = json.loads(json.dumps({"options": dataclasses.asdict(options), "format": fmt,
                                               "env": env, "quality": quality,
                                               "renderer": str(RENDERER_VERSION)}, default=str))
        self.signature = hashlib.sha256(json.dumps(self.settings, sort_keys=True).encode()).hexdigest()[:16]
        self._written = 0.0
        self._owners = {f: p for p, e in self.entries.items() for f in e.get("files", [])}
        self._sweep()

    def _sweep(self) -> None:
        """Temporary files a killed driver left in DIR (never read: they are not in the manifest)."""
        for tmp in self.out.rglob("*.tmp-*"):
            try:
                tmp.unlink()
            except OSError:
                pass

    def known(self, path: str) -> dict | None:
        """The asset key and thumbnail key DIR holds for this asset with these options, when
        its files are all there (the `known` of `Renderer`)."""
        old = self.entries.get(path)
        if (old and old.get("status") != "failed" and old.get("thumbnail")
                and old.get("signature") == self.signature
                and all((self.out / f).is_file() for f in old.get("files", []))):
            return {"key": old["key"], "thumbnail": old["thumbnail"]}
        return None

    def name_for(self, path: str, folder: str | None) -> str:
        """DIR-relative name: the path under its folder argument, else the file's name; when
        another asset already has that name (two file arguments `a/x.glb b/x.glb`), the
        name gets a digest of the asset's path, so no thumbnail overwrites another's."""
        rel = os.path.relpath(path, folder) if folder else os.path.basename(path)
        if rel.startswith(".."):
            rel = os.path.basename(path)
        name = Path(rel).as_posix() + "." + self.renderer.fmt
        if self._owners.setdefault(name, path) != path:
            digest = hashlib.sha256(os.path.abspath(path).encode()).hexdigest()[:8]
            name = Path(rel).as_posix() + f".{digest}." + self.renderer.fmt
            self._owners[name] = path
        return name

    def add(self, result: dict, folder: str | None) -> dict:
        """The manifest entry for one result (status `rendered`, `cached`, `kept`, or `failed`
        with the reason), its file in DIR. A result without a `render` record (a failed bake,
        or a bake that ran without the renderer) is rendered here."""
        path = result["path"]
        entry: dict[str, Any]
        if result.get("status") == "failed" or result.get("kind") != "asset":
            entry = {"asset": path, "status": "failed", "error": result.get("error", "not baked"),
                     "files": [], "warnings": [], "seconds": 0.0}
            self._store(path, entry)
            return entry
        if "render" not in result:
            result = self.renderer(result, self.known(path))
        record = result["render"]
        if record["status"] == "kept":
            return {**self.entries[path], "status": "kept"}
        entry = {"asset": path, "key": result["key"], "thumbnail": record.get("key"),
                 "signature": self.signature, "seconds": record["seconds"], "by": record.get("by")}
        if record["status"] == "failed":
            entry.update(status="failed", error=record["error"], files=[], warnings=[])
        else:
            name = self.name_for(path, folder)
            try:
                self._place(record["key"], name)
                entry.update(status=record["status"], files=[name], warnings=record.get("warnings", []))
            except (AssetError, OSError) as exc:
                entry.update(status="failed", error=f"{path}: {exc}", files=[], warnings=[])
        self._store(path, entry)
        return entry

    def _place(self, key: str, name: str) -> None:
        """The cache entry's file at DIR/name, under a temporary name first (renamed over)."""
        from pipeline.cache import Cache, NotInCache

        entry = Cache(self.renderer.cache).load("thumbnails", key, lazy=lambda n: True)
        if entry is None:
            raise NotInCache(key, "the thumbnail's cache entry is gone (evicted?); run again")
        [src] = [entry.path / f for f in entry.manifest["files"]]
        target = self.out / name
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f"{target.name}.tmp-{os.getpid()}")
        tmp.unlink(missing_ok=True)
        try:
            os.link(src, tmp)  # no copy; the entry's later eviction leaves this file whole
        except OSError:
            shutil.copyfile(src, tmp)  # another filesystem, or no hard links there
        os.replace(tmp, target)  # a reader never sees half a file

    def _store(self, path: str, entry: dict) -> None:
        self.entries[path] = entry
        # Rewritten whole, so at most twice a second (a library of 100k would otherwise write
        # its manifest 100k times); `flush` at the end. A driver killed between writes loses
        # only entries whose files are in the cache: the re-run puts them back as `cached`.
        if time.monotonic() - self._written >= MANIFEST_EVERY_S:
            self.flush()

    def flush(self) -> None:
        """Write the manifest now (whole, under a temporary name, renamed over)."""
        self._written = time.monotonic()
        tmp = self.manifest_path.with_name(MANIFEST + ".tmp")
        tmp.write_text(json.dumps({"settings": {**self.settings, "signature": self.signature},
                                   "assets": self.entries}, indent=1, sort_keys=True))
        os.replace(tmp, self.manifest_path)
