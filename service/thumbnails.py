"""Thumbnails: admission, cost, keys, the cache of finished ones, and the service they belong to.

Routers stay thin and call into one `ThumbnailService` (a FastAPI dependency): it owns the
store, the worker pool and the uploads (service.assets). A request passes route -> here ->
the worker protocol -> a worker's renderer, and comes back as one typed `RenderReply`; this
process only moves bytes, keeps records and serves cached thumbnails.
"""
from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import shutil
import time
from pathlib import Path
from typing import NamedTuple

from cachetools import LRUCache

from core.errors import AssetError, LimitExceeded
from core.options import MAX_FRAMES, RenderOptions
from pipeline.cache import Cache, NotInCache
from renderer import RENDERER_VERSION
from renderer.methods.auto import estimate_request_ms
from service.assets import Assets, BadParameter, BakeFailed, NotFound, StillBaking, public_error
from service.http.metrics import Metrics
from service.records import AssetRecord
from service.seed import seed
from service.settings import Settings
from service.store import Store, write_atomic
from service.workers.pool import WorkerPool
from service.workers.protocol import RenderJob, RenderPlan, RenderReply, WorkerConfig

log = logging.getLogger(__name__)

BUDGET_SHARE_OF_DEADLINE = 0.8  # budget_ms is capped here: the plan's estimate must leave headroom


class NeedsKey(Exception):
    """A read without a key (--public-read) asked for a render beyond what such reads may buy (-> 401)."""


class RateLimited(Exception):
    """The client started its share of renders for now (-> 429 Retry-After)."""

    def __init__(self, message: str, retry_after: float):
        super().__init__(message)
        self.retry_after = retry_after


class RateLimit:
    """Token buckets per client: `per_minute` renders a minute, in bursts of as many."""

    MAX_CLIENTS = 10_000  # past it, full buckets (clients idle for a minute) are dropped

    def __init__(self, per_minute: float):
        self.rate = per_minute / 60.0
        self.burst = max(1.0, per_minute)
        self._buckets: dict[str, tuple[float, float]] = {}  # client -> (tokens, when counted)

    def take(self, client: str, now: float | None = None) -> float:
        """0 when the client may start a render now (one token taken), else seconds to wait."""
        if not self.rate:
            return 0.0
        now = time.monotonic() if now is None else now
        tokens, last = self._buckets.get(client, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate)
        if len(self._buckets) >= self.MAX_CLIENTS:
            self._buckets = {c: (t, w) for c, (t, w) in self._buckets.items()
                             if t + (now - w) * self.rate < self.burst}
        if tokens >= 1:
            self._buckets[client] = (tokens - 1, now)
            return 0.0
        self._buckets[client] = (tokens, now)
        return (1 - tokens) / self.rate


class Thumbnail(NamedTuple):
    image: bytes
    etag: str  # strong, from the image bytes
    plan: RenderPlan


