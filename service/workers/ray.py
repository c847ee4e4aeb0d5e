"""The render pool on a Ray cluster: one Ray actor per worker, each owning one headless GL context.

Same interface as `service.workers.pool.WorkerPool` (start, warm_up, run, stop, ready, status,
pending, workers), so the service switches with one setting (`--executor ray`). An actor is
the Ray counterpart of a worker process: it keeps its GL context, shaders, loaded bakes and
GPU data warm between jobs and runs one job at a time; it runs the very same job code
(`jobs.WorkerState` through `jobs.answer`, typed by `protocol`). Actors are placed by Ray anywhere in the
cluster (`num_gpus` > 0 puts each on a GPU share), and read bakes from the shared cache, which
must sit at the same absolute path on every node.

Failure: an actor is created with max_restarts=0 and this pool replaces it itself, so the job
in flight when it died fails once with a clear message (WorkerCrashed, HTTP 500) and the next
job runs on the new actor, as with local worker processes. A job past its deadline gets its
actor killed and replaced (DeadlineExceeded, 504).
"""
from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.executors import connect, disconnect, require_ray, task_env
from service.workers.pool import Pool
from service.workers.protocol import DeadlineExceeded, Job, PingJob, Reply, WorkerConfig, WorkerCrashed

log = logging.getLogger(__name__)


class RenderActor:
    """Runs in a Ray worker process: one GL context and warm state, jobs one at a time."""

    def __init__(self, config: WorkerConfig):
        # Imported here: the worker side (GL, renderer, USD, Embree) loads in the actor only.
        from service.workers.jobs import WorkerState, answer
        logging.basicConfig(level=config.log_level, format="%(levelname)s actor %(process)d %(name)s: %(message)s")
        self.state, self._answer = WorkerState(config), answer

    def call(self, job: Job) -> Reply:
        return self._answer(self.state, job)

    def where(self) -> dict:
        import ray  # the optional dependency, present where an actor runs
        return {"pid": os.getpid(), "node": ray.util.get_node_ip_address()}


@dataclass
class ActorWorker:
    index: int
    actor: Any = None  # a Ray actor handle
    where_ref: object = None      # the actor's pid and node, resolved when it has answered
    where: dict = field(default_factory=dict)
    dead: bool = False
    busy_since: float | None = None
    op: str | None = None
    jobs: int = 0
    restarts: int = 0
    answered: bool = False

    @property
    def pid(self) -> int | None:
        if not self.where and self.where_ref is not None:
            import ray  # the optional dependency: this pool was made with it
            ready, _ = ray.wait([self.where_ref], timeout=0)
            if ready:
                try:
                    self.where = ray.get(ready[0])
                except ray.exceptions.RayError:
                    self.dead = True
        return self.where.get("pid")

    def alive(self) -> bool:
        return self.actor is not None and not self.dead


class RayWorkerPool(Pool):
    def __init__(self, size: int, config: WorkerConfig | str, max_queue: int = 64, on_restart=None,
                 address: str | None = None, num_gpus: float = 0.0, num_cpus: float = 1.0, **order):
        self._ray = require_ray()  # fails here, at startup, with how to install it
        if isinstance(config, str):
            config = WorkerConfig(cache_dir=config)
        # Absolute: actors on other nodes resolve it on the same shared mount.
        config = dataclasses.replace(config, cache_dir=str(Path(config.cache_dir).absolute()))
        super().__init__(size, config, max_queue, on_restart, "ray-render-pool", **order)
        self.address = address
        self.num_gpus, self.num_cpus = num_gpus, num_cpus
        self.workers = [ActorWorker(i) for i in range(size)]
        self._actor_class: Any = None  # the Ray actor class, made in start()

    # -- life cycle -------------------------------------------------------------------------

    async def start(self) -> None:
        ray = self._ray
        self._loop = loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._executor, connect, self.address)
        options: dict[str, Any] = {"num_cpus": self.num_cpus, "num_gpus": self.num_gpus, "max_restarts": 0,
                   "max_concurrency": 1}
        if env := task_env():
            options["runtime_env"] = env
        self._actor_class = ray.remote(RenderActor).options(**options)
        for w in self.workers:
            self._spawn(w)
        self._free = list(self.workers)

    async def warm_up(self, deadline: float = 120.0) -> None:
        """Ping every actor once (creates its GL context); readiness follows the first answer."""
        async def one():
            try:
                self.info = await self.run(PingJob(), deadline=deadline, queue=False)
            except Exception as exc:
                log.error("render actor warm-up failed: %s", exc)
        await asyncio.gather(*(one() for _ in self.workers))

    async def stop(self) -> None:
        self._closing = True
        for w in self.workers:
            self._kill(w)
        self._executor.shutdown(wait=False, cancel_futures=True)
        disconnect()

    def _spawn(self, w: ActorWorker) -> None:
        w.actor = self._actor_class.remote(self.config)
        w.where_ref, w.where, w.dead, w.answered = w.actor.where.remote(), {}, False, False
        log.info("render actor %d created", w.index)

    def _kill(self, w: ActorWorker) -> None:
        if w.actor is not None:
            try:
                self._ray.kill(w.actor, no_restart=True)
            except Exception:  # already gone
                pass

    def _replace(self, w: ActorWorker, reason: str) -> None:
        if self._closing:
            return
        self._kill(w)
        w.restarts += 1
        self.on_restart(reason)
        log.warning("render actor %d (pid %s on %s) %s; replacing it", w.index, w.where.get("pid"),
                    w.where.get("node", "?"), reason)
        self._spawn(w)

    # -- jobs -------------------------------------------------------------------------------

    def _exchange(self, w: ActorWorker, job: Job, deadline: float) -> Reply:
        ray, op = self._ray, job.name
        if w.dead:
            self._replace(w, "was found dead")
        ref = w.actor.call.remote(job)
        try:
            return ray.get(ref, timeout=deadline)
        except ray.exceptions.GetTimeoutError:
            self._replace(w, f"passed the {deadline:g} s deadline of a {op} job")
            raise DeadlineExceeded(f"{op} did not finish within its deadline of {deadline:g} s; "
                                   "the render actor was stopped") from None
        except ray.exceptions.RayActorError as exc:
            pid, node = w.pid or w.where.get("pid"), w.where.get("node", "?")
            cause = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
            w.dead = True
            self._replace(w, f"died during a {op} job")
            raise WorkerCrashed(f"render actor (pid {pid} on {node}) died during {op} ({cause}); "
                                "it has been replaced, retry the request") from None
