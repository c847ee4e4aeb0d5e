"""A pool of render worker processes, each owning one headless GL context.

Native code (the GL driver, USD, Embree) runs only in these processes, so a crash takes down
one worker, not the server: the job in flight fails with a clear message, the worker is
replaced, and the next job runs on the new one. Workers start with `spawn` (GL contexts and
fork do not mix) and keep their context, compiled shaders, loaded bakes and uploaded GPU data
warm between jobs. Every job has a deadline; a worker past it is killed and replaced.

This module is imported by the workers themselves, so it keeps its top-level imports light.
"""
from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

log = logging.getLogger(__name__)


class WorkerFailure(RuntimeError):
    """A job could not complete for a reason other than its input (-> HTTP 5xx)."""
    status = 500


class WorkerCrashed(WorkerFailure):
    pass


class DeadlineExceeded(WorkerFailure):
    status = 504


class QueueFull(WorkerFailure):
    status = 503


@dataclass(frozen=True)
class WorkerConfig:
    """What a worker process (or Ray actor) is started with."""
    cache_dir: str
    default_env: str = "footprint_court"
    cache_bytes: int = 512 * 2**20       # baked assets and environments kept in memory
    gpu_bytes: int = 512 * 2**20         # meshes and textures kept uploaded
    bake_cache_bytes: int | None = None  # the bake cache's cap (LRU eviction after each bake)
    limits: dict = field(default_factory=dict)
    log_level: int = logging.INFO


# ---------------------------------------------------------------------------------------------
# The worker process


