"""`asset-preview bench NAME`: each benchmark is a module bench/<name>.py with
`configure(parser)` and `run(args) -> int`; registering one is one line in BENCHMARKS."""
from __future__ import annotations

import argparse

from cli.main import add_commands

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
    "stability": ("bench.stability", "stability suite: every hard case x method, finite, TIR, error, verdict"),
    "fidelity": ("bench.fidelity", "Khronos samples: ours and raytrace vs Blender Cycles (FLIP per model)"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    add_commands(parser, BENCHMARKS, "benchmark", "_bench")


def run(args: argparse.Namespace) -> int:
    return int(args._bench(args) or 0)
