"""What the server and its render workers (processes or Ray actors) send each other.

A job is one of the dataclasses in `Job`; a worker answers it with a `Reply`: `Done` holding
the job's typed result, `Refused` holding the AssetError its input raised (it pickles as its
own class), or `Failed` with a message (a bug or an exhausted worker: HTTP 500). Everything
here pickles, and holds only plain values, so both sides read it without knowing the other.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, TypeVar, Union

from core.errors import AssetError
from core.options import RenderOptions

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
    max_rss_bytes: int = 0               # replaced between jobs past this (0: never)


# -- jobs ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PingJob:
    """Create the GL context and warm the shaders, kernels and default environment."""
    name: ClassVar[str] = "ping"


@dataclass(frozen=True)
class InspectJob:
    """Read an upload: `root` is its folder (a zip's extraction), which references may use."""
    path: str
    root: str | None = None
    name: ClassVar[str] = "inspect"


@dataclass(frozen=True)
class PartsJob:
    """Which of an upload's USD files (`files`, relative to `root`) are not entry points:
    parts another one references, and layers that draw nothing (pipeline.library; read in a
    worker, as every byte of an upload is)."""
    root: str
    files: tuple[str, ...]
    name: ClassVar[str] = "parts"


@dataclass(frozen=True)
class BakeJob:
    path: str
    root: str | None = None
    name: ClassVar[str] = "bake"


@dataclass(frozen=True)
class BakeEnvironmentJob:
    """Prefilter a panorama (bundled name or file path) at the default face size."""
    source: str
    name: ClassVar[str] = "bake_env"


@dataclass(frozen=True)
class RenderJob:
    """One thumbnail: the bake `key`, the environment's source, the options, the image format;
    `root`: the upload's folder, where a bake the options ask for (a USD variant selection,
    other purposes) reads from; `env_default`: the request named no environment, so the
    asset's own lighting may replace `env_source` (pipeline.lighting)."""
    key: str
    env_source: str
    options: RenderOptions
    fmt: str
    root: str | None = None
    env_default: bool = False
    name: ClassVar[str] = "render"


Job = Union[PingJob, InspectJob, PartsJob, BakeJob, BakeEnvironmentJob, RenderJob]


# -- results ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WorkerInfo:
    pid: int
    gl_renderer: str
    renderer_version: str
    environments: tuple[str, ...] | None  # bundled panoramas; None: the prefilter is missing
    warm_seconds: float


@dataclass(frozen=True)
class AssetSummary:
    format: str
    triangles: int
    materials: int
    warnings: tuple[str, ...]
    transmissive: bool
    files: tuple[str, ...]  # every file the scene read, so the rest of an upload can go
    emitters: int = 0       # emissive triangles as rendered (Scene.emissive_triangle_count)


@dataclass(frozen=True)
class BakeResult:
    key: str
    triangles: int
    seconds: float


@dataclass(frozen=True)
class EnvironmentResult:
    key: str
    face_size: int


@dataclass(frozen=True)
class RenderPlan:
    """What the renderer ran and why (its Frame.plan); JSON only at the HTTP edge and on disk."""
    method: str
    details: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, plan: dict) -> "RenderPlan":
        details = dict(plan)
        return cls(str(details.pop("method", "")), details)

    @classmethod
    def from_json(cls, text: str) -> "RenderPlan":
        return cls.of(json.loads(text))

    def to_json(self) -> str:
        return json.dumps({"method": self.method, **self.details}, separators=(",", ":"), default=str)


@dataclass(frozen=True)
class RenderReply:
    image: bytes
    plan: RenderPlan
    seconds: float


# -- replies ------------------------------------------------------------------------------------

T = TypeVar("T")


@dataclass(frozen=True)
class Done(Generic[T]):
    value: T


@dataclass(frozen=True)
class Refused:
    error: AssetError


@dataclass(frozen=True)
class Failed:
    message: str


Reply = Union[Done, Refused, Failed]


def unpack(job: Job, reply: Reply):
    """A worker's reply as the job's result, or the exception it stands for."""
    if isinstance(reply, Done):
        return reply.value
    if isinstance(reply, Refused):
        raise reply.error
    raise WorkerFailure(f"{job.name} failed in the render worker: {reply.message}")
