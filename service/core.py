"""The service's state and its operations: upload -> bake -> thumbnail.

Routers stay thin and call into one `ThumbnailService` (a FastAPI dependency). Pipeline and
renderer work never runs in this process: it goes to the worker pool, so this process only
moves bytes, keeps records and serves cached thumbnails.
"""
from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import shutil
import time
from pathlib import Path
from typing import Any

from core.errors import AssetError, LimitExceeded, MalformedAsset, UnsupportedFormat
from core.options import RenderOptions
from pipeline.ingest import READERS
from pipeline.limits import Limits

from . import archive
from .metrics import Metrics
from .settings import Settings
from .store import Store, ThumbnailCache, content_id, safe_name
from .workers import JobAssetError, WorkerFailure, WorkerPool

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


class ThumbnailService:
    def __init__(self, settings: Settings):
        self.settings = settings
        self.limits = Limits.from_env()
        self.store = Store(settings.root)
        self.thumbs = ThumbnailCache(self.store.thumbs_dir, settings.memory_cache_bytes)
        self.metrics = Metrics()
        if settings.executor == "ray":  # actors on a Ray cluster, same interface
            from .ray_workers import RayWorkerPool
            self.pool: WorkerPool | RayWorkerPool = RayWorkerPool(settings.worker_count, str(settings.cache),
                                      max_queue=settings.max_queue, on_restart=self._restarted,
                                      address=settings.ray_address or None, num_gpus=settings.ray_gpus)
        else:
            self.pool = WorkerPool(settings.worker_count, str(settings.cache),
                                   max_queue=settings.max_queue, on_restart=self._restarted)
        self.renderer_version = _renderer_version()
        self._bakes: dict[str, asyncio.Task] = {}
        self._baked: dict[str, asyncio.Event] = {}
        self._bake_slots: asyncio.Semaphore | None = None
        self._renders: dict[str, asyncio.Future] = {}
        self._background: set[asyncio.Task] = set()
        self._writes: dict[asyncio.Task, str] = {}  # thumbnails on their way to disk -> asset id
        self._bundled_envs: list[str] | None = None
        m = self.metrics
        m.gauges["asset_preview_render_queue"] = ("Renders waiting or running", lambda: {"": self.pool.pending})
        m.gauges["asset_preview_workers_busy"] = (
            "Render workers running a job", lambda: {"": sum(w.busy_since is not None for w in self.pool.workers)})
        m.gauges["asset_preview_assets"] = ("Stored assets by status", self._asset_counts)
        m.gauges["asset_preview_info"] = ("Versions in use", lambda: {
            f'renderer_version="{self.renderer_version}",workers="{self.pool.size}"': 1})

    # -- life cycle -------------------------------------------------------------------------

    async def start(self) -> None:
        # Bakes never take every worker, so renders of ready assets keep flowing meanwhile.
        self._bake_slots = asyncio.Semaphore(max(1, self.pool.size - 1))
        await self.pool.start()
        self._spawn(self._warm_up_then_resume())
        self._spawn(self._prune_thumbnails())

    async def stop(self) -> None:
        if self._writes:  # finish writing what was already answered
            await asyncio.wait(list(self._writes), timeout=10)
        for t in list(self._background) + list(self._bakes.values()):
            t.cancel()
        await self.pool.stop()

    async def _warm_up_then_resume(self) -> None:
        await self.pool.warm_up()
        if self.pool.info.get("renderer_version"):
            self.renderer_version = self.pool.info["renderer_version"]
        # A bake the last server did not finish is redone (the pipeline's cache makes a
        # finished-but-unrecorded bake a cheap hit).
        for rec in list(self.store.assets.values()):
            if rec["status"] == "baking":
                self.schedule_bake(rec["id"])
        if self.settings.seed and not (self.store.root / "seeded").exists():
            from .seed import seed
            await seed(self)

    async def _prune_thumbnails(self, every: float = 60.0) -> None:
        """Keep the thumbnail folder under its cap (a memory-cached answer survives its file)."""
        while True:
            try:
                removed = await asyncio.to_thread(self.thumbs.prune, self.settings.max_thumbnail_bytes)
                if removed:
                    log.info("thumbnail cache over %d bytes: %d files removed",
                             self.settings.max_thumbnail_bytes, removed)
            except OSError as exc:
                log.error("thumbnail pruning failed: %s", exc)
            await asyncio.sleep(every)

    def _spawn(self, coro) -> asyncio.Task:
        task = asyncio.get_running_loop().create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task

    def _restarted(self, reason: str) -> None:
        self.metrics.restarts["deadline" if "deadline" in reason else "crash"] += 1

    def _asset_counts(self) -> dict:
        counts = {"baking": 0, "ready": 0, "failed": 0}
        for rec in self.store.assets.values():
            counts[rec["status"]] += 1
        return {f'status="{k}"': v for k, v in counts.items()}

    # -- assets -----------------------------------------------------------------------------

    async def add_asset(self, filename: str, chunks, main: str | None = None) -> tuple[dict, bool]:
        """Store an upload (an async iterator of byte chunks); returns (record, created)."""
        name = safe_name(filename or "upload")
        suffix = Path(name).suffix.lower()
        if suffix not in ASSET_SUFFIXES:
            raise UnsupportedFormat(name, f"unsupported file type {suffix or '(none)'!r}; accepted: "
                                          + ", ".join(ASSET_SUFFIXES))
        staged = self.store.staging()
        try:
            raw, digest, size = await self._receive(staged / "upload", chunks, name)
            asset_id = content_id(digest)
            existing = self.store.assets.get(asset_id)
            if existing is not None:
                if existing["status"] == "failed":  # uploading it again retries the bake
                    existing = self.store.update_asset(asset_id, status="baking", reason=None)
                    self.schedule_bake(asset_id)
                return existing, False
            src = staged / "src"
            if suffix == ".zip":
                files = await asyncio.to_thread(
                    archive.extract, raw, src, max_bytes=self.limits.max_unpacked_bytes,
                    max_files=self.limits.max_archive_files, label=name)
                root = archive.find_root(files, name, main)
                raw.unlink()
            else:
                src.mkdir()
                raw.rename(src / name)
                root = name
            try:
                summary = await self.pool.run("inspect", str(src / root),
                                              deadline=self.settings.ingest_seconds)
            except JobAssetError as exc:
                raise _public_error(exc, src, name) from None
            summary["warnings"] = [_strip(w, src) for w in summary.get("warnings", [])]
            rec = {"id": asset_id, "name": name, "root": root, "size": size, "status": "baking",
                   "reason": None, "created": time.time(), **summary}
            rec = self.store.commit_asset(staged, rec)
            log.info("asset %s stored (%s, %d triangles)", asset_id, name, rec["triangles"])
            self.schedule_bake(asset_id)
            return rec, True
        finally:
            shutil.rmtree(staged, ignore_errors=True)

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
        if asset_id not in self.store.assets:
            raise NotFound(asset_id)
        writing = [t for t, a in self._writes.items() if a == asset_id]
        if writing:  # let them land, so nothing of the asset reappears after the answer
            await asyncio.wait(writing, timeout=10)
        if asset_id not in self.store.assets:  # deleted by a concurrent request meanwhile
            return
        self.store.delete_asset(asset_id)
        self.thumbs.forget(asset_id)
        event = self._baked.pop(asset_id, None)
        if event:
            event.set()

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
            assert self._bake_slots is not None  # made in start()
            async with self._bake_slots:
                rec = self.store.assets.get(asset_id)
                if rec is None:
                    return
                path = self.store.asset_path(rec)
                t0 = time.perf_counter()
                try:
                    out = await self.pool.run("bake", str(path), deadline=self.settings.bake_seconds,
                                              queue=False)
                except JobAssetError as exc:
                    fields: dict[str, Any] = {"status": "failed", "reason": str(_public_error(exc, path.parent, rec["name"]))}
                except WorkerFailure as exc:
                    fields = {"status": "failed", "reason": str(exc)}
                else:
                    fields = {"status": "ready", "reason": None, "bake_key": out["key"]}
                    self.metrics.bake.observe(time.perf_counter() - t0)
                self.metrics.bake_results[fields["status"]] += 1
                if asset_id in self.store.assets:  # not deleted meanwhile
                    self.store.update_asset(asset_id, **fields)
                    log.info("asset %s %s %s", asset_id, fields["status"], fields.get("reason") or "")
        finally:
            event = self._baked.get(asset_id)
            if event:
                event.set()

    async def wait_baked(self, asset_id: str, timeout: float) -> dict:
        rec = self.store.assets.get(asset_id)
        if rec is None:
            raise NotFound(asset_id)
        if rec["status"] == "baking":
            event = self._baked.setdefault(asset_id, asyncio.Event())
            try:
                await asyncio.wait_for(event.wait(), timeout)
            except asyncio.TimeoutError:
                raise StillBaking(asset_id) from None
            rec = self.store.assets.get(asset_id)
            if rec is None:
                raise NotFound(asset_id)
            if rec["status"] == "baking":
                raise StillBaking(asset_id)
        return rec

    # -- environments -----------------------------------------------------------------------

    def bundled_environments(self) -> list[str]:
        if self._bundled_envs is None:
            names = self.pool.info.get("environments")
            if names is None:
                try:
                    from pipeline.environment import list_bundled
                    names = list(list_bundled())
                except (ImportError, AttributeError):
                    return []
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
            return "uploaded:" + rec["id"], str(self.store.env_path(rec))
        bundled = self.bundled_environments()
        if name in bundled or (not bundled and name == self.settings.default_env):
            return "bundled:" + name, name
        raise BadParameter(f"unknown environment {name!r}; GET /environments lists them")

    async def add_environment(self, filename: str, chunks, name: str | None) -> tuple[dict, bool]:
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
                await self.pool.run("bake_env", str(raw), deadline=self.settings.bake_seconds)
            except JobAssetError as exc:
                raise _public_error(exc, staged, fname) from None
            rec = {"id": env_id, "name": label, "file": fname, "size": size, "created": time.time()}
            return self.store.commit_environment(staged, rec), True
        finally:
            shutil.rmtree(staged, ignore_errors=True)

    # -- thumbnails -------------------------------------------------------------------------

    def thumbnail_key(self, asset_id: str, options: RenderOptions, env_identity: str) -> str:
        """Every input of the render: the asset, the whole RenderOptions, the environment and
        the renderer (its version covers the environment face-size policy, which derives the
        cubemap from the asset and the options alone)."""
        norm = {"asset": asset_id, "options": options.key_dict(), "env": env_identity,
                "renderer": self.renderer_version}
        return hashlib.sha256(json.dumps(norm, sort_keys=True).encode()).hexdigest()[:32]

    def check_size(self, options: RenderOptions) -> None:
        limit = self.settings.max_thumbnail_size
        if max(options.width, options.height) > limit:
            raise LimitExceeded("thumbnail", f"{options.width}x{options.height} pixels asked; "
                                             f"the limit is {limit} on either side")

    def cached(self, asset_id: str, key: str, fmt: str):
        return self.thumbs.get(asset_id, key, fmt)

    async def render(self, asset_id: str, options: RenderOptions, fmt: str, key: str,
                     env_source: str):
        """Render (once, however many requests ask at the same time) and cache."""
        fut = self._renders.get(key + fmt)
        if fut is not None:
            return await asyncio.shield(fut)
        fut = asyncio.get_running_loop().create_future()
        self._renders[key + fmt] = fut
        try:
            result = await self._render(asset_id, options, fmt, key, env_source)
            fut.set_result(result)
            return result
        except BaseException as exc:
            fut.set_exception(exc)
            fut.exception()  # retrieved: no "never retrieved" warning when nobody else waits
            raise
        finally:
            self._renders.pop(key + fmt, None)

    async def _render(self, asset_id: str, options: RenderOptions, fmt: str, key: str,
                      env_source: str):
        rec = await self.wait_baked(asset_id, self.settings.bake_wait_seconds)
        if rec["status"] == "failed":
            raise BakeFailed(rec["name"], f"the asset failed to bake: {rec['reason']}")
        try:
            out = await self.pool.run("render", rec["bake_key"], env_source, options, fmt,
                                      deadline=self.settings.render_seconds)
        except JobAssetError as exc:
            raise _public_error(exc, self.store.asset_dir(asset_id) / "src", rec["name"]) from None
        self.metrics.render.observe(out["seconds"])
        plan = json.dumps(out["plan"], separators=(",", ":"), default=str)
        if asset_id not in self.store.assets:  # deleted while rendering: do not resurrect
            raise NotFound(asset_id)
        # Answer from memory now; the disk copy (two fsyncs) is written off the request path.
        task = asyncio.get_running_loop().create_task(
            self._persist(asset_id, key, fmt, out["image"], plan))
        self._writes[task] = asset_id
        task.add_done_callback(lambda t: self._writes.pop(t, None))
        return self.thumbs.remember(asset_id, key, fmt, out["image"], plan)

    async def _persist(self, asset_id: str, key: str, fmt: str, image: bytes, plan: str) -> None:
        try:
            await asyncio.to_thread(self.thumbs.write, asset_id, key, fmt, image, plan)
        except OSError as exc:  # a full disk costs the disk copy, not the answer
            log.error("thumbnail %s/%s not written: %s", asset_id, key, exc)
        if asset_id not in self.store.assets:  # deleted meanwhile: leave nothing behind
            await asyncio.to_thread(shutil.rmtree, self.store.thumbs_dir / asset_id, True)


class UploadTooLarge(AssetError):
    def __init__(self, name: str, limit: int):
        super().__init__(name, f"upload is larger than the limit of {limit} bytes")


class BakeFailed(AssetError):
    pass


def _public_error(exc: JobAssetError, folder: Path, name: str) -> AssetError:
    """The worker's error with server paths replaced by the names the client knows."""
    from core import errors
    cls = getattr(errors, exc.kind, None)
    if not (isinstance(cls, type) and issubclass(cls, AssetError)):
        cls = AssetError
    err = cls.__new__(cls)
    AssetError.__init__(err, _strip(exc.path, folder) or name, _strip(exc.reason, folder))
    return err


def _strip(text: str, folder: Path) -> str:
    """Server paths out of a message: the client knows files by their names in its upload."""
    for prefix in (str(folder.resolve()) + "/", str(folder) + "/"):
        text = text.replace(prefix, "")
    return text


def _renderer_version() -> str:
    try:
        import renderer
        return str(getattr(renderer, "RENDERER_VERSION", "0"))
    except ImportError:
        return "0"
