"""The tree integrator's soft shadows against the path integrator at high spp:
`python -m bench.penumbra DIR [--stages rect,sphere] [--size 96] [--spp 256]` renders each of
bench.penumbra_stages' stages (written to DIR) under a uniform sky with method raytrace:
the tree with the lights as points and directions ("before": what the tree did before it
sampled a light's extent, i.e. Light.shape cleared), the tree sampling them ("after"), and
the path integrator sampling them at --spp passes (the reference); LDR-FLIP of each tree
frame against the reference (tonemap none, sRGB, over 50% grey as `bench usd`), the tree's
render time (median of 3, warm), and a contact sheet (before | after | path) at DIR/penumbra_sheet.png.
`--storm-images DIR` instead measures whether Storm shadows at all, from `bench usd`'s frames
(`storm_in_our_shadow`)."""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

SKY = 0.1


def _srgb_over_grey(frame) -> np.ndarray:
    from bench.usd import over_grey
    return over_grey(frame.rgba8)


def storm_in_our_shadow(ours_png: Path, storm_png: Path) -> tuple[int, float, float]:
    """Whether Storm darkens where our raster's shadow falls, from `bench usd --keep-images`
    frames: (pixels in our shadow, Storm's mean sRGB there over its mean in a ring 3-5 pixels
    around it, ours likewise). Our shadow: opaque pixels of both where ours is under 0.35 of
    Storm's. A ratio near 1 is no shadow at all, hard or soft."""
    from PIL import Image
    from scipy import ndimage

    o = np.asarray(Image.open(ours_png).convert("RGBA"), np.float64) / 255
    t = np.asarray(Image.open(storm_png).convert("RGBA"), np.float64) / 255
    lo, lt = o[..., :3].mean(-1), t[..., :3].mean(-1)
    both = (o[..., 3] > 0.99) & (t[..., 3] > 0.99)
    mask = ndimage.binary_opening(both & (lo < 0.35 * lt) & (lt > 0.1))
    ring = (ndimage.binary_dilation(mask, iterations=5) & ~ndimage.binary_dilation(mask, iterations=2)
            & both & (lo >= 0.35 * lt))
    if not mask.any() or not ring.any():
        return 0, float("nan"), float("nan")
    return int(mask.sum()), float(lt[mask].mean() / lt[ring].mean()), float(lo[mask].mean() / lo[ring].mean())


def main(argv: list[str] | None = None) -> int:
    from bench.metrics import median_ms
    from bench.penumbra_stages import LIGHTS, write_stages
    from bench.usd import ldr_flip
    from core.options import RenderOptions
    from pipeline.bake import bake_environment, build_baked
    from pipeline.environment import uniform
    from pipeline.ingest import load_scene
    from renderer import render

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dir", type=Path)
    p.add_argument("--stages", default=",".join(LIGHTS))
    p.add_argument("--size", type=int, default=96)
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--storm-images", type=Path, default=None,
                   help="only compare Storm's frames with ours in our shadow (`bench usd --keep-images` folder)")
    args = p.parse_args(argv)
    if args.storm_images is not None:
        for ours in sorted(args.storm_images.glob("*.ours.png")):
            n, storm, mine = storm_in_our_shadow(ours, Path(str(ours).replace(".ours.png", ".storm.png")))
            print(f"{ours.name.removesuffix('.ours.png')}: {n} px in our shadow; there over around it: "
                  f"Storm {storm:.3f}, ours {mine:.3f}")
        return 0
    write_stages(args.dir)
    env = bake_environment(uniform.name((SKY,) * 3), args.dir / "env", face_size=32)
    base = RenderOptions(width=args.size, height=args.size, tonemap="none", background="transparent",
                         shadow=0.0, method="raytrace", yaw=30.0, pitch=35.0)
    rows, sheet = [], []
    for name in args.stages.split(","):
        asset = build_baked(load_scene(args.dir / "usd" / "Penumbra" / f"{name}.usda"), key=f"penumbra-{name}")
        hard = dataclasses.replace(asset, lights=[dataclasses.replace(li, shape="") for li in asset.lights])
        frames, ms = {}, {}
        for label, a, opts in (("before", hard, base), ("after", asset, base),
                               ("path", asset, dataclasses.replace(base, integrator="path", samples=args.spp,
                                                                    noise=0.0))):
            # the trees: median of 3 after a warm-up (compile, scene cache); the path: once
            ms[label], frames[label] = median_ms(lambda: render(a, env, opts), 3 if label != "path" else 1,
                                                 warm=label != "path")
        ref = _srgb_over_grey(frames["path"])
        row = {"stage": name, "before": ldr_flip(_srgb_over_grey(frames["before"]), ref)[0],
               "after": ldr_flip(_srgb_over_grey(frames["after"]), ref)[0],
               "tree_before_ms": ms["before"], "tree_after_ms": ms["after"], "path_ms": ms["path"]}
        rows.append(row)
        print(f"{name}: FLIP tree before {row['before']:.4f} after {row['after']:.4f} against path "
              f"{args.spp} spp; tree {ms['before']:.0f} -> {ms['after']:.0f} ms, path {ms['path']:.0f} ms",
              flush=True)
        sheet.append(np.concatenate([_srgb_over_grey(frames[k]) for k in ("before", "after", "path")], axis=1))
    from PIL import Image
    img = np.concatenate(sheet, axis=0)
    Image.fromarray((np.clip(img, 0, 1) * 255).astype(np.uint8)).save(args.dir / "penumbra_sheet.png")
    print(f"wrote {args.dir / 'penumbra_sheet.png'} (rows: {args.stages}; before | after | path)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
