"""Box.glb with its material overridden, the raster beside our path tracer: the mean linear
RGB of each visible face (docs/textures.md, "The split-sum's horizon").

    PYTHONPATH=. python -m bench.material_probe --samples ../shared/assets/gltf-samples \
        --size 64 --paths 128 --env footprint_court

The faces are told apart by a mask frame: the box lit by one directional light over a dark
environment, white Lambert, where the three visible faces take three distinct N.L; a pixel
belongs to a face where its value is within 2% of that face's (edges and their mixed pixels
drop out)."""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from core.options import MaterialOverride, RenderOptions
from core.scene import Light

# (name, base colour, metallic, roughness)
MATERIALS = [("white metal, roughness 1", (1.0, 1.0, 1.0), 1.0, 1.0),
             ("white metal, roughness 0.5", (1.0, 1.0, 1.0), 1.0, 0.5),
             ("red dielectric, roughness 0.5", (0.8, 0.05, 0.05), 0.0, 0.5)]
FACES = {"top": np.array([0.0, 1.0, 0.0]), "left": np.array([0.0, 0.0, 1.0]),
         "right": np.array([1.0, 0.0, 0.0])}


def face_masks(asset, cache: Path, size: int) -> dict[str, np.ndarray]:
    from pipeline.bake import bake_environment
    from renderer import render
    dark = bake_environment("dark", cache, face_size=16)
    to_light = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    # a directional light shines along its -z: turn -z onto -to_light
    z = to_light
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2] = x, np.cross(z, x), z
    # its own key: the renderer keeps a baked asset's GPU state (materials included) by key
    lit = dataclasses.replace(asset, key=asset.key + "-mask", lights=[Light(type="directional", color=(1.0, 1.0, 1.0),
                                                   intensity=1.0, matrix=matrix)])
    o = RenderOptions(width=size, height=size, tonemap="none", background="transparent", shadow=0.0,
                      method="opaque", override=MaterialOverride(base_color=(1.0, 1.0, 1.0), metallic=0.0,
                                                                 roughness=1.0))
    img = render(lit, dark, o).linear[..., :3].mean(-1)
    expected = {k: float(n @ to_light) for k, n in FACES.items()}
    scale = img.max() / max(expected.values())  # the Lambert's albedo / pi and the specular's
    return {k: np.abs(img / scale - e) < 0.02 * e for k, e in expected.items()}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=Path, required=True, help="the glTF sample models folder")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--paths", type=int, default=128)
    ap.add_argument("--env", default="footprint_court")
    ap.add_argument("--face-size", type=int, default=256)
    args = ap.parse_args(argv)
    from pipeline.bake import bake_asset, bake_environment
    from renderer import render
    cache = Path(tempfile.mkdtemp(prefix="probe-"))
    asset = bake_asset(args.samples / "Box" / "glTF-Binary" / "Box.glb", cache)
    env = bake_environment(args.env, cache, face_size=args.face_size)
    masks = face_masks(asset, cache, args.size)
    print("| material, face | raster | path | raster / path |")
    print("|---|---|---|---|")
    for name, colour, metallic, roughness in MATERIALS:
        ov = MaterialOverride(base_color=colour, metallic=metallic, roughness=roughness)
        base = dict(width=args.size, height=args.size, tonemap="none", background="transparent",
                    shadow=0.0, override=ov)
        raster = render(asset, env, RenderOptions(method="opaque", **base)).linear[..., :3]
        path = render(asset, env, RenderOptions(method="raytrace", integrator="path",
                                                samples=args.paths, **base)).linear[..., :3]
        for face, mask in masks.items():
            r, p = raster[mask].mean(0), path[mask].mean(0)
            print(f"| {name}, {face} | {' '.join(f'{c:.3f}' for c in r)} | "
                  f"{' '.join(f'{c:.3f}' for c in p)} | {' '.join(f'{c:.3f}' for c in r / p)} |")


if __name__ == "__main__":
    main()