class WorkerState:
    """What a worker keeps warm between jobs: baked assets and environments in one LRU weighed
    in bytes (the renderer keeps its GPU copies in its own byte-bounded LRU)."""

    def __init__(self, config: WorkerConfig):
        from cachetools import LRUCache
        self.config = config
        self.loaded: LRUCache[tuple, object] = LRUCache(maxsize=config.cache_bytes, getsizeof=_weight)
        import renderer.raster.gpu as gpu
        gpu.set_budget(asset_bytes=config.gpu_bytes, environments=4)

    def limits(self):
        from pipeline.limits import Limits
        return Limits.from_env(**self.config.limits)

    def cache(self):
        from pipeline.cache import Cache
        return Cache(self.config.cache_dir, max_bytes=self.config.bake_cache_bytes or 0)

    def ping(self) -> dict:
        """Creates the GL context, bakes the default environment and compiles the shaders (by
        drawing a packaged sample opaque, as glass and ray traced), so a first request is not
        slower."""
        import renderer
        from gl.context import get_context
        t0 = time.perf_counter()
        ctx = get_context()
        info = {"pid": os.getpid(), "gl_renderer": ctx.info.get("GL_RENDERER", ""),
                "renderer_version": str(getattr(renderer, "RENDERER_VERSION", "0"))}
        try:
            from pipeline.environment.prefilter import list_bundled
            info["environments"] = list(list_bundled())
        except ImportError:
            log.warning("pipeline.environment.prefilter is not available: no bundled environments")
        self._warm()
        info["warm_seconds"] = round(time.perf_counter() - t0, 3)
        return info

    def _warm(self) -> None:
        from pathlib import Path

        import renderer
        from core.options import MaterialOverride, RenderOptions
        from pipeline.bake import bake_asset
        from renderer.methods.auto import environment_face_size
        sample = Path(__file__).resolve().parents[1] / "samples" / "BoxTextured.glb"
        try:
            asset = bake_asset(sample, self.cache())
            # The environment a default-sized thumbnail needs (the face-size policy's answer).
            env = self._env(self.config.default_env, environment_face_size(asset, RenderOptions())[0])
            for override in (None, MaterialOverride(transmission=1.0, ior=1.5, roughness=0.0)):
                renderer.render(asset, env, RenderOptions(width=16, height=16, override=override))
            # and the ray tracer's compiled kernel, loaded from numba's cache (~0.5 s)
            renderer.render(asset, env, RenderOptions(width=16, height=16, method="raytrace"))
        except Exception as exc:  # a worker that cannot warm up still serves what it can
            log.warning("warm-up render failed: %s", exc)

    def inspect(self, path: str, root: str | None = None) -> dict:
        """`root`: the upload's folder (a zip's extraction): references may use all of it."""
        from pipeline.ingest import load_scene
        scene = load_scene(path, self.limits(), root=root)
        return {"format": scene.format, "triangles": int(scene.triangle_count),
                "materials": len(scene.materials), "warnings": list(scene.warnings)[:20],
                "transmissive": any(m.transmission > 0 for m in scene.materials),
                "files": [str(f) for f in scene.files]}

    def bake(self, path: str, root: str | None = None) -> dict:
        from pipeline.bake import bake_asset
        t0 = time.perf_counter()
        baked = bake_asset(path, self.cache(), limits=self.limits(), root=root)
        return {"key": baked.key, "triangles": int(baked.triangle_count),
                "seconds": time.perf_counter() - t0}

    def bake_env(self, source: str) -> dict:
        from core.cubemap import DEFAULT_FACE_SIZE
        env = self._env(source, DEFAULT_FACE_SIZE)
        return {"key": env.key, "face_size": env.face_size}

    def render(self, key: str, env_source: str, options, fmt: str) -> dict:
        """`options` is a core.options.RenderOptions; the environment is sized for it by
        the same policy the CLI uses (renderer.methods.auto.environment_face_size)."""
        import renderer
        from renderer.methods.auto import environment_face_size
        t0 = time.perf_counter()
        asset = self._cached(("asset", key), lambda: _load_baked(key, self.cache()))
        _touch(self.cache(), key)  # in use: the bake cache's LRU must not see it as cold
        env = self._env(env_source, environment_face_size(asset, options)[0])
        if options.animate or options.time is not None or options.animation is not None:
            # posed from the upload (pipeline.animate), its references inside its own folder
            from pathlib import Path

            from pipeline.animate import poses_for
            from renderer.sequence import encode_animation, render_animation
            source = Path(asset.manifest["source"])
            poses, motion = poses_for(source, asset, options, source.parent, self.limits())
            if not options.animate:
                asset = poses[0]
            else:
                frames = render_animation(poses, env, options, motion or {})
                data = encode_animation(frames, fmt, frame_ms=1000.0 / options.animate)
                return {"image": data, "plan": dict(frames[0].plan), "seconds": time.perf_counter() - t0}
        if options.turntable:  # N frames from one upload and one bake, one animated image
            from renderer.sequence import encode_animation, render_turntable
            frames = render_turntable(asset, env, options, keep_linear=False)  # encoded only
            frame, data = frames[0], encode_animation(frames, fmt)
        else:
            if options.views:
                from renderer.sequence import render_views
                frame = render_views(asset, env, options)
            else:
                frame = renderer.render(asset, env, options)
            data = frame.encode(fmt)
        plan = dict(getattr(frame, "plan", {}) or {})
        return {"image": data, "plan": plan, "seconds": time.perf_counter() - t0}

    def _env(self, source: str, face_size: int):
        from pipeline.bake import bake_environment
        return self._cached(("env", f"{face_size}:{source}"), lambda: bake_environment(
            source, self.cache(), face_size=face_size))

    def _cached(self, key: tuple, make):
        value = self.loaded.get(key)
        if value is None:
            value = make()
            if _weight(value) <= self.loaded.maxsize:  # one too big for the budget is not kept
                self.loaded[key] = value
        return value


def _weight(value) -> int:
    """Bytes a baked asset or environment may hold in memory: its arrays, and each texture's
    whole mip chain in every colour space it is read in (decompressed on demand, so this is
    the most it can grow to, whatever a render has read yet)."""
    arrays = list(getattr(value, "specular", None) or []) + [getattr(value, "brdf_lut", None)]
    total = sum(a.nbytes for a in arrays if a is not None)
    for m in getattr(value, "meshes", []):
        total += sum(a.nbytes for a in (m.positions, m.normals, m.indices, m.tangents, m.uv0, m.uv1,
                                        m.colors, m.interior) if a is not None)
    for t in getattr(value, "textures", []):
        h, w = getattr(t, "size", (0, 0))
        total += h * w * 4 * 4 // 3 * max(1, len(getattr(t, "spaces", ()) or (True,)))
    return max(1, total)


