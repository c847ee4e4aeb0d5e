"""`asset-preview bench raycost`: time the ray tracer (tree and path integrators) over assets,
sizes and settings, and fit the cost model `auto` and the service plan with
(renderer.methods.auto.estimate_raytrace_ms / estimate_request_ms).

Each row is one cold `render_raytrace` (Embree scene build, material tables, tracing, tone map;
numba warmed once per process first), with the inputs the model may use: the asset's triangles,
the frame's pixels, the pixels traced at full rate (the tracer's `near` mask: on and next to the
object, counted from the frame's coverage grown by a pixel), the rays a pixel side, bounces, the
Fresnel split, the integrator and its paths a pixel, and the emissive triangles (Material.is_light)
both integrators sample at every surface. The fit is least squares on relative error (each row
weighted by 1 / its time) of

    ms = fixed + a * triangles + b * frame_pixels + c_split * near * ss^2 * depth(bounces) * (1 + e)
    depth(b) = (1 - exp(-b / K)) * K      (rays die out: glass leaks, MIN_WEIGHT prunes)
    path:  ms = fixed + path_fixed + a * triangles + b * frame_pixels
                + c_path * near * samples * depth(b) * (1 + e)
    e = 0 without emitters, else m_integrator + m_weighed * min(emitters, LOCAL_EMITTERS)

with K chosen on a grid. The emitter factor e is fitted apart, from pairs: every frame of an
asset with emitters is rendered twice back to back, emitters sampled and not
(raytrace.EMITTER_SAMPLES 0, path_trace.EMITTER_NEE False), and t_on / t_off - 1 is fitted
as the off frame's ray share (by the model `auto` ships) x e: a ratio of two frames of one
moment, which a shared machine's load scales alike (absolute times on it swing 3-10x). It
prints the coefficients, the fit's median and worst relative error, e's fit and, scene by
scene, the shipped model's error on the frames with emitters with e and without (scaled by
the run's load: the median of measured / shipped over the frames without emitters), and
writes raycost.csv (each frame's wall and CPU time). `--cpu` fits the CPU time of every thread
instead of the wall: on a shared machine the wall grows with the other work (a frame's threads
wait for a core), its CPU time much less.
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
# Khronos samples with emissive materials (under --samples): cubes' faces of 5 strengths, one
# emissive label, two bottles with an emissive texture
EMITTER_ASSETS = ("EmissiveStrengthTest/glTF-Binary/EmissiveStrengthTest.glb",
                  "ClearCoatTest/glTF-Binary/ClearCoatTest.glb",
                  "SpecGlossVsMetalRough/glTF/SpecGlossVsMetalRough.gltf")
EMITTER_SIZES = (64, 128)
EMITTER_TREE = ((8, "both", None), (12, "roulette", None))
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
    p.add_argument("--samples", type=Path, default=None,
                   help="folder of Khronos sample model folders (default: bench.assets.CORPUS/gltf-samples)")
    p.add_argument("--cpu", action="store_true",
                   help="fit the frames' CPU time (all threads) instead of their wall time: what a "
                        "loaded machine inflates least")
    p.add_argument("--emitters-only", action="store_true",
                   help="only the assets with emitters (their pairs, for the emitter factor)")


def depth(bounces, k: float):
    b = np.maximum(np.asarray(bounces, np.float64), 1.0)
    return b if k >= 1e8 else (1.0 - np.exp(-b / k)) * k


def _features(rows: list[dict], k: float) -> np.ndarray:
    """Columns: 1, triangles, frame pixels, tree both, tree roulette/sample, path, path's own
    fixed part (its environment sampling tables). Frames that sample emitters are left out of
    this fit (their factor is fitted from pairs: fit_emitters)."""
    x = np.zeros((len(rows), 7))
    for i, r in enumerate(rows):
        x[i, 0], x[i, 1], x[i, 2] = 1.0, r["triangles"], r["width"] * r["height"]
        d = float(depth(r["bounces"], k))
        path = r["integrator"] == "path"
        rays = r["near"] * (r["samples"] if path else r["ss"] ** 2) * d
        if path:
            x[i, 5] = rays
            x[i, 6] = 1.0
        else:
            x[i, 3 if r["split"] == "both" else 4] = rays
    return x


def sampled(r: dict) -> bool:
    """The frame sampled emitters (an asset with some, their sampling on)."""
    return r.get("emitters", 0) > 0 and r.get("nee", 1) > 0


def fit(rows: list[dict]) -> dict:
    """Non-negative weighted least squares over K_GRID on the frames that sample no emitters;
    the best K's coefficients and errors."""
    from scipy.optimize import nnls

    rows = [r for r in rows if not sampled(r)]
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


