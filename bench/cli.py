"""`asset-preview bench NAME`: each benchmark is a module bench/<name>.py with
`configure(parser)` and `run(args) -> int`; registering one is one line in BENCHMARKS."""
from __future__ import annotations

import argparse
import importlib

BENCHMARKS = {
    "ingest": ("bench.ingest", "load every sample asset: our load_scene vs trimesh.load"),
    "bake": ("bench.bake", "interior rays, cold bake vs cache hit, environment prefilter"),
    "thumbnail": ("bench.thumbnail", "PBR+IBL thumbnails cold and warm beside pyrender and f3d"),
    "service": ("bench.service", "HTTP service: cached thumbnails, warm renders, cold uploads"),
    "scale": ("bench.scale", "bake a few hundred assets: 1 and 2 local workers vs Ray; 100k projection"),
    "refraction": ("bench.refraction", "refraction methods: time and error vs Mitsuba per scene"),
    "accuracy": ("bench.accuracy", "speed-vs-accuracy chart: every scene x method vs Mitsuba, Pareto front, auto"),
    "stability": ("bench.stability", "stability suite: every hard case x method, finite, TIR, error, verdict"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for name, (module, help_text) in BENCHMARKS.items():
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue  # not built in this version
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.configure(p)
        p.set_defaults(_bench=mod.run)


def run(args: argparse.Namespace) -> int:
    return int(args._bench(args) or 0)
