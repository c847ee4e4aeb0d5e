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
from collections import OrderedDict
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


class JobAssetError(Exception):
    """An AssetError raised in a worker, carried back with its class name."""

    def __init__(self, kind: str, path: str, reason: str):
        self.kind, self.path, self.reason = kind, path, reason
        super().__init__(f"{path}: {reason}")


# ---------------------------------------------------------------------------------------------
# The worker process


class WorkerState:
    """What a worker keeps warm between jobs (the renderer keeps its own GPU-side LRU)."""

    def __init__(self, cache_dir: str, limits: dict):
        self.cache_dir = cache_dir
        self.limits_overrides = limits
        self.assets: OrderedDict[str, object] = OrderedDict()
        self.envs: OrderedDict[str, object] = OrderedDict()

    def limits(self):
        from pipeline.limits import Limits
        return Limits.from_env(**self.limits_overrides)

    def ping(self) -> dict:
        """Creates the GL context (the slow part of a first render) and says what we run."""
        import renderer
        from core.context import get_context
        ctx = get_context()
        info = {"pid": os.getpid(), "gl_renderer": ctx.info.get("GL_RENDERER", ""),
                "renderer_version": str(getattr(renderer, "RENDERER_VERSION", "0"))}
        try:
            from pipeline.environment import list_bundled
            info["environments"] = list(list_bundled())
        except ImportError:
            log.warning("pipeline.environment is not available: no bundled environments")
        return info

    def inspect(self, path: str) -> dict:
        import pipeline
        scene = pipeline.load_scene(path, self.limits())
        return {"format": scene.format, "triangles": int(scene.triangle_count),
                "materials": len(scene.materials), "warnings": list(scene.warnings)[:20]}

    def bake(self, path: str) -> dict:
        import pipeline
        t0 = time.perf_counter()
        baked = pipeline.bake_asset(path, self.cache_dir)
        return {"key": baked.key, "triangles": int(baked.triangle_count),
                "seconds": time.perf_counter() - t0}

    def bake_env(self, source: str) -> dict:
        from core.cubemap import DEFAULT_FACE_SIZE
        env = self._env(source, DEFAULT_FACE_SIZE)
        return {"key": env.key, "face_size": env.face_size}

    def render(self, key: str, env_source: str, options, fmt: str) -> dict:
        """`options` is a core.options.RenderOptions; the environment is sized for it by
        the same policy the CLI uses (renderer.auto.environment_face_size)."""
        import renderer
        from renderer.auto import environment_face_size
        t0 = time.perf_counter()
        asset = self._cached(self.assets, key, 16, lambda: _load_baked(key, self.cache_dir))
        env = self._env(env_source, environment_face_size(asset, options)[0])
        frame = renderer.render(asset, env, options)
        data = frame.encode(fmt)
        plan = dict(getattr(frame, "plan", {}) or {})
        return {"image": data, "plan": plan, "seconds": time.perf_counter() - t0}

    def _env(self, source: str, face_size: int):
        import pipeline
        return self._cached(self.envs, f"{face_size}:{source}", 4, lambda: pipeline.bake_environment(
            source, self.cache_dir, face_size=face_size))

    @staticmethod
    def _cached(table: OrderedDict, key: str, size: int, make):
        value = table.get(key)
        if value is None:
            value = make()
            table[key] = value
            while len(table) > size:
                table.popitem(last=False)
        table.move_to_end(key)
        return value


def _load_baked(key: str, cache_dir: str):
    import pipeline
    return pipeline.load_baked(key, cache_dir)


def answer(state: WorkerState, op: str, args: tuple) -> tuple[str, object]:
    """Run one job in a worker (process or Ray actor): ("ok", value), ("asset_error",
    (class name, path, reason)) or ("error", text); `unpack_reply` turns it back server-side."""
    from core.errors import AssetError
    try:
        return ("ok", getattr(state, op)(*args))
    except AssetError as exc:
        return ("asset_error", (type(exc).__name__, exc.path, exc.reason))
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
        raise JobAssetError(*value)
    raise WorkerFailure(f"{op} failed in the render worker: {value}")


def _worker_main(conn, cache_dir: str, limits: dict, log_level: int) -> None:
    logging.basicConfig(level=log_level, format="%(levelname)s worker %(process)d %(name)s: %(message)s")
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server stops us; Ctrl-C goes to it
    state = WorkerState(cache_dir, limits)
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


class Pool:
    """What the process pool and the Ray actor pool (service/ray_workers.py) share: the queue
    bound, one job per worker at a time, busy bookkeeping, readiness and status. A subclass
    creates `self.workers` and supplies start/stop/_replace and `_exchange`, which runs one job
    on one worker and returns its (status, value) reply."""

    def __init__(self, size: int, cache_dir: str | os.PathLike, limits: dict | None,
                 max_queue: int, on_restart, thread_prefix: str):
        self.size = size
        self.cache_dir = str(cache_dir)
        self.limits = dict(limits or {})
        self.max_queue = max_queue
        self.on_restart = on_restart or (lambda reason: None)
        self.workers: list = []
        self._idle: asyncio.Queue | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.pending = 0  # jobs counted against the queue bound (waiting or running)
        self.info: dict = {}
        self._closing = False
        # One waiting thread per busy worker: jobs never wait on threads used elsewhere.
        self._executor = ThreadPoolExecutor(size + 1, thread_name_prefix=thread_prefix)

    @property
    def ready(self) -> bool:
        return any(w.answered and w.alive() for w in self.workers)

    async def run(self, op: str, *args, deadline: float, queue: bool = True):
        """Run `op(*args)` on a free worker within `deadline` seconds of starting it.
        `queue=True` counts the job against the bound (renders); background work does not."""
        assert self._idle is not None, "the pool is not started"
        if queue:
            if self.pending >= self.max_queue:
                raise QueueFull(f"render queue is full ({self.pending} waiting or running)")
            self.pending += 1
        try:
            w = await self._idle.get()
            job = self._executor.submit(self._call, w, op, args, deadline)
            # Back to the idle queue when the thread is done with the worker, not when this
            # coroutine is (a cancelled request must not hand a busy worker to another).
            job.add_done_callback(lambda _: self._release(w))
            return await asyncio.wrap_future(job)
        finally:
            if queue:
                self.pending -= 1

    def _release(self, w) -> None:
        assert self._loop is not None and self._idle is not None  # started: a job ran
        try:
            self._loop.call_soon_threadsafe(self._idle.put_nowait, w)
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
    def __init__(self, size: int, cache_dir: str, limits: dict | None = None,
                 max_queue: int = 64, on_restart=None):
        super().__init__(size, cache_dir, limits, max_queue, on_restart, "render-pool")
        self._ctx = mp.get_context("spawn")
        self.workers = [Worker(i) for i in range(size)]
        self._tasks: set[asyncio.Task] = set()

    # -- life cycle -------------------------------------------------------------------------

    async def start(self) -> None:
        self._idle = asyncio.Queue()
        self._loop = loop = asyncio.get_running_loop()
        await asyncio.gather(*(loop.run_in_executor(self._executor, self._spawn, w) for w in self.workers))
        for w in self.workers:
            self._idle.put_nowait(w)

    async def warm_up(self) -> None:
        """Ping every worker once (creates its GL context); readiness follows the first answer."""
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
                                 args=(child, self.cache_dir, self.limits,
                                       logging.getLogger().getEffectiveLevel()))
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