def _model(r: dict, emitters: bool) -> tuple[float, float]:
    """(the shipped model's ms for row r, its ray term's share of it); `emitters` False:
    as if nothing emitted."""
    from renderer.methods import auto

    def model(near: float, e: int) -> float:
        return auto.rt_ms(int(r["triangles"]), int(r["width"]), int(r["height"]), near, int(r["bounces"]),
                          int(r["ss"]), r["split"], r["integrator"], int(r["samples"]), emitters=e)

    total = model(r["near"], int(r.get("emitters", 0)) if emitters and sampled(r) else 0)
    bare = model(0.0, 0)  # no traced pixel: the fixed parts
    return total, (total - bare) / total


def fit_emitters(rows: list[dict]) -> dict:
    """The emitter factor e = m_integrator + m_weighed * min(emitters, LOCAL_EMITTERS) from the
    on / off pairs (consecutive rows of one asset and setting): t_on / t_off - 1 = share x e,
    share the off frame's ray term over its whole (the shipped model's), by non-negative least
    squares. Returns the m's and the pairs' residuals."""
    from scipy.optimize import nnls

    from renderer.methods.trace_lights import LOCAL_EMITTERS

    x, y, names = [], [], []
    for on, off in zip(rows, rows[1:]):
        if not (sampled(on) and off.get("nee", 1) == 0 and on["asset"] == off["asset"]
                and all(on[k] == off[k] for k in ("width", "bounces", "split", "integrator", "samples", "ss"))):
            continue
        share = _model(off, False)[1]
        path = on["integrator"] == "path"
        x.append([share * (not path), share * path, share * min(on["emitters"], LOCAL_EMITTERS)])
        y.append(on["ms"] / off["ms"] - 1.0)
        names.append(on["asset"])
    if not x:
        return {}
    xa, ya = np.array(x), np.array(y)
    coef, _ = nnls(xa, ya)
    # the on frame's time from its off twin's: x 1 (no emitter term) or x (1 + share e), the fit's
    # and the shipped constants'
    from renderer.methods import auto
    ship = np.array([auto.RT_EMITTER_SHARE["tree"], auto.RT_EMITTER_SHARE["path"], auto.RT_EMITTER_WEIGHED_SHARE])
    return {"tree": coef[0], "path": coef[1], "weighed": coef[2], "pairs": len(y),
            "resid": xa @ coef - ya, "ratio": ya + 1.0, "names": names,
            "err_none": 1.0 / (ya + 1.0) - 1.0, "err_fit": (1 + xa @ coef) / (ya + 1.0) - 1.0,
            "err_ship": (1 + xa @ ship) / (ya + 1.0) - 1.0, "is_path": xa[:, 1] > 0}


