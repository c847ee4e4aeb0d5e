"""Service configuration: command-line flags, then ASSET_PREVIEW_* variables, then defaults.

Defaults work with nothing set: cache in ./.cache, one render worker per core, no API key.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

ENV_PREFIX = "ASSET_PREVIEW_"


@dataclass(frozen=True)
class Settings:
    cache: Path = Path(".cache")
    workers: int = 0                      # render worker processes; 0 = one per core
    executor: str = "local"               # "local" worker processes, or "ray" actors on a cluster
    ray_address: str = ""                 # cluster to join ("" = $RAY_ADDRESS, else a local one)
    ray_gpus: float = 0.0                 # GPU share per render actor (0 on CPU-only clusters)
    api_key: str = ""                     # when set, POST and DELETE need `Authorization: Bearer KEY`
    max_upload_bytes: int = 256 * 2**20   # request body (413 beyond)
    max_thumbnail_size: int = 2048        # width/height in pixels (422 beyond)
    max_queue: int = 64                   # renders waiting or running (503 beyond)
    render_seconds: float = 60.0          # deadline of one render (worker killed past it)
    bake_seconds: float = 600.0           # deadline of one bake
    ingest_seconds: float = 120.0         # deadline of reading an upload for its summary
    bake_wait_seconds: float = 10.0       # thumbnail of a baking asset waits this long, then 202
    retry_after_seconds: int = 5          # Retry-After on 202 and 503
    cache_max_age: int = 86400            # Cache-Control max-age of thumbnails
    memory_cache_bytes: int = 64 * 2**20  # hot thumbnails kept in the server process
    max_thumbnail_bytes: int = 4 * 2**30  # thumbnails on disk; least recently made go first
    default_env: str = "footprint_court"
    seed: bool = True                     # seed the sample assets into an empty store
    samples: Path | None = None           # folder to seed from; default ../shared/assets or service/samples
    state: Path | None = None             # service records/uploads/thumbnails; default <cache>/service.
                                          # Own per replica when replicas share one bake cache.

    @classmethod
    def from_env(cls, **overrides) -> "Settings":
        """Defaults, overridden by ASSET_PREVIEW_<FIELD> variables, overridden by arguments
        (arguments that are None are ignored, so argparse results can be passed as they are)."""
        values = {}
        for field in dataclasses.fields(cls):
            raw = os.environ.get(ENV_PREFIX + field.name.upper())
            if raw is not None:
                values[field.name] = _parse(field, raw)
        values.update({k: v for k, v in overrides.items() if v is not None})
        for key in ("cache", "samples", "state"):
            if values.get(key) not in (None, ""):
                values[key] = Path(values[key])
        return cls(**values)

    @property
    def worker_count(self) -> int:
        if self.workers > 0:
            return self.workers
        try:  # the CPUs this process may use (a container's cpuset), not the host's count
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:
            return max(1, os.cpu_count() or 1)

    @property
    def root(self) -> Path:
        """Where the service keeps its own state, beside the pipeline's bake cache."""
        return Path(self.state) if self.state else Path(self.cache) / "service"


def _parse(field: dataclasses.Field, raw: str):
    kind = field.type if isinstance(field.type, str) else field.type.__name__
    if kind == "bool":
        return raw.strip().lower() in ("1", "true", "yes", "on")
    if kind == "int":
        return int(float(raw))
    if kind == "float":
        return float(raw)
    if kind in ("Path", "Path | None"):
        return Path(raw)
    return raw
