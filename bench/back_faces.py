"""Single-sided back faces beside Storm: `python -m bench.back_faces STORM_PNG_DIR` renders
bench/stages_translucent's Sphere_ds0_op025 / Sphere_ds1_op025 (a single- and a double-sided
sphere of opacity 0.25) through the bench wrapper's camera and dome (bench/storm.py) with the
raster, the tree tracer and the path tracer, and prints the mean linear premultiplied colour
over the sphere beside Storm's (its PNG from `bench usd --keep-images STORM_PNG_DIR`:
premultiplied sRGB, decoded), over the pixels both cover (alpha > 0.1 in each).
"""
from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.assets import REPO
from bench.storm import CAMERA, write_wrapper

STAGES = ("Sphere_ds0_op025", "Sphere_ds1_op025")
METHODS: dict[str, dict] = {"raster": {"method": "auto"}, "raytrace": {"method": "raytrace"},
           "path": {"method": "raytrace", "integrator": "path", "samples": 64, "noise": 0.0}}


def _storm(png: Path) -> np.ndarray:
    from PIL import Image

    from core.colour import srgb_decode
    rgba = np.asarray(Image.open(png).convert("RGBA"), np.float64) / 255.0
    return np.concatenate([srgb_decode(rgba[..., :3]), rgba[..., 3:]], axis=2)


def _ours(wrapper, cache: Path, size: int, root: Path, **kw) -> np.ndarray:
    """bench.usd.render_ours with the tracer's options too: the linear frame."""
    from core.options import from_request
    from pipeline.bake import bake_asset, bake_environment
    from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
    from pipeline.lighting import dome_texture
    from renderer.methods.auto import environment_face_size
    from renderer.raster.render import render

    options = from_request({"width": size, "height": size, "camera": CAMERA, "tonemap": "none",
                            "background": "transparent", "shadow": 0.0, **kw})
    asset = bake_asset(str(wrapper.path), str(cache), root=str(root))
    face, _ = environment_face_size(asset, options)
    env = bake_environment(dome_texture(asset, str(wrapper.path)) or DEFAULT_ENVIRONMENT, str(cache),
                           face_size=face)
    return render(asset, env, options).linear


def main(storm_dir: Path, size: int = 256) -> None:
    work = Path(tempfile.mkdtemp(prefix="bench-back-"))
    src = REPO / "bench" / "stages_translucent" / "usd"
    shutil.copytree(src, work / "usd")
    print("| | " + " | ".join(STAGES) + " |")
    print("|---|" + "---|" * len(STAGES))
    storm = {s: _storm(storm_dir / f"usd__{s}.usda.storm.png") for s in STAGES}
    rows: dict[str, list[str]] = {"Storm": []}
    masks = {}
    for s in STAGES:
        wrapper = write_wrapper(work / "usd" / f"{s}.usda")
        ours = {name: _ours(wrapper, work / "cache", size, work / "usd", **kw) for name, kw in METHODS.items()}
        mask = storm[s][..., 3] > 0.1
        for img in ours.values():
            mask &= img[..., 3] > 0.1
        masks[s] = mask
        rows["Storm"].append(" ".join(f"{v:.3f}" for v in storm[s][mask][:, :3].mean(axis=0)))
        for name, img in ours.items():
            rows.setdefault(name, []).append(" ".join(f"{v:.3f}" for v in img[mask][:, :3].mean(axis=0)))
    for name, cells in rows.items():
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("pixels: " + ", ".join(f"{s} {int(m.sum())}" for s, m in masks.items()))


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 256)