def _touch(cache, key: str) -> None:
    try:
        os.utime(cache.entry_dir("assets", key) / "manifest.json")
    except (OSError, ValueError):
        pass  # gone or read-only: the next load finds out


def _load_baked(key: str, cache):
    from pipeline.bake import load_baked
    return load_baked(key, cache)


def answer(state: WorkerState, op: str, args: tuple) -> tuple[str, object]:
    """Run one job in a worker (process or Ray actor): ("ok", value), ("asset_error", the
    AssetError itself: it pickles as its own class) or ("error", text)."""
    from core.errors import AssetError
    try:
        return ("ok", getattr(state, op)(*args))
    except AssetError as exc:
        return ("asset_error", exc)
    except MemoryError:
        return ("error", "out of memory")
    except Exception as exc:  # reported to the caller as a 500 with this text
        log.exception("job %s failed", op)
        return ("error", f"{type(exc).__name__}: {exc}")


def unpack_reply(op: str, status: str, value):
    """A worker's reply as the job's value, or the exception it stands for."""
    if status == "ok":
        return value
    if status == "asset_error":
        raise value
    raise WorkerFailure(f"{op} failed in the render worker: {value}")


def _worker_main(conn, config: WorkerConfig) -> None:
    logging.basicConfig(level=config.log_level, format="%(levelname)s worker %(process)d %(name)s: %(message)s")
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server stops us; Ctrl-C goes to it
    state = WorkerState(config)
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            return
        reply = answer(state, op, args)
        try:
            conn.send(reply)
        except (BrokenPipeError, OSError):
            return


# ---------------------------------------------------------------------------------------------
# The server side


@dataclass
class Worker:
    index: int
    process: BaseProcess | None = None
    conn: Connection | None = None
    busy_since: float | None = None
    op: str | None = None
    jobs: int = 0
    restarts: int = 0
    answered: bool = False
    info: dict = field(default_factory=dict)

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process else None

    def alive(self) -> bool:
        return bool(self.process and self.process.is_alive())


@dataclass(eq=False)
class _Job:
    cost_ms: float
    expensive: bool
    client: str | None
    seq: int
    enqueued: float
    future: asyncio.Future


