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
import re
import shutil
import time
from pathlib import Path
from typing import Any

from core.errors import AssetError, IngestTimeout, LimitExceeded, MalformedAsset, UnsupportedFormat
from core.options import RenderOptions
from pipeline.cache import Cache, NotInCache
from pipeline.ingest import READERS
from pipeline.limits import Limits
from service import archive
from service.http.metrics import Metrics
from service.records import AssetRecord, EnvironmentRecord
from service.settings import Settings
from service.store import Store, ThumbnailCache, content_id, safe_name
from service.workers.pool import DeadlineExceeded, QueueFull, WorkerConfig, WorkerFailure, WorkerPool

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


class ThumbnailService:
    def __init__(self, settings: Settings):
        self.settings = settings
        self.limits = Limits.from_env()
        self.store = Store(settings.root)
        self.thumbs = ThumbnailCache(self.store.thumbs_dir, settings.memory_cache_bytes,
                                     settings.max_thumbnail_bytes)
        self.bake_cache = Cache(settings.cache, max_bytes=settings.bake_cache_bytes or 0)
        self.metrics = Metrics()
        config = WorkerConfig(cache_dir=str(settings.cache), default_env=settings.default_env,
                              cache_bytes=settings.worker_cache_bytes, gpu_bytes=settings.gpu_bytes, bake_cache_bytes=settings.bake_cache_bytes,
                              log_level=logging.getLogger().getEffectiveLevel())
        order = {"cheap_ms": settings.cheap_render_ms, "client_share": settings.client_share}
        if settings.executor == "ray":  # actors on a Ray cluster, same interface
            from service.workers.ray import RayWorkerPool
            self.pool: WorkerPool | RayWorkerPool = RayWorkerPool(settings.worker_count, config, max_queue=settings.max_queue,
                                      on_restart=self._restarted, address=settings.ray_address or None,
                                      num_gpus=settings.ray_gpus, **order)
        else:
            self.pool = WorkerPool(settings.worker_count, config, max_queue=settings.max_queue,
                                   on_restart=self._restarted, **order)
        self.renderer_version = _renderer_version()
        self._bakes: dict[str, asyncio.Task] = {}
        self._baked: dict[str, asyncio.Event] = {}
        self._renders: dict[str, asyncio.Future] = {}
        self._background: set[asyncio.Task] = set()
        self._writes: dict[asyncio.Task, str] = {}  # thumbnails on their way to disk -> asset id
        self._bundled_envs: list[str] | None = None
        m = self.metrics
        m.gauge("asset_preview_render_queue", "Renders waiting or running", (), lambda: {(): self.pool.pending})
        m.gauge("asset_preview_workers_busy", "Render workers running a job", (),
                lambda: {(): sum(w.busy_since is not None for w in self.pool.workers)})
        m.gauge("asset_preview_assets", "Stored assets by status", ("status",), self._asset_counts)
        m.gauge("asset_preview_info", "Versions in use", ("renderer_version", "workers"),
                lambda: {(self.renderer_version, str(self.pool.size)): 1})

    # -- life cycle -------------------------------------------------------------------------

    async def start(self) -> None:
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
            if rec.status == "baking":
                self.schedule_bake(rec.id)
        if self.settings.seed and not (self.store.root / "seeded").exists():
            from service.seed import seed
            await seed(self)

    async def _prune_thumbnails(self, every: float = 60.0) -> None:
        """Keep the thumbnail folder and the bake cache under their caps, least recently used
        first (each write prunes too when it takes the folder over; this catches the rest)."""
        while True:
            await self._prune()
            await asyncio.sleep(every)

    async def _prune(self) -> None:
        try:
            removed = await asyncio.to_thread(self.thumbs.prune)
            if removed:
                log.info("thumbnail cache over %d bytes: %d files removed",
                         self.settings.max_thumbnail_bytes, removed)
            await asyncio.to_thread(self.bake_cache.evict)
        except OSError as exc:
            log.error("cache pruning failed: %s", exc)

    def _spawn(self, coro) -> asyncio.Task:
        task = asyncio.get_running_loop().create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task

    def _restarted(self, reason: str) -> None:
        self.metrics.restarts.labels("deadline" if "deadline" in reason else "crash").inc()

    def _asset_counts(self) -> dict:
        counts = {"baking": 0, "ready": 0, "failed": 0}
        for rec in self.store.assets.values():
            counts[rec.status] += 1
        return {(k,): v for k, v in counts.items()}

    # -- assets -----------------------------------------------------------------------------

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
                root = archive.find_root(files, name, main)
                raw.unlink()
            else:
                src.mkdir()
                raw.rename(src / name)
                root = name
            try:
                # The worker's own bound (Limits.ingest_seconds) answers first with a clean 422;
                # the job deadline only catches a worker that hangs past it.
                summary = await self.pool.run("inspect", str(src / root), str(src),
                                              deadline=1.5 * self.limits.ingest_seconds + 10,
                                              cost_ms=self.settings.cheap_render_ms, expensive=True,
                                              client=client)
            except AssetError as exc:
                raise _public_error(exc, src, name) from None
            except QueueFull:
                raise
            except WorkerFailure as exc:  # the upload crashed or hung the reader: its fault, not ours
                log.error("upload %s: reading it failed in a worker: %s", name, public_message(str(exc)))
                timeout = isinstance(exc, DeadlineExceeded)
                raise (IngestTimeout if timeout else MalformedAsset)(name, (
                    "reading it took longer than the worker deadline" if timeout else
                    "the file could not be read (the reader failed on it)")) from None
            # Only what the asset references is kept (a zip's readme, previews, other scenes go).
            dropped = await asyncio.to_thread(archive.drop_unreferenced, src, summary.pop("files", []))
            stored = sum(f.stat().st_size for f in src.rglob("*") if f.is_file())
            self._check_quota(owner, stored)
            summary["warnings"] = [_strip(w, src) for w in summary.get("warnings", [])]
            rec = AssetRecord(id=asset_id, name=name, root=root, size=size, stored_bytes=stored, owner=owner,
                              created=time.time(), **summary)
            rec = self.store.commit_asset(staged, rec)
            log.info("asset %s stored (%s, %d triangles, %d bytes kept, %d unreferenced dropped)",
                     asset_id, name, rec.triangles, stored, dropped)
            self.schedule_bake(asset_id)
            return rec, True
        finally:
            shutil.rmtree(staged, ignore_errors=True)

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
        if asset_id not in self.store.assets:
            raise NotFound(asset_id)
        writing = [t for t, a in self._writes.items() if a == asset_id]
        if writing:  # let them land, so nothing of the asset reappears after the answer
            await asyncio.wait(writing, timeout=10)
        if asset_id not in self.store.assets:  # deleted by a concurrent request meanwhile
            return
        rec = self.store.assets[asset_id]
        self.store.delete_asset(asset_id)
        self.thumbs.forget(asset_id)
        key = rec.bake_key
        if key and not any(r.bake_key == key for r in self.store.assets.values()):
            # Its bake goes too, unless another upload (same referenced files) shares it.
            await asyncio.to_thread(self.bake_cache.remove, "assets", key)
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
            rec = self.store.assets.get(asset_id)
            if rec is None:
                return
            path = self.store.asset_path(rec)
            t0 = time.perf_counter()
            try:
                # Expensive: bakes never take every worker, so cheap renders keep flowing.
                src = self.store.asset_dir(asset_id) / "src"  # the upload's root (a zip's whole tree)
                out = await self.pool.run("bake", str(path), str(src), deadline=self.settings.bake_seconds,
                                          queue=False, cost_ms=self.settings.cheap_render_ms, expensive=True)
            except AssetError as exc:
                src = self.store.asset_dir(asset_id) / "src"
                fields: dict[str, Any] = {"status": "failed", "reason": str(_public_error(exc, src, rec.name))}
            except WorkerFailure as exc:
                fields = {"status": "failed", "reason": public_message(str(exc))}
            else:
                fields = {"status": "ready", "reason": None, "bake_key": out["key"]}
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

    # -- environments -----------------------------------------------------------------------

    def bundled_environments(self) -> list[str]:
        if self._bundled_envs is None:
            names = self.pool.info.get("environments")
            if names is None:
                try:
                    from pipeline.environment.prefilter import list_bundled
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
                await self.pool.run("bake_env", str(raw), deadline=self.settings.bake_seconds,
                                    cost_ms=self.settings.cheap_render_ms, expensive=True)
            except AssetError as exc:
                raise _public_error(exc, staged, fname) from None
            rec = EnvironmentRecord(id=env_id, name=label, file=fname, size=size, created=time.time())
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

    def admit(self, options: RenderOptions) -> RenderOptions:
        """The request as it will run: size within the limit (422 beyond), the time budget
        capped by the render deadline and the cost ceiling (a budget the deadline would cut
        short buys nothing; one within the ceiling keeps the request admissible)."""
        limit = self.settings.max_thumbnail_size
        if max(options.width, options.height) > limit:
            raise LimitExceeded("thumbnail", f"{options.width}x{options.height} pixels asked; "
                                             f"the limit is {limit} on either side")
        cap = min(BUDGET_SHARE_OF_DEADLINE * self.settings.render_seconds * 1000,
                  self.settings.render_cost_ceiling_ms)
        if options.budget_ms is not None and options.budget_ms > cap:
            options = options.replace(budget_ms=cap)
        return options

    def estimate_ms(self, rec: AssetRecord, options: RenderOptions) -> float:
        """The request's cost by the model `auto` plans with (renderer.methods.auto)."""
        from renderer.methods.auto import estimate_request_ms
        ov = options.override
        transmissive = bool(ov and ov.transmission) or ((ov is None or ov.transmission is None)
                                                        and rec.transmissive)
        return estimate_request_ms(rec.triangles, options.width, options.height, options.method,
                                   transmissive, options.budget_ms, options.bounces,
                                   options.supersample)

    def check_cost(self, rec: AssetRecord, options: RenderOptions) -> float:
        cost = self.estimate_ms(rec, options)
        ceiling = self.settings.render_cost_ceiling_ms
        if cost > ceiling:
            self.metrics.rejected.labels("over_cost").inc()
            raise BadParameter(f"estimated render cost {cost:.0f} ms is over the ceiling of {ceiling:.0f} ms "
                               "per request (max_render_cost_ms); ask for fewer pixels, a raster "
                               "method or a smaller budget_ms")
        return cost

    def cached(self, asset_id: str, key: str, fmt: str):
        return self.thumbs.get(asset_id, key, fmt)

    async def render(self, asset_id: str, options: RenderOptions, fmt: str, key: str,
                     env_source: str, client: str | None = None):
        """Render (once, however many requests ask at the same time) and cache."""
        fut = self._renders.get(key + fmt)
        if fut is not None:
            return await asyncio.shield(fut)
        fut = asyncio.get_running_loop().create_future()
        self._renders[key + fmt] = fut
        try:
            result = await self._render(asset_id, options, fmt, key, env_source, client)
            fut.set_result(result)
            return result
        except BaseException as exc:
            fut.set_exception(exc)
            fut.exception()  # retrieved: no "never retrieved" warning when nobody else waits
            raise
        finally:
            self._renders.pop(key + fmt, None)

    async def _render(self, asset_id: str, options: RenderOptions, fmt: str, key: str,
                      env_source: str, client: str | None):
        rec = self.store.assets.get(asset_id)
        if rec is None:
            raise NotFound(asset_id)
        cost = self.check_cost(rec, options)
        rec = await self.wait_baked(asset_id, self.settings.bake_wait_seconds)
        if rec.status == "failed":
            raise BakeFailed(rec.name, f"the asset failed to bake: {rec.reason}")
        for attempt in range(2):
            try:
                out = await self.pool.run("render", rec.bake_key, env_source, options, fmt,
                                          deadline=self.settings.render_seconds, cost_ms=cost, client=client)
                break
            except NotInCache:
                if attempt or asset_id not in self.store.assets:
                    raise StillBaking(asset_id) from None
                # The bake was evicted from the cache (its byte budget): bake it again.
                log.info("asset %s: bake %s evicted; baking it again", asset_id, (rec.bake_key or "")[:12])
                self.store.update_asset(asset_id, status="baking")
                self.schedule_bake(asset_id)
                rec = await self.wait_baked(asset_id, self.settings.bake_wait_seconds)
                if rec.status == "failed":
                    raise BakeFailed(rec.name, f"the asset failed to bake: {rec.reason}") from None
            except AssetError as exc:
                raise _public_error(exc, self.store.asset_dir(asset_id) / "src", rec.name) from None
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


