"""A floor's contact shadow, by region (issue 30, pipeline.occlusion's refinement):
`python -m bench.floor_region --cycles OUT/fidelity/TransmissionRoughnessTest_cycles.exr`
bakes the model with the occlusion refinement off (a vertex budget of 0: the bake as before)
and on, renders the raster (`auto`) and the tree (`raytrace`) at bench fidelity's view and
environment, and prints the mean linear RGB of a box of pixels (default: the floor in front of
TransmissionRoughnessTest's panes at 128 px) beside Cycles', and each frame's LDR FLIP."""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from bench.fidelity import MODELS, VIEW, display, flip_ldr, read_exr
    from core.options import RenderOptions
    from pipeline import occlusion
    from pipeline.bake import bake_asset, bake_environment
    from renderer.raster.render import render

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--samples", default=str(MODELS), help="folder of Khronos sample models")
    p.add_argument("--model", default="TransmissionRoughnessTest")
    p.add_argument("--cycles", required=True, help="bench fidelity's MODEL_cycles.exr for this model")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--box", default="74,86,45,85", help="rows top,bottom and columns left,right")
    p.add_argument("--cache", default="/tmp/floor-region-cache")
    p.add_argument("--sheet", default="", help="PNG: raster off | on, tree off | on, Cycles")
    args = p.parse_args(argv)

    folder = Path(args.samples) / args.model
    path = next(iter(sorted(folder.glob("glTF-Binary/*.glb")) + sorted(folder.glob("glTF/*.gltf"))))
    r0, r1, c0, c1 = (int(v) for v in args.box.split(","))
    ref = read_exr(args.cycles)

    def region(img: np.ndarray) -> str:
        return " ".join(f"{v:.3f}" for v in img[r0:r1, c0:c1, :3].reshape(-1, 3).mean(axis=0))

    print(f"# {args.model} {args.size} px, box rows {r0}-{r1} columns {c0}-{c1}: mean linear RGB; "
          f"LDR FLIP of the whole frame against Cycles")
    print(f"Cycles                {region(ref)}")
    tiles = []
    budget = occlusion.REFINE_MAX_VERTICES
    for method in ("auto", "raytrace"):
        for label, vertices in (("off", 0), ("on", budget)):
            occlusion.REFINE_MAX_VERTICES = vertices
            cache = Path(args.cache) / label  # the bake's key does not hold the budget
            cache.mkdir(parents=True, exist_ok=True)
            env = bake_environment("footprint_court", cache, face_size=256)
            # its own key: the GPU copy is kept by key, and the budget is not in it
            asset = dataclasses.replace(bake_asset(path, cache), key=f"floor-region-{label}")
            occlusion.REFINE_MAX_VERTICES = budget
            o = RenderOptions(width=args.size, height=args.size, background="transparent", shadow=0.0,
                              tonemap="aces", yaw=VIEW["yaw"], pitch=VIEW["pitch"], fov=VIEW["fov"],
                              method=method)
            img = render(asset, env, o).linear
            vertices_ = sum(len(m.positions) for m in asset.meshes)
            print(f"{method:<8} refine {label:<3}  {region(img)}   FLIP {flip_ldr(img, ref):.3f}   "
                  f"({vertices_} vertices)")
            tiles.append(img)
    if args.sheet:
        from PIL import Image
        out = []
        for x in [*tiles, ref]:
            t = np.round(display(x) * 255).clip(0, 255).astype(np.uint8)[..., :3].copy()
            t[r0, c0:c1] = t[r1 - 1, c0:c1] = t[r0:r1, c0] = t[r0:r1, c1 - 1] = (255, 0, 0)
            out.append(t)
        Image.fromarray(np.concatenate(out, axis=1)).resize((len(out) * 3 * args.size, 3 * args.size),
                                                            Image.Resampling.NEAREST).save(args.sheet)
        print(f"wrote {args.sheet} (raster off | on, tree off | on, Cycles)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
