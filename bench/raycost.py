"""`asset-preview bench raycost`: time the ray tracer (tree and path integrators) over assets,
sizes and settings, and fit the cost model `auto` and the service plan with
(renderer.methods.auto.estimate_raytrace_ms / estimate_request_ms).

Each row is one cold `render_raytrace` (Embree scene build, material tables, tracing, tone map;
numba warmed once per process first), with the inputs the model may use: the asset's triangles,
the frame's pixels, the pixels traced at full rate (the tracer's `near` mask: on and next to the
object, counted from the frame's coverage grown by a pixel), the rays a pixel side, bounces, the
Fresnel split, the integrator and its paths a pixel. The fit is least squares on relative error
(each row weighted by 1 / its time) of

    ms = fixed + a * triangles + b * frame_pixels + c_split * near * ss^2 * depth(bounces)
    depth(b) = (1 - exp(-b / K)) * K      (rays die out: glass leaks, MIN_WEIGHT prunes)
    path:  ms = fixed + path_fixed + a * triangles + b * frame_pixels
                + c_path * near * samples * depth(b)

with K chosen on a grid. It prints the coefficients, the fit's median and worst relative error,
and writes raycost.csv.
"""
from __future__ import annotations

import argparse
import csv
import itertools
import math
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

SCENES = ("glass_sphere_ior1.5", "glass_torus_ior1.5", "glass_bunny_ior1.5",
          "textured_glass_sphere_ior1.5", "attenuation_vase_ior1.5")
ASSETS = ("gltf/Duck.glb",)  # a real opaque textured asset (bench.assets.ASSETS)
SIZES = (64, 128, 256)
TREE = ((8, "both", None), (12, "roulette", None), (12, "roulette", 2), (4, "both", 2))
PATH = (8, 32)          # paths a pixel (noise 0: every pass runs), at the two smaller sizes
PATH_BOUNCES = 8
K_GRID = (2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 1e9)


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench-results", help="folder for raycost.csv")
    p.add_argument("--cache", default=None, help="bake cache (default: a temporary folder)")
    p.add_argument("--quick", action="store_true", help="two scenes at 64 px, one tree setting")
    p.add_argument("--refit", action="store_true", help="fit OUT/raycost.csv again without timing")


def depth(bounces, k: float):
    b = np.maximum(np.asarray(bounces, np.float64), 1.0)
    return b if k >= 1e8 else (1.0 - np.exp(-b / k)) * k


def _features(rows: list[dict], k: float) -> np.ndarray:
    """Columns: 1, triangles, frame pixels, tree both, tree roulette/sample, path, path's own
    fixed part (its environment sampling tables)."""
    x = np.zeros((len(rows), 7))
    for i, r in enumerate(rows):
        x[i, 0], x[i, 1], x[i, 2] = 1.0, r["triangles"], r["width"] * r["height"]
        d = float(depth(r["bounces"], k))
        if r["integrator"] == "path":
            x[i, 5] = r["near"] * r["samples"] * d
            x[i, 6] = 1.0
        else:
            x[i, 3 if r["split"] == "both" else 4] = r["near"] * r["ss"] ** 2 * d
    return x


def fit(rows: list[dict]) -> dict:
    """Non-negative weighted least squares over K_GRID; the best K's coefficients and errors."""
    from scipy.optimize import nnls

    t = np.array([r["ms"] for r in rows])
    best: dict = {}
    for k in K_GRID:
        x = _features(rows, k)
        w = 1.0 / t  # relative error
        coef, _ = nnls(x * w[:, None], t * w)
        rel = x @ coef / t - 1.0
        score = float(np.sqrt(np.mean(rel ** 2)))
        if not best or score < best["rms"]:
            best = {"k": k, "coef": coef, "rms": score, "rel": rel}
    rel = best["rel"]
    best.update(median=float(np.median(np.abs(rel))), worst=float(np.max(np.abs(rel))),
                under=float(np.min(rel)))
    return best