BUDGET_SHARE_OF_DEADLINE = 0.8  # budget_ms is capped here: the plan's estimate must leave headroom
_SERVER_PATH = re.compile(r"(?<![\w.:/~-])/(?:[^\s'\"():,/]+/)+([^\s'\"():,]*)")


def _public_error(exc: AssetError, folder: Path, name: str) -> AssetError:
    """The worker's error (its own class) with server paths replaced by the names the client
    knows: paths inside the upload's folder relative to it, any other one by its file name."""
    path = _strip(exc.path, folder)
    if not path or path == "." or path.startswith("/"):
        path = name
    return type(exc)(path, _strip(exc.reason, folder))


def _strip(text: str, folder: Path) -> str:
    """Server paths out of a message: the client knows files by their names in its upload."""
    for prefix in (str(folder.resolve()) + "/", str(folder) + "/", str(folder.resolve()), str(folder)):
        text = text.replace(prefix, "")
    return public_message(text)


def public_message(text: str) -> str:
    """Any absolute path left in `text` (a staging folder, the cache) becomes its last part."""
    return _SERVER_PATH.sub(lambda m: m.group(1) or "(server folder)", text)


def _renderer_version() -> str:
    try:
        import renderer
        return str(getattr(renderer, "RENDERER_VERSION", "0"))
    except ImportError:
        return "0"
