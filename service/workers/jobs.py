"""The worker side: what a render process (or Ray actor) keeps warm and how it runs each job.

Native code (the GL driver, USD, Embree) runs only here, so a crash takes down one worker,
not the server. A worker keeps its GL context, compiled shaders, loaded bakes and uploaded GPU
data warm between jobs, and answers each job (service.workers.protocol) with one typed reply.
"""
from __future__ import annotations

import logging
import os
import signal
import time
from pathlib import Path

from cachetools import LRUCache

import renderer
from core.baked import BakedAsset, BakedEnvironment
from core.cubemap import DEFAULT_FACE_SIZE
from core.errors import AssetError
from core.options import MaterialOverride, RenderOptions
from gl.context import get_context
from pipeline.animate import poses_for
from pipeline.bake import ASSET_OPTIONS, USD_SUFFIXES, asset_options, bake_asset, bake_environment, load_baked
from pipeline.cache import Cache
from pipeline.environment.prefilter import list_bundled
from pipeline.ingest import load_scene
from pipeline.library import drawless, usd_parts
from pipeline.lighting import environment_source
from pipeline.limits import Limits
from renderer.methods.auto import environment_face_size
from renderer.raster import gpu
from renderer.sequence import encode_animation, render_animation, render_turntable, render_views
from service.workers import memory
from service.workers.protocol import (
    AssetSummary,
    BakeEnvironmentJob,
    BakeJob,
    BakeResult,
    Done,
    EnvironmentResult,
    Failed,
    InspectJob,
    Job,
    PartsJob,
    PingJob,
    Refused,
    RenderJob,
    RenderPlan,
    RenderReply,
    Reply,
    WorkerConfig,
    WorkerInfo,
)

log = logging.getLogger(__name__)

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "BoxTextured.glb"  # drawn by the warm-up