class ThumbnailService:
    def __init__(self, settings: Settings):
        self.settings = settings
        self.store = Store(settings.root)
        self.thumbs = ThumbnailCache(self.store.thumbs_dir, settings.memory_cache_bytes,
                                     settings.max_thumbnail_bytes)
        self.bake_cache = Cache(settings.cache, max_bytes=settings.bake_cache_bytes or 0)
        self.metrics = Metrics()
        config = WorkerConfig(cache_dir=str(settings.cache), default_env=settings.default_env,
                              cache_bytes=settings.worker_cache_bytes, gpu_bytes=settings.gpu_bytes,
                              bake_cache_bytes=settings.bake_cache_bytes, max_rss_bytes=settings.worker_max_rss_bytes,
                              log_level=logging.getLogger().getEffectiveLevel())
        order = {"cheap_ms": settings.cheap_render_ms, "client_share": settings.client_share}
        if settings.executor == "ray":  # actors on a Ray cluster, same interface
            from service.workers.ray import RayWorkerPool  # needs the optional `ray` extra
            self.pool: WorkerPool | RayWorkerPool = RayWorkerPool(
                settings.worker_count, config, max_queue=settings.max_queue, on_restart=self._restarted,
                address=settings.ray_address or None, num_gpus=settings.ray_gpus, **order)
        else:
            self.pool = WorkerPool(settings.worker_count, config, max_queue=settings.max_queue,
                                   on_restart=self._restarted, **order)
        self.assets = Assets(settings, self.store, self.pool, self.bake_cache, self.metrics)
        self.renderer_version = RENDERER_VERSION
        self._renders: dict[str, asyncio.Future] = {}
        self._background: set[asyncio.Task] = set()
        self._writes: dict[asyncio.Task, str] = {}  # thumbnails on their way to disk -> asset id
        self.rate = RateLimit(settings.renders_per_minute)
        m = self.metrics
        m.gauge("asset_preview_render_queue", "Renders waiting or running", (), lambda: {(): self.pool.pending})
        m.gauge("asset_preview_workers_busy", "Render workers running a job", (),
                lambda: {(): sum(w.busy_since is not None for w in self.pool.workers)})
        m.gauge("asset_preview_assets", "Stored assets by status", ("status",), self.assets.counts)
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
        for t in list(self._background):
            t.cancel()
        self.assets.stop()
        await self.pool.stop()

    async def _warm_up_then_resume(self) -> None:
        await self.pool.warm_up()
        if self.pool.info is not None:
            self.renderer_version = self.pool.info.renderer_version
        self.assets.resume()
        if self.settings.seed and not (self.store.root / "seeded").exists():
            await seed(self.assets)

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
        kind = "deadline" if "deadline" in reason else "memory" if "resident" in reason else "crash"
        self.metrics.restarts.labels(kind).inc()

    async def delete_asset(self, asset_id: str) -> None:
        """The asset (service.assets) and every thumbnail of it."""
        if asset_id not in self.store.assets:
            raise NotFound(asset_id)
        writing = [t for t, a in self._writes.items() if a == asset_id]
        if writing:  # let them land, so nothing of the asset reappears after the answer
            await asyncio.wait(writing, timeout=10)
        await self.assets.delete_asset(asset_id)
        self.thumbs.forget(asset_id)

    # -- admission and cost -----------------------------------------------------------------

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
        """The request's cost by the model `auto` plans with (renderer.methods.auto), times its
        frames: a turntable's, or for an animated image the most it may have (the record does not
        know the animation's length, so the cap: an upper estimate, as the model's are)."""
        ov = options.override
        transmissive = bool(ov and ov.transmission) or ((ov is None or ov.transmission is None)
                                                        and rec.transmissive)
        frame = estimate_request_ms(rec.triangles, options.width, options.height, options.method,
                                    transmissive, options.budget_ms, options.bounces,
                                    options.supersample, options.integrator, options.samples,
                                    options.fresnel_split, rec.emitters)
        frames = MAX_FRAMES if options.animate else max(options.turntable, 1)
        return frame * frames

    def public_ceiling_ms(self, rec: AssetRecord) -> float:
        """The estimated cost a read without a key may render: public_render_ms, else the
        default thumbnail's."""
        return self.settings.public_render_ms or self.estimate_ms(rec, self.admit(RenderOptions()))

    def check_cost(self, rec: AssetRecord, options: RenderOptions) -> float:
        cost = self.estimate_ms(rec, options)
        ceiling = self.settings.render_cost_ceiling_ms
        if cost > ceiling:
            self.metrics.rejected.labels("over_cost").inc()
            raise BadParameter(f"estimated render cost {cost:.0f} ms is over the ceiling of {ceiling:.0f} ms "
                               "per request (max_render_cost_ms); ask for fewer pixels, a raster "
                               "method or a smaller budget_ms")
        return cost

    def check_may_render(self, rec: AssetRecord, options: RenderOptions, client: str, anonymous: bool) -> None:
        """Before a cache miss renders: a read without a key (--public-read) buys at most the
        default thumbnail's cost (or public_render_ms), and every client its rate of renders."""
        if anonymous:
            ceiling = self.public_ceiling_ms(rec)
            cost = self.estimate_ms(rec, options)
            if cost > ceiling:
                self.metrics.rejected.labels("anonymous_cost").inc()
                raise NeedsKey(f"this thumbnail is not cached and reads without an API key may only render "
                               f"up to {ceiling:.0f} ms of estimated cost (this one: {cost:.0f} ms); send "
                               "`Authorization: Bearer KEY`, or ask for a cached or smaller one")
        wait = self.rate.take(client)
        if wait:
            self.metrics.rejected.labels("rate_limited").inc()
            raise RateLimited(f"you started {self.settings.renders_per_minute:g} renders within a minute, "
                              f"your rate; retry in {wait:.0f} s (cached thumbnails are served meanwhile)",
                              wait)

    # -- rendering --------------------------------------------------------------------------

    def cached(self, asset_id: str, key: str, fmt: str) -> Thumbnail | None:
        return self.thumbs.get(asset_id, key, fmt)

    async def render(self, asset_id: str, options: RenderOptions, fmt: str, key: str,
                     env_source: str, client: str | None = None, env_default: bool = False) -> Thumbnail:
        """Render (once, however many requests ask at the same time) and cache."""
        fut = self._renders.get(key + fmt)
        if fut is not None:
            return await asyncio.shield(fut)
        fut = asyncio.get_running_loop().create_future()
        self._renders[key + fmt] = fut
        try:
            result = await self._render(asset_id, options, fmt, key, env_source, client, env_default)
            fut.set_result(result)
            return result
        except BaseException as exc:
            fut.set_exception(exc)
            fut.exception()  # retrieved: no "never retrieved" warning when nobody else waits
            raise
        finally:
            self._renders.pop(key + fmt, None)

    async def _render(self, asset_id: str, options: RenderOptions, fmt: str, key: str,
                      env_source: str, client: str | None, env_default: bool = False) -> Thumbnail:
        rec = self.store.assets.get(asset_id)
        if rec is None:
            raise NotFound(asset_id)
        cost = self.check_cost(rec, options)
        rec = await self.assets.wait_baked(asset_id, self.settings.bake_wait_seconds)
        for attempt in range(2):
            if rec.status == "failed":
                raise BakeFailed(rec.name, f"the asset failed to bake: {rec.reason}")
            assert rec.bake_key is not None  # ready
            try:
                out: RenderReply = await self.pool.run(
                    RenderJob(rec.bake_key, env_source, options, fmt,
                              str(self.store.asset_dir(asset_id) / "src"), env_default),
                    deadline=self.settings.render_seconds,
                    cost_ms=cost, client=client)
                break
            except NotInCache:
                if attempt or asset_id not in self.store.assets:
                    raise StillBaking(asset_id) from None
                log.info("asset %s: bake %s evicted; baking it again", asset_id, rec.bake_key[:12])
                rec = await self.assets.rebake(asset_id)
            except AssetError as exc:
                raise public_error(exc, self.store.asset_dir(asset_id) / "src", rec.name) from None
        self.metrics.render.observe(out.seconds)
        if asset_id not in self.store.assets:  # deleted while rendering: do not resurrect
            raise NotFound(asset_id)
        # Answer from memory now; the disk copy (two fsyncs) is written off the request path.
        task = asyncio.get_running_loop().create_task(self._persist(asset_id, key, fmt, out.image, out.plan))
        self._writes[task] = asset_id
        task.add_done_callback(lambda t: self._writes.pop(t, None))
        return self.thumbs.remember(asset_id, key, fmt, out.image, out.plan)

    async def _persist(self, asset_id: str, key: str, fmt: str, image: bytes, plan: RenderPlan) -> None:
        try:
            await asyncio.to_thread(self.thumbs.write, asset_id, key, fmt, image, plan)
        except OSError as exc:  # a full disk costs the disk copy, not the answer
            log.error("thumbnail %s/%s not written: %s", asset_id, key, exc)
        if asset_id not in self.store.assets:  # deleted meanwhile: leave nothing behind
            await asyncio.to_thread(shutil.rmtree, self.store.thumbs_dir / asset_id, True)