def measure(cache: Path, quick: bool) -> list[dict]:
    from bench import scenes
    from bench.assets import ASSETS as ROOT
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer.methods.raytrace import clear_scene_cache, default_supersample, render_raytrace

    env = bake_environment("footprint_court", cache, face_size=512)
    assets: list[tuple[str, Any, Any]] = [(n, scenes.baked_asset(scenes.scene(n), cache), scenes.scene(n))
              for n in (SCENES[:2] if quick else SCENES)]
    if not quick:
        assets += [(a, bake_asset(ROOT / a, cache), None) for a in ASSETS]
    sizes = (64,) if quick else SIZES
    tree = TREE[:1] if quick else TREE
    rows = []

    def one(name, asset, spec, size, **kw):
        o = RenderOptions(background="env", width=size, height=size, **kw)
        if spec is not None:
            o = o.replace(yaw=spec.yaw, pitch=spec.pitch, fov=spec.fov,
                          distance=spec.camera_distance(size, size))
        clear_scene_cache()  # the model prices the scene build (the service's first frame)
        t0 = time.perf_counter()
        frame = render_raytrace(asset, env, o)
        ms = (time.perf_counter() - t0) * 1e3
        assert np.isfinite(frame.linear).all(), name
        cov = _near_px(asset, o)  # outside the timing
        ss = kw.get("supersample") or default_supersample(size, size)
        row = {"asset": name, "width": size, "height": size, "triangles": asset.triangle_count,
               "near": cov, "ss": ss if kw.get("integrator") != "path" else 1,
               "bounces": kw.get("bounces", 8), "split": kw.get("fresnel_split", "both"),
               "integrator": kw.get("integrator", "tree"), "samples": kw.get("samples", 0),
               "ms": ms}
        rows.append(row)
        print(f"{name:30s} {size:4d} {row['integrator']:5s} b{row['bounces']:<3d} "
              f"{row['split']:9s} ss{row['ss']} spp{row['samples']:<3d} near {cov:6d} {ms:9.1f} ms",
              flush=True)

    # numba's import and cached code load once per process: not a frame's cost
    one(*assets[0], 32)
    rows.clear()
    for (name, asset, spec), size in itertools.product(assets, sizes):
        for b, split, ss in tree:
            one(name, asset, spec, size, method="raytrace", bounces=b, fresnel_split=split,
                supersample=ss)
        if size <= 128:
            for spp in (PATH[:1] if quick else PATH):
                one(name, asset, spec, size, method="raytrace", integrator="path", samples=spp,
                    noise=0.0, bounces=PATH_BOUNCES)
    return rows


def _near_px(asset, options) -> int:
    """Pixels the tracer traces at full rate: the centre rays' hits grown by one pixel, as
    renderer.methods.raytrace.trace's `near` mask."""
    from renderer.methods.raytrace import build_scene, grown_by_one, subpixel_rays
    from renderer.methods.trace_scene import intersect_front
    from renderer.view.framing import asset_camera

    cam = asset_camera(asset, options)[0]
    ts = build_scene(asset, options)
    d, _ = subpixel_rays(cam, np.arange(cam.width * cam.height), 1)
    hit = intersect_front(ts, np.broadcast_to(cam.position, d.shape), d)[0] >= 0
    return int(grown_by_one(hit.reshape(cam.height, cam.width)).sum())


def rt_upper(r: dict, f: dict) -> float:
    """The fitted model with the whole frame traced (the service's estimate before the asset
    is loaded)."""
    full = dict(r, near=r["width"] * r["height"])
    return float(_features([full], f["k"])[0] @ f["coef"])


def report(rows: list[dict]) -> dict:
    f = fit(rows)
    c = f["coef"]
    print(f"\n{len(rows)} frames; depth K = {f['k']:g}")
    print(f"  fixed {c[0]:.1f} ms, {c[1] * 1e3:.3f} us/triangle, {c[2] * 1e3:.3f} us/frame pixel")
    print(f"  tree both     {c[3] * 1e3:.3f} us per near pixel x ss^2 x depth")
    print(f"  tree roulette {c[4] * 1e3:.3f} us per near pixel x ss^2 x depth")
    print(f"  path          {c[5] * 1e3:.3f} us per near pixel x sample x depth, "
          f"+ {c[6]:.1f} ms fixed")
    up = [rt_upper(r, f) / r["ms"] - 1.0 for r in rows]
    print(f"  the service's upper estimate (whole frame traced): under the measured time on "
          f"{sum(u < 0 for u in up)}/{len(up)} frames, median {np.median(up):+.0%}, "
          f"least {min(up):+.0%}")
    print(f"  relative error: median {f['median']:.1%}, rms {f['rms']:.1%}, worst {f['worst']:.1%} "
          f"(most under-estimated {f['under']:.1%})")
    by: dict[str, list[float]] = {}
    for r, e in zip(rows, f["rel"]):
        by.setdefault(r["asset"], []).append(e)
    for a, es in by.items():
        print(f"    {a:30s} median {statistics.median(np.abs(es)):.1%}  worst {max(np.abs(es)):.1%}")
    return f


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "raycost.csv"
    if args.refit:
        with open(path) as fh:
            rows = [{k: (v if k in ("asset", "split", "integrator") else float(v))
                     for k, v in r.items()} for r in csv.DictReader(fh)]
    else:
        cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="bench-raycost-"))
        rows = measure(cache, args.quick)
        with open(path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    report(rows)
    print(f"wrote {path}")
    return 0 if all(math.isfinite(float(r["ms"])) for r in rows) else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    configure(parser)
    raise SystemExit(run(parser.parse_args()))
