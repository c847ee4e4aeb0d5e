"""Texture filtering against a supersampled reference of our own (issue 30).

`python -m bench.texture_filtering [--px 384] [--factor 8] [--samples DIR] [MODEL ...]`: each
Khronos sample model (under `--samples`, by default ../shared/assets/gltf-samples beside the
checkout) rendered by the default raster frame at `--px` (the thumbnail's texture levels,
trilinear + anisotropic) and, as the reference, by `render_supersampled` at `--factor` x
`--factor` samples per pixel with full-resolution textures (so GL samples near mip 0 and the
pixel is a box average of many samples), both under the studio environment at the default
view. Prints LDR FLIP (flip-evaluator) of the tone-mapped frames per model; lower is closer.
Figures: bench/RESULTS.md, docs/textures.md.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bench.assets import CORPUS

DEFAULT = ("TextureSettingsTest", "NegativeScaleTest", "Box", "Duck")


def _path(samples: Path, name: str) -> Path:
    for sub, ext in (("glTF-Binary", ".glb"), ("glTF", ".gltf")):
        p = samples / name / sub / f"{name}{ext}"
        if p.exists():
            return p
    raise FileNotFoundError(f"{name}: no .glb or .gltf under {samples / name}")


def main(argv: list[str] | None = None) -> int:
    import flip_evaluator

    from core.options import RenderOptions
    from pipeline.bake import bake_environment, build_baked
    from pipeline.ingest import load_scene
    from renderer import render
    from renderer.methods.auto import environment_face_size
    from renderer.raster.render import render_supersampled

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="*", default=list(DEFAULT))
    p.add_argument("--px", type=int, default=384)
    p.add_argument("--factor", type=int, default=8)
    p.add_argument("--cache", default=".cache")
    p.add_argument("--samples", type=Path, default=CORPUS / "gltf-samples",
                   help="folder of Khronos sample model folders")
    args = p.parse_args(argv)
    scores = []
    for name in args.models:
        src = _path(args.samples, name)
        baked = build_baked(load_scene(src), "bench-" + name, {"thumbnail_size": args.px})
        full = build_baked(load_scene(src), "bench-full-" + name, {"thumbnail_size": 1 << 16})
        o = RenderOptions(width=args.px, height=args.px, background="env")
        env = bake_environment("studio", args.cache, face_size=environment_face_size(baked, o)[0])
        ours = render(baked, env, o).rgba8[..., :3] / np.float32(255)
        ref = render_supersampled(full, env, o, args.factor).rgba8[..., :3] / np.float32(255)
        _, mean, _ = flip_evaluator.evaluate(ref, ours, "LDR", applyMagma=False)
        scores.append(float(mean))
        print(f"{name}: FLIP {mean:.4f}", flush=True)
    print(f"mean FLIP {np.mean(scores):.4f} over {len(scores)} models")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