class Pool:
    """What the process pool and the Ray actor pool (service/workers/ray.py) share: the queue
    bound, one job per worker at a time, the order jobs get workers in, busy bookkeeping,
    readiness and status. A subclass creates `self.workers` and supplies start/stop/_replace
    and `_exchange`, which runs one job on one worker and returns its (status, value) reply.

    Order: a free worker goes to a waiting job of the client running fewest jobs (clients take
    turns), and among those to the lowest estimated cost, less `AGING_MS_PER_S` for every
    second it has waited (so an expensive job is never starved).
    Expensive jobs (over `cheap_ms`: big renders, bakes, uploads' ingest) hold at most all
    workers but one, so a cheap render never waits behind them, and one client (API key or
    address) holds at most its `client_share` of the workers with them and of the queue."""

    AGING_MS_PER_S = 1000.0

    def __init__(self, size: int, config: WorkerConfig, max_queue: int, on_restart, thread_prefix: str,
                 cheap_ms: float = 2000.0, client_share: float = 1.0):
        self.size = size
        self.config = config
        self.max_queue = max_queue
        self.on_restart = on_restart or (lambda reason: None)
        self.cheap_ms = cheap_ms
        self.expensive_slots = max(1, size - 1)
        self.client_slots = max(1, int(client_share * size))
        self.client_queue = max(1, int(client_share * max_queue))
        self.workers: list = []
        self._free: list = []
        self._waiting: list[_Job] = []
        self._expensive_running = 0
        self._expensive_by: dict[str, int] = {}
        self._queued_by: dict[str, int] = {}
        self._running_by: dict[str, int] = {}
        self._seq = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self.pending = 0  # jobs counted against the queue bound (waiting or running)
        self.info: dict = {}
        self._closing = False
        # One waiting thread per busy worker: jobs never wait on threads used elsewhere.
        self._executor = ThreadPoolExecutor(size + 1, thread_name_prefix=thread_prefix)

    @property
    def ready(self) -> bool:
        return any(w.answered and w.alive() for w in self.workers)

    async def run(self, op: str, *args, deadline: float, queue: bool = True, cost_ms: float = 0.0,
                  expensive: bool | None = None, client: str | None = None):
        """Run `op(*args)` on a worker within `deadline` seconds of starting it. `queue=True`
        counts the job against the bound (requests); background work does not. `cost_ms` is
        the job's estimated cost; `client` who asked (None: the service itself)."""
        if queue:
            if self.pending >= self.max_queue:
                raise QueueFull(f"render queue is full ({self.pending} waiting or running)")
            if client is not None and self._queued_by.get(client, 0) >= self.client_queue:
                raise QueueFull(f"you have {self.client_queue} renders waiting or running, your "
                                "share of the queue; retry when one has finished")
            self.pending += 1
            if client is not None:
                self._queued_by[client] = self._queued_by.get(client, 0) + 1
        try:
            job = _Job(cost_ms, cost_ms > self.cheap_ms if expensive is None else expensive, client,
                       self._next_seq(), time.monotonic(), asyncio.get_running_loop().create_future())
            w = await self._acquire(job)
            future = self._executor.submit(self._call, w, op, args, deadline)
            # Back to the free list when the thread is done with the worker, not when this
            # coroutine is (a cancelled request must not hand a busy worker to another).
            future.add_done_callback(lambda _: self._release_threadsafe(w, job))
            return await asyncio.wrap_future(future)
        finally:
            if queue:
                self.pending -= 1
                if client is not None:
                    self._queued_by[client] -= 1
                    if not self._queued_by[client]:
                        del self._queued_by[client]

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    async def _acquire(self, job: _Job):
        self._waiting.append(job)
        self._dispatch()
        try:
            return await job.future
        except asyncio.CancelledError:
            if job in self._waiting:
                self._waiting.remove(job)
            elif job.future.done() and not job.future.cancelled():
                self._release(job.future.result(), job)  # handed a worker it will not use
            raise

    def _dispatch(self) -> None:
        """Give free workers to the best eligible waiting jobs (event loop thread only)."""
        while self._free and self._waiting:
            now = time.monotonic()
            eligible = [j for j in self._waiting if not j.future.done() and self._may_start(j)]
            if not eligible:
                return
            # Among the eligible: the client running fewest jobs first (clients take turns), then
            # the lowest cost less its aging credit, then the oldest.
            job = min(eligible, key=lambda j: (self._running_by.get(j.client, 0) if j.client else 0,
                                               j.cost_ms - self.AGING_MS_PER_S * (now - j.enqueued), j.seq))
            self._waiting.remove(job)
            w = self._free.pop(0)
            if job.client is not None:
                self._running_by[job.client] = self._running_by.get(job.client, 0) + 1
            if job.expensive:
                self._expensive_running += 1
                if job.client is not None:
                    self._expensive_by[job.client] = self._expensive_by.get(job.client, 0) + 1
            job.future.set_result(w)

    def _may_start(self, job: _Job) -> bool:
        if not job.expensive:
            return True
        if self._expensive_running >= self.expensive_slots:
            return False
        return job.client is None or self._expensive_by.get(job.client, 0) < self.client_slots

    def _release(self, w, job: _Job) -> None:
        if job.client is not None:
            self._running_by[job.client] -= 1
            if not self._running_by[job.client]:
                del self._running_by[job.client]
        if job.expensive:
            self._expensive_running -= 1
            if job.client is not None:
                self._expensive_by[job.client] -= 1
                if not self._expensive_by[job.client]:
                    del self._expensive_by[job.client]
        self._free.append(w)
        self._dispatch()

    def _release_threadsafe(self, w, job: _Job) -> None:
        assert self._loop is not None  # started: a job ran
        try:
            self._loop.call_soon_threadsafe(self._release, w, job)
        except RuntimeError:  # the loop is closed: the server is stopping
            pass

    def _call(self, w, op: str, args: tuple, deadline: float):
        w.busy_since, w.op = time.time(), op
        try:
            status, value = self._exchange(w, op, args, deadline)
        finally:
            w.busy_since, w.op = None, None
        w.jobs += 1
        w.answered = True
        return unpack_reply(op, status, value)

    def _exchange(self, w, op: str, args: tuple, deadline: float) -> tuple[str, object]:
        raise NotImplementedError

    def status(self) -> list[dict]:
        now = time.time()
        return [{"index": w.index, "pid": w.pid, "alive": w.alive(), "busy": w.busy_since is not None,
                 "op": w.op, "busy_seconds": round(now - w.busy_since, 3) if w.busy_since else None,
                 "jobs": w.jobs, "restarts": w.restarts} for w in self.workers]