class ThumbnailCache:
    """Finished thumbnails: files on disk (at most `disk_bytes`, least recently used removed
    first), the hottest also held in memory (a byte-weighed LRU of `memory_bytes`).
    The plan is written (as JSON) before the image, so an image on disk always has its plan."""

    def __init__(self, root: Path, memory_bytes: int, disk_bytes: int | None = None):
        self.root = Path(root)
        self.memory_bytes = memory_bytes
        self.disk_bytes = disk_bytes
        self._hot: LRUCache[str, Thumbnail] = LRUCache(maxsize=max(1, memory_bytes),
                                                        getsizeof=lambda e: len(e.image) or 1)
        self._used: dict[str, float] = {}  # disk entry -> last use, for hits the disk never sees
        self.written = 0  # bytes written since the last prune

    def path(self, asset_id: str, key: str, fmt: str) -> Path:
        return self.root / asset_id / f"{key}.{fmt}"

    def get(self, asset_id: str, key: str, fmt: str) -> Thumbnail | None:
        mem_key = f"{asset_id}/{key}.{fmt}"
        hit = self._hot.get(mem_key)
        if hit is None:
            path = self.path(asset_id, key, fmt)
            try:
                data = path.read_bytes()
                plan = RenderPlan.from_json(path.with_suffix(".plan.json").read_text())
            except FileNotFoundError:
                return None
            except ValueError:  # a plan not ours (hand-edited, another version): render again
                return None
            hit = self._remember(mem_key, data, plan)
        self._used[mem_key] = time.time()
        return hit

    def write(self, asset_id: str, key: str, fmt: str, data: bytes, plan: RenderPlan) -> None:
        """The disk half of `put` (blocking: the server runs it in a thread). Prunes when the
        bytes written since the last prune may have taken the folder over its budget."""
        path = self.path(asset_id, key, fmt)
        text = plan.to_json().encode()
        write_atomic(path.with_suffix(".plan.json"), text)
        write_atomic(path, data)
        self.written += len(data) + len(text)
        if self.disk_bytes and self.written > 0.05 * self.disk_bytes:
            self.prune()

    def put(self, asset_id: str, key: str, fmt: str, data: bytes, plan: RenderPlan) -> Thumbnail:
        self.write(asset_id, key, fmt, data, plan)
        return self.remember(asset_id, key, fmt, data, plan)

    def remember(self, asset_id: str, key: str, fmt: str, data: bytes, plan: RenderPlan) -> Thumbnail:
        """The memory half: call it from one thread only (the event loop's)."""
        return self._remember(f"{asset_id}/{key}.{fmt}", data, plan)

    def disk_usage(self) -> int:
        return sum(p.stat().st_size for p in self.root.glob("*/*") if p.is_file())

    def prune(self, max_bytes: int | None = None) -> int:
        """Delete the least recently used thumbnails until the folder holds at most 90% of
        `max_bytes` (default: the disk budget). Blocking: run it in a thread. Returns how
        many files went."""
        max_bytes = max_bytes or self.disk_bytes
        self.written = 0
        if not max_bytes:
            return 0
        files = []
        for path in self.root.glob("*/*"):
            try:
                st = path.stat()
            except FileNotFoundError:
                continue
            image = path.name.replace(".plan.json", "")  # a plan goes with its image
            used = self._used.get(f"{path.parent.name}/{image}", 0.0)
            files.append((max(st.st_mtime, used), st.st_size, path))
        total = sum(size for _, size, _ in files)
        if total <= max_bytes:
            return 0
        removed = 0
        for _, size, path in sorted(files):
            if total <= 0.9 * max_bytes:
                break
            path.unlink(missing_ok=True)  # a plan without its image is never read
            self._used.pop(f"{path.parent.name}/{path.name.replace('.plan.json', '')}", None)
            total -= size
            removed += 1
        return removed

    def forget(self, asset_id: str) -> None:
        for k in [k for k in self._hot if k.startswith(asset_id + "/")]:
            self._hot.pop(k, None)
        for k in [k for k in list(self._used) if k.startswith(asset_id + "/")]:  # prune runs in a thread
            self._used.pop(k, None)

    def _remember(self, mem_key: str, data: bytes, plan: RenderPlan) -> Thumbnail:
        entry = Thumbnail(data, '"' + hashlib.sha256(data).hexdigest()[:32] + '"', plan)
        if len(data) <= self.memory_bytes // 4:
            self._hot[mem_key] = entry
        return entry
