"""Uploads and what becomes of them: storing, de-duplication, quotas, bakes and environments.

An upload is received into staging, identified by the SHA-256 of its bytes (the same bytes
again are the same asset), read once by a worker (only the files it references are kept),
committed to the store by rename and baked in the background. Pipeline work never runs in
this process: it goes to the worker pool as typed jobs (service.workers.protocol).
"""
from __future__ import annotations

import asyncio
import hashlib
import logging
import re
import shutil
import time
from pathlib import Path
from typing import Any

from core.errors import AssetError, IngestTimeout, MalformedAsset, UnsupportedFormat
from pipeline.cache import Cache
from pipeline.environment.panorama import list_bundled
from pipeline.ingest import READERS
from pipeline.limits import Limits
from service import archive
from service.http.metrics import Metrics
from service.records import AssetRecord, EnvironmentRecord
from service.settings import Settings
from service.store import Store, content_id, safe_name
from service.workers.pool import Pool
from service.workers.protocol import (
    AssetSummary,
    BakeEnvironmentJob,
    BakeJob,
    BakeResult,
    DeadlineExceeded,
    InspectJob,
    PartsJob,
    QueueFull,
    WorkerFailure,
)

log = logging.getLogger(__name__)

ASSET_SUFFIXES = (*READERS, ".zip")  # what the pipeline reads, or an archive of it
ENV_SUFFIXES = (".jpg", ".jpeg", ".png", ".hdr", ".exr")


class StillBaking(Exception):
    """The asset's bake did not finish within the wait bound (-> 202 Retry-After)."""


class NotFound(Exception):
    pass


class BadParameter(Exception):
    """A request parameter names something that does not exist (-> 422)."""


class Conflict(Exception):
    """The request clashes with what is stored (-> 409)."""


class QuotaExceeded(Exception):
    """The caller's key holds its quota of assets or bytes (-> 413)."""


class UploadTooLarge(AssetError):
    def __init__(self, name: str, limit: int):
        super().__init__(name, f"upload is larger than the limit of {limit} bytes")


class BakeFailed(AssetError):
    pass