def measure(cache: Path, quick: bool, samples: Path | None = None, emitters_only: bool = False) -> list[dict]:
    from bench import scenes
    from bench.assets import ASSETS as ROOT
    from bench.assets import CORPUS
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer.methods import path_trace, raytrace
    from renderer.methods.raytrace import clear_scene_cache, default_supersample, render_raytrace

    env = bake_environment("footprint_court", cache, face_size=512)
    assets: list[tuple[str, Any, Any]] = [] if emitters_only else [
        (n, scenes.baked_asset(scenes.scene(n), cache), scenes.scene(n)) for n in (SCENES[:2] if quick else SCENES)]
    if not quick and not emitters_only:
        assets += [(a, bake_asset(ROOT / a, cache), None) for a in ASSETS]
    folder = samples or CORPUS / "gltf-samples"
    lit = [] if quick else [(a.split("/")[0], bake_asset(folder / a, cache), None)
                            for a in EMITTER_ASSETS if (folder / a).is_file()]
    sizes = (64,) if quick else SIZES
    tree = TREE[:1] if quick else TREE
    rows = []

    def one(name, asset, spec, size, **kw):
        o = RenderOptions(background="env", width=size, height=size, **kw)
        if spec is not None:
            o = o.replace(yaw=spec.yaw, pitch=spec.pitch, fov=spec.fov,
                          distance=spec.camera_distance(size, size))
        clear_scene_cache()  # the model prices the scene build (the service's first frame)
        t0, c0 = time.perf_counter(), time.process_time()
        frame = render_raytrace(asset, env, o)
        ms = (time.perf_counter() - t0) * 1e3
        cpu_ms = (time.process_time() - c0) * 1e3  # every thread's
        assert np.isfinite(frame.linear).all(), name
        cov = _near_px(asset, o)  # outside the timing
        ss = kw.get("supersample") or default_supersample(size, size)
        row = {"asset": name, "width": size, "height": size, "triangles": asset.triangle_count,
               "emitters": asset.emissive_triangle_count,
               "nee": int(raytrace.EMITTER_SAMPLES > 0 if kw.get("integrator") != "path" else path_trace.EMITTER_NEE),
               "near": cov, "ss": ss if kw.get("integrator") != "path" else 1,
               "bounces": kw.get("bounces", 8), "split": kw.get("fresnel_split", "both"),
               "integrator": kw.get("integrator", "tree"), "samples": kw.get("samples", 0),
               "ms": ms, "cpu_ms": cpu_ms}
        rows.append(row)
        print(f"{name:30s} {size:4d} {row['integrator']:5s} b{row['bounces']:<3d} "
              f"{row['split']:9s} ss{row['ss']} spp{row['samples']:<3d} near {cov:6d} "
              f"e{row['emitters'] * row['nee']:<5d} {ms:9.1f} ms ({cpu_ms:.0f} CPU)", flush=True)

    def pair(name, asset, spec, size, **kw):
        """The frame with its emitters sampled, then without (the emitter factor's pair)."""
        one(name, asset, spec, size, **kw)
        keep = raytrace.EMITTER_SAMPLES, path_trace.EMITTER_NEE
        raytrace.EMITTER_SAMPLES, path_trace.EMITTER_NEE = 0, False
        try:
            one(name, asset, spec, size, **kw)
        finally:
            raytrace.EMITTER_SAMPLES, path_trace.EMITTER_NEE = keep

    # numba's import and cached code load once per process (both integrators'): not a frame's cost
    warm_name, warm_asset, warm_spec = (assets or lit)[0]
    one(warm_name, warm_asset, warm_spec, 32)
    one(warm_name, warm_asset, warm_spec, 32, method="raytrace", integrator="path", samples=1, noise=0.0)
    rows.clear()
    for (name, asset, spec), size in itertools.product(assets, sizes):
        for b, split, ss in tree:
            one(name, asset, spec, size, method="raytrace", bounces=b, fresnel_split=split,
                supersample=ss)
        if size <= 128:
            for spp in (PATH[:1] if quick else PATH):
                one(name, asset, spec, size, method="raytrace", integrator="path", samples=spp,
                    noise=0.0, bounces=PATH_BOUNCES)
    for (name, asset, spec), size in itertools.product(lit, EMITTER_SIZES):
        for b, split, ss in EMITTER_TREE:
            pair(name, asset, spec, size, method="raytrace", bounces=b, fresnel_split=split, supersample=ss)
        pair(name, asset, spec, size, method="raytrace", integrator="path", samples=PATH[0], noise=0.0,
             bounces=PATH_BOUNCES)
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
    f = fit(rows) if any(not sampled(r) for r in rows) else {}
    em = fit_emitters(rows)
    if em:
        print(f"\nemitter factor from {em['pairs']} on / off pairs: e = tree {em['tree']:.3f} | path "
              f"{em['path']:.3f} + {em['weighed'] * 1e3:.3f}e-3 x min(emitters, 256)")
        print(f"  t_on / t_off: median {np.median(em['ratio']):.2f} ({min(em['ratio']):.2f}-{max(em['ratio']):.2f})")
        print("  the on frame's time from its off twin's, |error| median / worst: no emitter term | "
              "this fit | auto's constants")
        groups: dict[str, list[int]] = {}
        for i, n in enumerate(em["names"]):
            groups.setdefault(f"{n} {'path' if em['is_path'][i] else 'tree'}", []).append(i)
        for g, idx in [*sorted(groups.items()), (f"all ({em['pairs']} pairs)", list(range(em["pairs"])))]:
            print(f"    {g[-30:]:30s} " + " | ".join(
                f"{np.median(np.abs(em[k][idx])):6.1%} {max(np.abs(em[k][idx])):6.1%}"
                for k in ("err_none", "err_fit", "err_ship")))
    plain_rows = [r for r in rows if not sampled(r)]
    load = float(np.median([r["ms"] / _model(r, False)[0] for r in plain_rows]))
    print(f"\nthis run's load: measured / shipped model on the {len(plain_rows)} frames without emitters "
          f"sampled: median {load:.2f}x")
    lit = [r for r in rows if sampled(r)]
    by_asset: dict[str, list[dict]] = {}
    for r in lit:
        by_asset.setdefault(r["asset"], []).append(r)
    if lit:
        print("  shipped model x load on the frames that sample emitters, |error| median / worst:")
        print("    scene                          emitters   without e        with e")
        for a, rs in [*by_asset.items(), (f"all ({len(lit)} frames)", lit)]:
            errs = [np.abs([load * _model(r, on)[0] / r["ms"] - 1.0 for r in rs]) for on in (False, True)]
            print(f"    {a[-30:]:30s} {int(rs[0]['emitters']):6d}   " + "   ".join(
                f"{np.median(e_):6.1%} {max(e_):6.1%}" for e_ in errs))
    if not f:
        return em
    c = f["coef"]
    print(f"\n{len(plain_rows)} frames without emitters sampled; depth K = {f['k']:g}")
    print(f"  fixed {c[0]:.1f} ms, {c[1] * 1e3:.3f} us/triangle, {c[2] * 1e3:.3f} us/frame pixel")
    print(f"  tree both     {c[3] * 1e3:.3f} us per near pixel x ss^2 x depth")
    print(f"  tree roulette {c[4] * 1e3:.3f} us per near pixel x ss^2 x depth")
    print(f"  path          {c[5] * 1e3:.3f} us per near pixel x sample x depth, "
          f"+ {c[6]:.1f} ms fixed")
    up = [rt_upper(r, f) / r["ms"] - 1.0 for r in plain_rows]
    print(f"  the service's upper estimate (whole frame traced): under the measured time on "
          f"{sum(u < 0 for u in up)}/{len(up)} frames, median {np.median(up):+.0%}, "
          f"least {min(up):+.0%}")
    print(f"  relative error: median {f['median']:.1%}, rms {f['rms']:.1%}, worst {f['worst']:.1%} "
          f"(most under-estimated {f['under']:.1%})")
    by: dict[str, list[float]] = {}
    for r, e in zip(plain_rows, f["rel"]):
        by.setdefault(r["asset"], []).append(e)
    for a, es in by.items():
        print(f"    {a[-30:]:30s} median {statistics.median(np.abs(es)):.1%}  worst {max(np.abs(es)):.1%}")
    return f


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "raycost.csv"
    if args.refit:
        with open(path) as fh:
            rows = [{k: (v if k in ("asset", "split", "integrator") else float(v))
                     for k, v in r.items()} for r in csv.DictReader(fh)]
        for r in rows:  # a file from before the emitter columns: none
            r.setdefault("emitters", 0.0)
            r.setdefault("nee", 1.0)
    else:
        cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="bench-raycost-"))
        rows = measure(cache, args.quick, args.samples, args.emitters_only)
        with open(path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    if args.cpu:
        rows = [dict(r, ms=r["cpu_ms"]) for r in rows]
    report(rows)
    print(f"wrote {path}")
    return 0 if all(math.isfinite(float(r["ms"])) for r in rows) else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    configure(parser)
    raise SystemExit(run(parser.parse_args()))
