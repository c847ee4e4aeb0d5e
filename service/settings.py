"""Service configuration: command-line flags, then ASSET_PREVIEW_* variables, then defaults.

One declaration per knob (core.config.FromEnv): `asset-preview serve --help`, the environment
and README's table all come from the fields below. Defaults work with nothing set: cache in
./.cache, one render worker per core, no API key (and then loopback only).
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from core.config import FromEnv
from core.schema import knob


@dataclasses.dataclass(frozen=True, init=False)
class Settings(FromEnv):
    host: str = knob("127.0.0.1", description="address to listen on")
    port: int = knob(8000, ge=0, le=65535, description="port to listen on")
    cache: Path = knob(Path(".cache"), description="bake cache folder (shared by replicas)")
    render_workers: int = knob(0, ge=0, description="render worker processes; 0 = one per core")
    executor: str = knob("local", pattern="^(local|ray)$", description="local worker processes, or ray actors")
    ray_address: str = knob("", description="Ray cluster to join (empty: $RAY_ADDRESS, else a local one)")
    ray_gpus: float = knob(0.0, ge=0, description="GPU share per render actor")
    # -- access ----------------------------------------------------------------------------
    api_key: str = knob("", description="when set, every endpoint but /healthz /readyz /metrics needs "
                                         "`Authorization: Bearer KEY`; several keys separated by commas")
    public_read: bool = knob(False, description="with a key: GET and HEAD (thumbnails, listings, the page) "
                                                 "need none; writes still do")
    insecure_no_auth: bool = knob(False, description="allow binding a non-loopback address without a key")
    allowed_hosts: str = knob("", description="names this service answers to in Host (every request "
                               "but probes) and Origin (writes), comma-separated; loopback names and "
                               "--host always; `*` any); each with the server's own port unless "
                               "given as NAME:PORT")
    allowed_origins: str = knob("", description="origins besides this service's own (scheme://name:port, "
                                 "comma-separated) whose pages may write (POST, DELETE)")
    public_render_ms: float = knob(0.0, ge=0, description="with public_read: the estimated cost up to "
                                    "which a read without a key may render (401 beyond; cached "
                                    "thumbnails are always served); 0 = the default thumbnail's")
    renders_per_minute: float = knob(0.0, ge=0, description="renders (cache misses) one client (key or "
                                      "address) may start per minute, in bursts of as many; 429 with "
                                      "Retry-After beyond; 0 = no limit")
    # -- request bounds --------------------------------------------------------------------
    max_upload_bytes: int = knob(256 * 2**20, ge=1, description="request body (413 beyond)")
    max_thumbnail_size: int = knob(2048, ge=1, description="width/height in pixels (422 beyond)")
    max_render_cost_ms: float = knob(0.0, ge=0, description="estimated cost ceiling of one render "
                                      "(422 beyond); 0 = the render deadline")
    cheap_render_ms: float = knob(2000.0, gt=0, description="renders estimated under this are cheap: "
                                   "one worker is kept for them")
    client_share: float = knob(0.5, gt=0, le=1, description="share of the workers (expensive jobs) and "
                                "of the queue one client (key or address) may hold")
    max_queue: int = knob(64, ge=1, description="renders waiting or running (503 beyond)")
    render_seconds: float = knob(60.0, gt=0, description="deadline of one render (worker killed past it)")
    bake_seconds: float = knob(600.0, gt=0, description="deadline of one bake")
    bake_wait_seconds: float = knob(10.0, ge=0, description="a thumbnail of a baking asset waits this long, then 202")
    retry_after_seconds: int = knob(5, ge=1, description="Retry-After on 202 and 503")
    # -- storage ---------------------------------------------------------------------------
    cache_max_age: int = knob(86400, ge=0, description="Cache-Control max-age of thumbnails")
    memory_cache_bytes: int = knob(64 * 2**20, ge=0, description="hot thumbnails kept in the server process")
    max_thumbnail_bytes: int = knob(4 * 2**30, ge=1, description="thumbnails on disk; least recently used go first")
    cache_max_bytes: str = knob("16G", description="bake cache on disk (binary units: 500M, 16G); least "
                                 "recently used entries go first (the variable asset-bake reads too)")
    quota_bytes: int = knob(0, ge=0, description="stored bytes per API key (413 beyond); 0 = no quota")
    quota_assets: int = knob(0, ge=0, description="assets per API key (413 beyond); 0 = no quota")
    # -- worker memory ---------------------------------------------------------------------
    worker_cache_bytes: int = knob(512 * 2**20, ge=1, description="baked assets and environments a "
                                    "render worker keeps in memory")
    gpu_bytes: int = knob(512 * 2**20, ge=1, description="meshes and textures a render worker keeps uploaded")
    worker_max_rss_bytes: int = knob(0, ge=0, description="a render worker whose resident memory is over "
                                      "this after a job is replaced before its next one; 0 = never")
    # -- content ---------------------------------------------------------------------------
    default_env: str = knob("studio", description="environment of renders that name none (studio: "
                             "generated in code, pipeline/environment/studio.py)")
    seed: bool = knob(True, description="seed the sample assets into an empty store")
    samples: Path | None = knob(None, description="folder to seed from; default: the samples shipped in service/samples")
    state: Path | None = knob(None, description="records, uploads, thumbnails; default <cache>/service "
                               "(own per replica when replicas share one bake cache)")

    @property
    def worker_count(self) -> int:
        if self.render_workers > 0:
            return self.render_workers
        try:  # the CPUs this process may use (a container's cpuset), not the host's count
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:
            return max(1, os.cpu_count() or 1)

    @property
    def root(self) -> Path:
        """Where the service keeps its own state, beside the pipeline's bake cache."""
        return Path(self.state) if self.state else Path(self.cache) / "service"

    @property
    def bake_cache_bytes(self) -> int | None:
        from pipeline.cache import parse_size
        return parse_size(self.cache_max_bytes)

    @property
    def api_keys(self) -> list[str]:
        return [k.strip() for k in self.api_key.split(",") if k.strip()]

    @property
    def render_cost_ceiling_ms(self) -> float:
        return self.max_render_cost_ms or self.render_seconds * 1000
