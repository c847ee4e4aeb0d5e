"""The server's side of the render workers: the scheduler and the pool of worker processes.

A crash in a worker (service.workers.jobs) takes down that worker, not the server: the job in
flight fails with a clear message, the worker is replaced, and the next job runs on the new
one. Workers start with `spawn` (GL contexts and fork do not mix). Every job has a deadline;
a worker past it is killed and replaced.
"""
from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

from service.workers.protocol import (
    DeadlineExceeded,
    Job,
    PingJob,
    QueueFull,
    Reply,
    WorkerConfig,
    WorkerCrashed,
    WorkerFailure,
    WorkerInfo,
    unpack,
)

__all__ = ["Pool", "WorkerPool", "WorkerConfig", "WorkerFailure", "WorkerCrashed", "DeadlineExceeded",
           "QueueFull"]

log = logging.getLogger(__name__)


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
    rss_bytes: int | None = None  # after its last job

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process else None

    def alive(self) -> bool:
        return bool(self.process and self.process.is_alive())


@dataclass(eq=False)
class _Waiting:
    """A job waiting for a worker, as the scheduler sees it."""
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
        self._waiting: list[_Waiting] = []
        self._expensive_running = 0
        self._expensive_by: dict[str, int] = {}
        self._queued_by: dict[str, int] = {}
        self._running_by: dict[str, int] = {}
        self._seq = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self.pending = 0  # jobs counted against the queue bound (waiting or running)
        self.info: WorkerInfo | None = None  # the last warm-up's answer
        self._closing = False
        # One waiting thread per busy worker: jobs never wait on threads used elsewhere.
        self._executor = ThreadPoolExecutor(size + 1, thread_name_prefix=thread_prefix)

    @property
    def ready(self) -> bool:
        return any(w.answered and w.alive() for w in self.workers)

    async def run(self, job: Job, *, deadline: float, queue: bool = True, cost_ms: float = 0.0,
                  expensive: bool | None = None, client: str | None = None):
        """Run `job` on a worker within `deadline` seconds of starting it. `queue=True`
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
            waiting = _Waiting(cost_ms, cost_ms > self.cheap_ms if expensive is None else expensive, client,
                               self._next_seq(), time.monotonic(), asyncio.get_running_loop().create_future())
            w = await self._acquire(waiting)
            future = self._executor.submit(self._call, w, job, deadline)
            # Back to the free list when the thread is done with the worker, not when this
            # coroutine is (a cancelled request must not hand a busy worker to another).
            future.add_done_callback(lambda _: self._release_threadsafe(w, waiting))
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

    async def _acquire(self, job: _Waiting):
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

    def _may_start(self, job: _Waiting) -> bool:
        if not job.expensive:
            return True
        if self._expensive_running >= self.expensive_slots:
            return False
        return job.client is None or self._expensive_by.get(job.client, 0) < self.client_slots

    def _release(self, w, job: _Waiting) -> None:
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

    def _release_threadsafe(self, w, job: _Waiting) -> None:
        assert self._loop is not None  # started: a job ran
        try:
            self._loop.call_soon_threadsafe(self._release, w, job)
        except RuntimeError:  # the loop is closed: the server is stopping
            pass

    def _call(self, w, job: Job, deadline: float):
        w.busy_since, w.op = time.time(), job.name
        try:
            reply = self._exchange(w, job, deadline)
        finally:
            w.busy_since, w.op = None, None
        w.jobs += 1
        w.answered = True
        return unpack(job, reply)

    def _exchange(self, w, job: Job, deadline: float) -> Reply:
        raise NotImplementedError

    def status(self) -> list[dict]:
        now = time.time()
        return [{"index": w.index, "pid": w.pid, "alive": w.alive(), "busy": w.busy_since is not None,
                 "op": w.op, "busy_seconds": round(now - w.busy_since, 3) if w.busy_since else None,
                 "jobs": w.jobs, "restarts": w.restarts, "rss_bytes": getattr(w, "rss_bytes", None)}
                for w in self.workers]


def _resident_bytes(pid: int | None) -> int | None:
    """A process's resident set (Linux /proc), or None where it cannot be read."""
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def _worker_process(conn: Connection, config: WorkerConfig) -> None:
    # Imported here: the worker side (GL, renderer, USD, Embree) loads in the worker only.
    from service.workers.jobs import worker_main
    worker_main(conn, config)


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
        proc = self._ctx.Process(target=_worker_process, name=f"render-worker-{w.index}", daemon=True,
                                 args=(child, self.config))
        proc.start()
        child.close()
        w.process, w.conn, w.answered, w.rss_bytes = proc, parent, False, None
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
            self.info = await self.run(PingJob(), deadline=120, queue=False)
        except Exception as exc:  # logged; readiness stays false until a worker answers
            log.error("render worker warm-up failed: %s", exc)

    # -- jobs -------------------------------------------------------------------------------

    def _exchange(self, w: Worker, job: Job, deadline: float) -> Reply:
        op = job.name
        if not w.alive():
            self._replace(w, "was found dead")
        assert w.conn is not None and w.process is not None  # set by _spawn
        try:
            w.conn.send(job)
            if not w.conn.poll(deadline):
                self._replace(w, f"passed the {deadline:g} s deadline of a {op} job")
                raise DeadlineExceeded(f"{op} did not finish within its deadline of "
                                       f"{deadline:g} s; the worker was stopped")
            reply = w.conn.recv()
        except (EOFError, OSError, BrokenPipeError):
            pid = w.pid
            w.process.join(timeout=5)
            code = w.process.exitcode
            how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit status {code}"
            self._replace(w, f"crashed during a {op} job ({how})")
            raise WorkerCrashed(f"render worker (pid {pid}) crashed during {op} ({how}); "
                                "it has been restarted, retry the request") from None
        w.rss_bytes = _resident_bytes(w.pid)
        limit = self.config.max_rss_bytes
        # The answer is in hand; a warm-up is the baseline, not a job that grew the worker.
        if limit and w.rss_bytes is not None and w.rss_bytes > limit and not isinstance(job, PingJob):
            self._replace(w, f"held {w.rss_bytes} resident bytes after a {op} job, over its bound of {limit}")
        return reply