class WorkerPool(Pool):
    def __init__(self, size: int, config: WorkerConfig, max_queue: int = 64, on_restart=None, **order):
        super().__init__(size, config, max_queue, on_restart, "render-pool", **order)
        self._ctx = mp.get_context("spawn")
        self.workers = [Worker(i) for i in range(size)]
        self._tasks: set[asyncio.Task] = set()

    # -- life cycle -------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = loop = asyncio.get_running_loop()
        await asyncio.gather(*(loop.run_in_executor(self._executor, self._spawn, w) for w in self.workers))
        self._free = list(self.workers)

    async def warm_up(self) -> None:
        """Ping every worker once (GL context, default environment, shaders); readiness follows
        the first answer. Each ping is a worker's first job, so requests wait for it."""
        await asyncio.gather(*(self._ping() for _ in self.workers))

    async def stop(self) -> None:
        self._closing = True
        for w in self.workers:
            try:
                if w.conn:
                    w.conn.close()
            except OSError:
                pass
            if w.process:
                w.process.join(timeout=2)
                if w.process.is_alive():
                    w.process.kill()
                    w.process.join(timeout=2)
        self._executor.shutdown(wait=False, cancel_futures=True)

    def _spawn(self, w: Worker) -> None:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_worker_main, name=f"render-worker-{w.index}", daemon=True,
                                 args=(child, self.config))
        proc.start()
        child.close()
        w.process, w.conn, w.answered = proc, parent, False
        log.info("render worker %d started (pid %d)", w.index, proc.pid)

    def _replace(self, w: Worker, reason: str) -> None:
        if self._closing:
            return
        if w.process and w.process.is_alive():
            w.process.kill()
        if w.process:
            w.process.join(timeout=5)
        try:
            if w.conn is not None:
                w.conn.close()
        except OSError:
            pass
        w.restarts += 1
        self.on_restart(reason)
        log.warning("render worker %d (pid %s) %s; restarting it", w.index, w.pid, reason)
        self._spawn(w)
        # Warm the new worker (GL context) without holding up the failed request's answer.
        assert self._loop is not None  # started: workers are replaced only then
        self._loop.call_soon_threadsafe(self._ping_soon)

    def _ping_soon(self) -> None:
        assert self._loop is not None
        task = self._loop.create_task(self._ping())
        self._tasks.add(task)  # the loop keeps only weak references to tasks
        task.add_done_callback(self._tasks.discard)

    async def _ping(self) -> None:
        try:
            self.info = await self.run("ping", deadline=120, queue=False)
        except Exception as exc:  # logged; readiness stays false until a worker answers
            log.error("render worker warm-up failed: %s", exc)

    # -- jobs -------------------------------------------------------------------------------

    def _exchange(self, w: Worker, op: str, args: tuple, deadline: float):
        if not w.alive():
            self._replace(w, "was found dead")
        assert w.conn is not None and w.process is not None  # set by _spawn
        try:
            w.conn.send((op, args))
            if not w.conn.poll(deadline):
                self._replace(w, f"passed the {deadline:g} s deadline of a {op} job")
                raise DeadlineExceeded(f"{op} did not finish within its deadline of "
                                       f"{deadline:g} s; the worker was stopped")
            return w.conn.recv()
        except (EOFError, OSError, BrokenPipeError):
            pid = w.pid
            w.process.join(timeout=5)
            code = w.process.exitcode
            how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit status {code}"
            self._replace(w, f"crashed during a {op} job ({how})")
            raise WorkerCrashed(f"render worker (pid {pid}) crashed during {op} ({how}); "
                                "it has been restarted, retry the request") from None