class Assets:
    """The stored uploads and panoramas, and their bakes."""

    def __init__(self, settings: Settings, store: Store, pool: Pool, bake_cache: Cache, metrics: Metrics):
        self.settings, self.store, self.pool = settings, store, pool
        self.bake_cache, self.metrics = bake_cache, metrics
        self.limits = Limits.from_env()
        self._bakes: dict[str, asyncio.Task] = {}
        self._baked: dict[str, asyncio.Event] = {}
        self._bundled_envs: list[str] | None = None

    def resume(self) -> None:
        """A bake the last server did not finish is redone (the pipeline's cache makes a
        finished-but-unrecorded bake a cheap hit)."""
        for rec in list(self.store.assets.values()):
            if rec.status == "baking":
                self.schedule_bake(rec.id)

    def stop(self) -> None:
        for t in list(self._bakes.values()):
            t.cancel()

    def counts(self) -> dict:
        counts = {"baking": 0, "ready": 0, "failed": 0}
        for rec in self.store.assets.values():
            counts[rec.status] += 1
        return {(k,): v for k, v in counts.items()}

    # -- uploads ----------------------------------------------------------------------------

    async def add_asset(self, filename: str, chunks, main: str | None = None,
                        client: str | None = None) -> tuple[AssetRecord, bool]:
        """Store an upload (an async iterator of byte chunks); returns (record, created).
        `client` ("key:..." when an API key was used) owns the asset for quotas."""
        name = safe_name(filename or "upload")
        try:
            return await self._add_asset(name, chunks, main, client)
        except AssetError as exc:  # one line, no traceback: the client's input was refused
            log.warning("upload %s refused: %s", name, public_message(str(exc)))
            raise

    async def _add_asset(self, name: str, chunks, main: str | None, client: str | None):
        suffix = Path(name).suffix.lower()
        if suffix not in ASSET_SUFFIXES:
            raise UnsupportedFormat(name, f"unsupported file type {suffix or '(none)'!r}; accepted: "
                                          + ", ".join(ASSET_SUFFIXES))
        owner = client if client and client.startswith("key:") else None
        self._check_quota(owner, 0)
        staged = self.store.staging()
        try:
            raw, digest, size = await self._receive(staged / "upload", chunks, name)
            asset_id = content_id(digest)
            existing = self.store.assets.get(asset_id)
            if existing is not None:
                if existing.status == "failed":  # uploading it again retries the bake
                    existing = self.store.update_asset(asset_id, status="baking", reason=None)
                    self.schedule_bake(asset_id)
                return existing, False
            src = staged / "src"
            if suffix == ".zip":
                lim = self.limits
                files = await asyncio.to_thread(
                    archive.extract, raw, src, max_bytes=lim.max_unpacked_bytes,
                    max_files=lim.max_archive_files, max_depth=lim.max_archive_depth,
                    max_name=lim.max_name_length, max_ratio=lim.max_archive_ratio, label=name)
                try:
                    root = archive.find_root(files, name, main)
                except archive.AmbiguousEntry:
                    # a kit: its parts (files other USD files reference) are not entry points
                    parts = await self._parts(src, archive.usd_layers(files), name, client)
                    root = archive.find_root(files, name, main, frozenset(parts))
                raw.unlink()
            else:
                src.mkdir()
                raw.rename(src / name)
                root = name
            summary = await self._inspect(src, root, name, client)
            # Only what the asset references is kept (a zip's readme, previews, other scenes go).
            dropped = await asyncio.to_thread(archive.drop_unreferenced, src, list(summary.files))
            stored = sum(f.stat().st_size for f in src.rglob("*") if f.is_file())
            self._check_quota(owner, stored)
            rec = AssetRecord(id=asset_id, name=name, root=root, size=size, stored_bytes=stored, owner=owner,
                              created=time.time(), format=summary.format, triangles=summary.triangles,
                              materials=summary.materials, transmissive=summary.transmissive,
                              emitters=summary.emitters,
                              warnings=[_strip(w, src) for w in summary.warnings])
            rec = self.store.commit_asset(staged, rec)
            log.info("asset %s stored (%s, %d triangles, %d bytes kept, %d unreferenced dropped)",
                     asset_id, name, rec.triangles, stored, dropped)
            self.schedule_bake(asset_id)
            return rec, True
        finally:
            shutil.rmtree(staged, ignore_errors=True)

    async def _parts(self, src: Path, layers: list[str], name: str, client: str | None) -> tuple[str, ...]:
        if len(layers) < 2:
            return ()
        try:
            parts: tuple[str, ...] = await self.pool.run(
                PartsJob(str(src), tuple(layers)), deadline=1.5 * self.limits.ingest_seconds + 10,
                cost_ms=self.settings.cheap_render_ms, expensive=True, client=client)
            return parts
        except AssetError as exc:
            raise public_error(exc, src, name) from None
        except WorkerFailure:  # a layer that crashes Sdf: no parts known, the listing stands
            log.error("upload %s: reading its USD references failed in a worker", name)
            return ()

    async def _inspect(self, src: Path, root: str, name: str, client: str | None) -> AssetSummary:
        try:
            # The worker's own bound (Limits.ingest_seconds) answers first with a clean 422;
            # the job deadline only catches a worker that hangs past it.
            summary: AssetSummary = await self.pool.run(
                InspectJob(str(src / root), str(src)), deadline=1.5 * self.limits.ingest_seconds + 10,
                cost_ms=self.settings.cheap_render_ms, expensive=True, client=client)
            return summary
        except AssetError as exc:
            raise public_error(exc, src, name) from None
        except QueueFull:
            raise
        except WorkerFailure as exc:  # the upload crashed or hung the reader: its fault, not ours
            log.error("upload %s: reading it failed in a worker: %s", name, public_message(str(exc)))
            timeout = isinstance(exc, DeadlineExceeded)
            raise (IngestTimeout if timeout else MalformedAsset)(name, (
                "reading it took longer than the worker deadline" if timeout else
                "the file could not be read (the reader failed on it)")) from None

    def _check_quota(self, owner: str | None, adding: int) -> None:
        s = self.settings
        if owner is None or not (s.quota_assets or s.quota_bytes):
            return
        mine = [r for r in self.store.assets.values() if r.owner == owner]
        if s.quota_assets and len(mine) >= s.quota_assets:
            raise QuotaExceeded(f"this API key holds {len(mine)} assets, its quota of {s.quota_assets}; "
                                "delete some first")
        used = sum(r.stored_bytes or r.size for r in mine)
        if s.quota_bytes and used + adding > s.quota_bytes:
            raise QuotaExceeded(f"this API key would hold {used + adding} bytes, more than its quota "
                                f"of {s.quota_bytes}; delete some assets first")

    async def _receive(self, path: Path, chunks, name: str):
        digest, size = hashlib.sha256(), 0
        with open(path, "wb") as f:
            async for chunk in chunks:
                size += len(chunk)
                if size > self.settings.max_upload_bytes:
                    raise UploadTooLarge(name, self.settings.max_upload_bytes)
                digest.update(chunk)
                f.write(chunk)
        if size == 0:
            raise MalformedAsset(name, "the upload is empty")
        return path, digest, size

    async def delete_asset(self, asset_id: str) -> None:
        """The record, the upload and its bake (unless another upload shares it). Its
        thumbnails are the caller's (service.thumbnails)."""
        rec = self.store.assets.get(asset_id)
        if rec is None:  # deleted by a concurrent request meanwhile
            return
        self.store.delete_asset(asset_id)
        key = rec.bake_key
        if key and not any(r.bake_key == key for r in self.store.assets.values()):
            await asyncio.to_thread(self.bake_cache.remove, "assets", key)
        event = self._baked.pop(asset_id, None)
        if event:
            event.set()

    # -- bakes ------------------------------------------------------------------------------

    def schedule_bake(self, asset_id: str) -> None:
        if asset_id in self._bakes:
            return
        event = self._baked.get(asset_id)
        if event is None or event.is_set():  # a new bake of an asset baked before: a new event
            self._baked[asset_id] = asyncio.Event()
        task = asyncio.get_running_loop().create_task(self._bake(asset_id))
        self._bakes[asset_id] = task
        task.add_done_callback(lambda _: self._bakes.pop(asset_id, None))

    async def _bake(self, asset_id: str) -> None:
        try:
            rec = self.store.assets.get(asset_id)
            if rec is None:
                return
            path = self.store.asset_path(rec)
            src = self.store.asset_dir(asset_id) / "src"  # the upload's root (a zip's whole tree)
            t0 = time.perf_counter()
            try:
                # Expensive: bakes never take every worker, so cheap renders keep flowing.
                out: BakeResult = await self.pool.run(
                    BakeJob(str(path), str(src)), deadline=self.settings.bake_seconds, queue=False,
                    cost_ms=self.settings.cheap_render_ms, expensive=True)
            except AssetError as exc:
                fields: dict[str, Any] = {"status": "failed", "reason": str(public_error(exc, src, rec.name))}
            except WorkerFailure as exc:
                fields = {"status": "failed", "reason": public_message(str(exc))}
            else:
                fields = {"status": "ready", "reason": None, "bake_key": out.key}
                self.metrics.bake.observe(time.perf_counter() - t0)
            self.metrics.bake_results.labels(fields["status"]).inc()
            if asset_id in self.store.assets:  # not deleted meanwhile
                self.store.update_asset(asset_id, **fields)
                log.info("asset %s %s %s", asset_id, fields["status"], fields.get("reason") or "")
        finally:
            event = self._baked.get(asset_id)
            if event:
                event.set()

    async def wait_baked(self, asset_id: str, timeout: float) -> AssetRecord:
        rec = self.store.assets.get(asset_id)
        if rec is None:
            raise NotFound(asset_id)
        if rec.status == "baking":
            event = self._baked.setdefault(asset_id, asyncio.Event())
            try:
                await asyncio.wait_for(event.wait(), timeout)
            except asyncio.TimeoutError:
                raise StillBaking(asset_id) from None
            rec = self.store.assets.get(asset_id)
            if rec is None:
                raise NotFound(asset_id)
            if rec.status == "baking":
                raise StillBaking(asset_id)
        return rec

    async def rebake(self, asset_id: str) -> AssetRecord:
        """Bake again an asset whose bake was evicted from the cache (its byte budget)."""
        self.store.update_asset(asset_id, status="baking")
        self.schedule_bake(asset_id)
        return await self.wait_baked(asset_id, self.settings.bake_wait_seconds)

    # -- environments -----------------------------------------------------------------------

    def bundled_environments(self) -> list[str]:
        if self._bundled_envs is None:
            info = self.pool.info
            names = info.environments if info is not None and info.environments is not None else list_bundled()
            self._bundled_envs = sorted(names)
        return self._bundled_envs

    def default_environment(self) -> str:
        names = self.bundled_environments()
        if self.settings.default_env in names or not names:
            return self.settings.default_env
        return names[0]

    def resolve_environment(self, name: str | None) -> tuple[str, str]:
        """(identity for cache keys, source for the worker) of a bundled or uploaded panorama."""
        name = name or self.default_environment()
        rec = self.store.find_environment(name)
        if rec is not None:
            return "uploaded:" + rec.id, str(self.store.env_path(rec))
        bundled = self.bundled_environments()
        if name in bundled or (not bundled and name == self.settings.default_env):
            return "bundled:" + name, name
        raise BadParameter(f"unknown environment {name!r}; GET /environments lists them")

    async def add_environment(self, filename: str, chunks, name: str | None) -> tuple[EnvironmentRecord, bool]:
        fname = safe_name(filename or "panorama")
        suffix = Path(fname).suffix.lower()
        if suffix not in ENV_SUFFIXES:
            raise UnsupportedFormat(fname, f"unsupported panorama type {suffix or '(none)'!r}; "
                                           "accepted: " + ", ".join(ENV_SUFFIXES))
        label = safe_name(name or Path(fname).stem)
        if label in self.bundled_environments():
            raise Conflict(f"environment name {label!r} is taken by a bundled panorama")
        staged = self.store.staging()
        try:
            raw, digest, size = await self._receive(staged / fname, chunks, fname)
            env_id = content_id(digest)
            if env_id in self.store.environments:
                return self.store.environments[env_id], False
            clash = self.store.find_environment(label)
            if clash is not None:
                raise Conflict(f"environment name {label!r} is taken by another panorama")
            try:  # prefilter it now: a bad panorama is refused at upload, not at first render
                await self.pool.run(BakeEnvironmentJob(str(raw)), deadline=self.settings.bake_seconds,
                                    cost_ms=self.settings.cheap_render_ms, expensive=True)
            except AssetError as exc:
                raise public_error(exc, staged, fname) from None
            rec = EnvironmentRecord(id=env_id, name=label, file=fname, size=size, created=time.time())
            return self.store.commit_environment(staged, rec), True
        finally:
            shutil.rmtree(staged, ignore_errors=True)


