"""`asset-preview bench NAME`: each benchmark is a module bench/<name>.py with
`configure(parser)` and `run(args) -> int`; registering one is one line in BENCHMARKS."""
from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from cli.main import add_commands

# bench/ ships in the source checkout, not in the wheel: run from a checkout (an editable
# install), its root goes on the path; from a wheel the command says where to get it.
CHECKOUT = Path(__file__).resolve().parents[1]

BENCHMARKS = {
    "ingest": ("bench.ingest", "load every sample asset: our load_scene vs trimesh.load"),
    "bake": ("bench.bake", "interior rays, cold bake vs cache hit, environment prefilter"),
    "thumbnail": ("bench.thumbnail", "PBR+IBL thumbnails cold and warm beside pyrender and f3d"),
    "encode": ("bench.encode", "thumbnail encoding: PNG/WebP/JPEG time and size beside Pillow's settings"),
    "service": ("bench.service", "HTTP service: cached thumbnails, warm renders, cold uploads, "
                "cached and cheap renders under expensive load"),
    "scale": ("bench.scale", "bake a few hundred assets: 1 and 2 local workers vs Ray; 100k projection"),
    "refraction": ("bench.refraction", "refraction methods: time and error vs Mitsuba per scene"),
    "accuracy": ("bench.accuracy", "speed-vs-accuracy chart: every scene x method vs Mitsuba, Pareto front, auto"),
    "raycost": ("bench.raycost", "ray tracer (tree, path) timed over assets, sizes, settings; the cost model fitted"),
    "stability": ("bench.stability", "stability suite: every hard case x method, finite, TIR, error, verdict"),
    "fidelity": ("bench.fidelity", "Khronos samples: ours and raytrace vs Blender Cycles (FLIP per model)"),
    "usd": ("bench.usd", "USD stages: ours vs Hydra Storm (usdview), FLIP, cold and warm first image"),
    "upload_disk": ("bench.upload_disk", "bytes on disk one upload costs, folder by folder (upload, bake, thumbnails)"),
    "worker_memory": ("bench.worker_memory", "a render worker's RSS after 1M-triangle and 8k-texture jobs, vs its bound"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    if importlib.util.find_spec("bench") is None and (CHECKOUT / "bench" / "__init__.py").is_file():
        sys.path.insert(0, str(CHECKOUT))
    if importlib.util.find_spec("bench") is None:
        parser.add_argument("benchmark", nargs="?", help="needs the source checkout")
        parser.set_defaults(_bench=_not_installed)
        return
    add_commands(parser, BENCHMARKS, "benchmark", "_bench")


def _not_installed(args: argparse.Namespace) -> int:
    print("error: the benchmarks are in the source checkout (bench/), not in the installed package: "
          "run `asset-preview bench` from a clone after `make install`", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    return int(args._bench(args) or 0)