class WorkerState:
    """What a worker keeps warm between jobs: baked assets and environments in one LRU weighed
    in bytes (the renderer keeps its GPU copies in its own byte-bounded LRU)."""

    def __init__(self, config: WorkerConfig):
        self.config = config
        self.loaded: LRUCache[tuple, BakedAsset | BakedEnvironment] = LRUCache(
            maxsize=config.cache_bytes, getsizeof=lambda v: max(1, v.nbytes()))
        self.cache = Cache(config.cache_dir, max_bytes=config.bake_cache_bytes or 0)
        self.limits = Limits.from_env(**config.limits)
        gpu.set_budget(asset_bytes=config.gpu_bytes, environments=4)

    def run(self, job: Job):
        """The job's typed result; an AssetError when its input is refused."""
        if isinstance(job, RenderJob):
            return self.render(job)
        if isinstance(job, InspectJob):
            return self.inspect(job)
        if isinstance(job, BakeJob):
            return self.bake(job)
        if isinstance(job, PartsJob):
            root = Path(job.root)
            layers = [root / f for f in job.files]
            skip = set(usd_parts(layers)) | drawless(layers)  # parts, material libraries
            return tuple(sorted(Path(p).relative_to(root).as_posix() for p in skip))
        if isinstance(job, BakeEnvironmentJob):
            env = self._env(job.source, DEFAULT_FACE_SIZE)
            return EnvironmentResult(env.key, env.face_size)
        if isinstance(job, PingJob):
            return self.ping()
        raise TypeError(f"not a job: {job!r}")

    def ping(self) -> WorkerInfo:
        """Creates the GL context, bakes the default environment and compiles the shaders (by
        drawing a packaged sample opaque, as glass and ray traced), so a first request is not
        slower."""
        t0 = time.perf_counter()
        ctx = get_context()
        self._warm()
        return WorkerInfo(pid=os.getpid(), gl_renderer=ctx.info.get("GL_RENDERER", ""),
                          renderer_version=str(renderer.RENDERER_VERSION),
                          environments=tuple(list_bundled()),
                          warm_seconds=round(time.perf_counter() - t0, 3))

    def _warm(self) -> None:
        try:
            asset = bake_asset(SAMPLE, self.cache)
            # The environment a default-sized thumbnail needs (the face-size policy's answer).
            env = self._env(self.config.default_env, environment_face_size(asset, RenderOptions())[0])
            for override in (None, MaterialOverride(transmission=1.0, ior=1.5, roughness=0.0)):
                renderer.render(asset, env, RenderOptions(width=16, height=16, override=override))
            # and the ray tracer's compiled kernel, loaded from numba's cache
            renderer.render(asset, env, RenderOptions(width=16, height=16, method="raytrace"))
        except Exception as exc:  # a worker that cannot warm up still serves what it can
            log.warning("warm-up render failed: %s", exc)

    def inspect(self, job: InspectJob) -> AssetSummary:
        scene = load_scene(job.path, self.limits, root=job.root)
        return AssetSummary(format=scene.format, triangles=int(scene.triangle_count),
                            materials=len(scene.materials), warnings=tuple(scene.warnings)[:20],
                            transmissive=any(m.transmission > 0 for m in scene.materials),
                            emitters=int(scene.emissive_triangle_count),
                            files=tuple(str(f) for f in scene.files))

    def bake(self, job: BakeJob) -> BakeResult:
        t0 = time.perf_counter()
        baked = bake_asset(job.path, self.cache, limits=self.limits, root=job.root)
        return BakeResult(baked.key, int(baked.triangle_count), time.perf_counter() - t0)

    def render(self, job: RenderJob) -> RenderReply:
        """The environment is sized for the options by the same policy the CLI uses
        (renderer.methods.auto.environment_face_size)."""
        t0 = time.perf_counter()
        options = job.options
        asset = self._cached(("asset", job.key), lambda: load_baked(job.key, self.cache))
        self.cache.touch("assets", job.key)  # in use: the bake cache's LRU must not see it as cold
        assert isinstance(asset, BakedAsset)
        wanted = asset_options(options)
        if any(wanted[k] != ASSET_OPTIONS[k] for k in wanted) and \
                asset.manifest["source"].lower().endswith(USD_SUFFIXES):
            # another population of the stage: its own bake (cached, keyed by the selection)
            source = Path(asset.manifest["source"])
            asset = self._cached(("asset", job.key, repr(sorted(wanted.items()))), lambda: bake_asset(
                source, self.cache, limits=self.limits, root=job.root or source.parent, **wanted))
        env_source = job.env_source if not job.env_default else environment_source(
            asset, asset.manifest["source"], None, job.env_source, options.lights)
        env = self._env(env_source, environment_face_size(asset, options)[0])
        if options.animate or options.time is not None or options.animation is not None:
            # posed from the upload (pipeline.animate), its references inside its own folder
            source = Path(asset.manifest["source"])
            poses, motion = poses_for(source, asset, options, source.parent, self.limits)
            if not options.animate:
                asset = poses[0]
            else:
                frames = render_animation(poses, env, options, motion or {})
                data = encode_animation(frames, job.fmt, frame_ms=1000.0 / options.animate)
                return RenderReply(data, RenderPlan.of(frames[0].plan), time.perf_counter() - t0)
        if options.turntable:  # N frames from one upload and one bake, one animated image
            frames = render_turntable(asset, env, options, keep_linear=False)  # encoded only
            frame, data = frames[0], encode_animation(frames, job.fmt)
        else:
            frame = render_views(asset, env, options) if options.views else renderer.render(asset, env, options)
            data = frame.encode(job.fmt)
        return RenderReply(data, RenderPlan.of(frame.plan), time.perf_counter() - t0)

    def _env(self, source: str, face_size: int) -> BakedEnvironment:
        env = self._cached(("env", f"{face_size}:{source}"), lambda: bake_environment(
            source, self.cache, face_size=face_size))
        assert isinstance(env, BakedEnvironment)
        return env

    def _cached(self, key: tuple, make):
        value = self.loaded.get(key)
        if value is None:
            value = make()
            if value.nbytes() <= self.loaded.maxsize:  # one too big for the budget is not kept
                self.loaded[key] = value
        return value


def answer(state: WorkerState, job: Job) -> Reply:
    """Run one job in a worker (process or Ray actor) and wrap its outcome for the wire; what
    the job freed goes back to the system before the answer does (service.workers.memory), so
    the RSS the pool reads after it is what the worker keeps."""
    try:
        return Done(state.run(job))
    except AssetError as exc:
        return Refused(exc)
    except MemoryError:
        return Failed("out of memory")
    except Exception as exc:  # reported to the caller as a 500 with this text
        log.exception("job %s failed", job.name)
        return Failed(f"{type(exc).__name__}: {exc}")
    finally:
        memory.release_free_memory()


def worker_main(conn, config: WorkerConfig) -> None:
    """A worker process: jobs from `conn`, one at a time, each answered on it."""
    logging.basicConfig(level=config.log_level, format="%(levelname)s worker %(process)d %(name)s: %(message)s")
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server stops us; Ctrl-C goes to it
    memory.configure_allocator()  # before the first big array
    state = WorkerState(config)
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        reply = answer(state, job)
        try:
            conn.send(reply)
        except (BrokenPipeError, OSError):
            return