_SERVER_PATH = re.compile(r"(?<![\w.:/~-])/(?:[^\s'\"():,/]+/)+([^\s'\"():,]*)")


def public_error(exc: AssetError, folder: Path, name: str) -> AssetError:
    """The worker's error (its own class) with server paths replaced by the names the client
    knows: paths inside the upload's folder relative to it, any other one by its file name."""
    path = _strip(exc.path, folder)
    if not path or path == "." or path.startswith("/"):
        path = name
    return type(exc)(path, _strip(exc.reason, folder))


_ROOT = re.compile(r"(leaves|outside) the root \S+")


def _strip(text: str, folder: Path) -> str:
    """Server paths out of a message: the client knows files by their names in its upload, and
    a reference refused for leaving the sandbox is one that leaves the upload."""
    text = _ROOT.sub(lambda m: f"{m.group(1)} the upload (a reference must name a file sent in "
                               "the same upload: send the asset and its files together as a .zip)",
                     text)
    for prefix in (str(folder.resolve()) + "/", str(folder) + "/", str(folder.resolve()), str(folder)):
        text = text.replace(prefix, "")
    return public_message(text)


def public_message(text: str) -> str:
    """Any absolute path left in `text` (a staging folder, the cache) becomes its last part."""
    return _SERVER_PATH.sub(lambda m: m.group(1) or "(server folder)", text)
