"""`asset-preview bench worker_memory`: a render worker's resident memory after heavy jobs.

One real worker process (service.workers.pool.WorkerPool, as the server runs it) warms up, then
bakes and renders a chess-set-class asset (a generated ~1M-triangle mesh) and a big-texture-class
one (bench.big_textures: three 8192^2 PNGs), default thumbnails and a small ray trace of the
mesh; the worker's RSS (/proc) is read after every job, as the pool reads it for
`worker_max_rss_bytes`. The bound the docs state is `bound_bytes`: the warm worker plus both of
its budgets (baked assets in memory, GPU copies) plus HEADROOM_BYTES.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import struct
import tempfile
from pathlib import Path

import numpy as np

HEADROOM_BYTES = 200 * 2**20  # allocator slack of the interpreter and the libraries (Embree's, after a bake's AO pass)


def chess_class(path: Path, triangles: int = 1_000_000) -> Path:
    """A wavy grid of about `triangles` triangles (a chess set's count), one mesh, as .glb."""
    if path.exists():
        return path
    n = int(np.sqrt(triangles / 2)) + 1
    u, v = np.meshgrid(np.linspace(-1, 1, n, dtype=np.float32), np.linspace(-1, 1, n, dtype=np.float32))
    pos = np.stack([u, 0.05 * np.sin(9 * u) * np.cos(7 * v), v], -1).reshape(-1, 3).astype(np.float32)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel().astype(np.uint32)
    idx = np.stack([i, i + n, i + 1, i + 1, i + n, i + n + 1], -1).ravel().astype(np.uint32)
    blobs = [pos.tobytes(), idx.tobytes()]
    views, data = [], b""
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": len(data), "byteLength": len(b)})
        data += b + b"\0" * (-len(b) % 4)
    doc = {"asset": {"version": "2.0", "generator": "asset-preview bench.worker_memory"},
           "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                          "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
                         {"bufferView": 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"}],
           "bufferViews": views, "buffers": [{"byteLength": len(data)}]}
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(data), b"BIN\0") + data
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    return path


async def measure(assets: Path, cache: Path, cache_bytes: int, gpu_bytes: int,
                  texture_size: int = 8192) -> dict:
    """RSS of one real worker after each job; `bound_bytes` = warm + both budgets + headroom."""
    from bench import big_textures
    from core.options import RenderOptions
    from service.workers.pool import WorkerPool
    from service.workers.protocol import BakeJob, RenderJob, WorkerConfig

    work = Path(tempfile.gettempdir()) / "asset-preview-bench"
    files = {"chess": chess_class(work / "chess_class_1M.glb"),
             "big_textures": big_textures.build(assets, texture_size)}
    pool = WorkerPool(1, WorkerConfig(cache_dir=str(cache), cache_bytes=cache_bytes, gpu_bytes=gpu_bytes))
    steps: list[dict] = []
    await pool.start()
    try:
        async def run(job, what):
            result = await pool.run(job, deadline=600)  # the job's result; a refusal raises
            steps.append({"step": what, "rss_bytes": pool.workers[0].rss_bytes})
            return result
        await pool.warm_up()
        warm = pool.workers[0].rss_bytes
        steps.append({"step": "warm", "rss_bytes": warm})
        for name, path in files.items():
            key = (await run(BakeJob(str(path)), f"bake {name}")).key
            for what, options in (("512 px", RenderOptions()), ("1024 px", RenderOptions(width=1024, height=1024))):
                await run(RenderJob(key, "footprint_court", options, "png"), f"render {name} {what}")
            if name == "chess":
                await run(RenderJob(key, "footprint_court", RenderOptions(width=128, height=128, method="raytrace"),
                                    "png"), f"render {name} raytrace 128 px")
    finally:
        await pool.stop()
    assert warm is not None
    peak = max(s["rss_bytes"] or 0 for s in steps)
    return {"warm_bytes": warm, "cache_bytes": cache_bytes, "gpu_bytes": gpu_bytes,
            "bound_bytes": warm + cache_bytes + gpu_bytes + HEADROOM_BYTES, "max_after_job_bytes": peak,
            "steps": steps, "files": {k: {"path": str(p), "bytes": p.stat().st_size} for k, p in files.items()}}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cache-bytes", type=int, default=512 * 2**20)
    parser.add_argument("--gpu-bytes", type=int, default=512 * 2**20)


def run(args: argparse.Namespace) -> int:
    assets = Path(getattr(args, "assets", None) or Path(__file__).resolve().parents[1] / "tests" / "assets")
    with tempfile.TemporaryDirectory() as tmp:
        out = asyncio.run(measure(assets, Path(tmp) / "cache", args.cache_bytes, args.gpu_bytes))
    for s in out["steps"]:
        print(f"{s['step']:<40} {s['rss_bytes'] / 2**20:8.0f} MiB")
    print(f"bound (warm + {args.cache_bytes / 2**20:.0f} + {args.gpu_bytes / 2**20:.0f} + "
          f"{HEADROOM_BYTES / 2**20:.0f} MiB): {out['bound_bytes'] / 2**20:.0f} MiB; "
          f"max after a job {out['max_after_job_bytes'] / 2**20:.0f} MiB")
    print(json.dumps(out))
    return 0 if out["max_after_job_bytes"] <= out["bound_bytes"] else 1
