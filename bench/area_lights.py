"""The raster's emissive area lights (core.area_lights): what they gain and cost (issue 30).

`python -m bench.area_lights --cycles OUT/fidelity/EmissiveStrengthTest_cycles.exr` renders
the raster frame (`method auto`, bench fidelity's view and environment) with the baked area
lights, with each cap in `--caps` (the brightest N polygons), and with none (the frame before
them), and prints each one's LDR FLIP against the Cycles frame and the median of `--repeat`
warm frame times, all in one run. `--tree` also renders the ray tracer's tree with its
emitter samples shadowed (as always) and unshadowed: the FLIP the raster's unshadowed emitter
light gives away, measured where both are otherwise alike.
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from bench.fidelity import MODELS, VIEW, flip_ldr, read_exr
    from core import area_lights
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer.methods import raytrace
    from renderer.raster.render import render

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--samples", default=str(MODELS), help="folder of Khronos sample models")
    p.add_argument("--model", default="EmissiveStrengthTest")
    p.add_argument("--cycles", required=True, help="bench fidelity's MODEL_cycles.exr for this model")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--caps", default="4,8,16", help="comma-separated caps on the polygons kept")
    p.add_argument("--cache", default="/tmp/area-lights-cache")
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--tree", action="store_true", help="also the tree, emitters shadowed and not")
    p.add_argument("--sheet", default="", help="PNG: none | baked | Cycles")
    args = p.parse_args(argv)

    folder = Path(args.samples) / args.model
    path = next(iter(sorted(folder.glob("glTF-Binary/*.glb")) + sorted(folder.glob("glTF/*.gltf"))))
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    env = bake_environment("footprint_court", cache, face_size=256)
    asset = bake_asset(path, cache)
    o = RenderOptions(width=args.size, height=args.size, background="transparent", shadow=0.0,
                      tonemap="aces", yaw=VIEW["yaw"], pitch=VIEW["pitch"], fov=VIEW["fov"], method="auto")
    ref = read_exr(args.cycles)
    baked = asset.area_lights if asset.area_lights is not None else area_lights.extract(asset.meshes, asset.textures)
    variants = [("none", area_lights.empty())]
    for cap in (int(c) for c in args.caps.split(",") if c):
        variants.append((f"cap {cap}", area_lights.extract(asset.meshes, asset.textures, cap)))
    variants.append((f"baked ({len(baked)} polygons, {baked.dropped} dropped)", baked))
    print(f"# {args.model} {args.size} px, LDR FLIP against {args.cycles}; frame times: median "
          f"of {args.repeat} warm frames (after one that compiles the programs)")
    images = {}
    for label, lights in variants:
        a = dataclasses.replace(asset, key=f"{asset.key}#area={label}", area_lights=lights)
        img = render(a, env, o).linear  # programs compiled, asset uploaded
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            img = render(a, env, o).linear
            times.append((time.perf_counter() - t0) * 1e3)
        images[label] = img
        print(f"raster, area lights {label:<34} {flip_ldr(img, ref):.3f}   median {np.median(times):.1f} ms")
    if args.tree:
        traced = o.replace(method="raytrace")
        shadowed = render(asset, env, traced).linear
        kept = raytrace.shadow_transmittance

        def unshadowed(ts, origins, dirs, *rest):
            return np.ones((len(origins), 3))
        raytrace.shadow_transmittance = unshadowed  # measurement only: every shadow ray lets all through
        try:
            open_ = render(dataclasses.replace(asset, key=f"{asset.key}#unshadowed"), env, traced).linear
        finally:
            raytrace.shadow_transmittance = kept
        print(f"raytrace (tree), emitters shadowed           {flip_ldr(shadowed, ref):.3f}")
        print(f"raytrace (tree), emitters unshadowed         {flip_ldr(open_, ref):.3f}")
    if args.sheet:
        from PIL import Image

        from bench.fidelity import display
        tiles = [np.round(display(x) * 255).clip(0, 255).astype(np.uint8)
                 for x in (images["none"], images[variants[-1][0]], ref)]
        Image.fromarray(np.concatenate(tiles, axis=1)).save(args.sheet)
        print(f"wrote {args.sheet} (no area lights | baked | Cycles)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
