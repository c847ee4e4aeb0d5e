"""`asset-preview bench refraction`: render time and error against Mitsuba per scene and method.

For each scene (bench.scenes) and size: the refraction methods registered with
renderer.raster.render (`single`, `wyman` when built), our ray tracer at 1, 2 and 8 bounces (1 is
the single-refraction result, 2 the exact two-interface one that Wyman approximates), and the
peer, Mitsuba 3 (scalar_rgb path tracer), measured in the same run: its reference at
`--spp` and an equal-effort run at `--peer-spp`. Times are warm medians of `--repeat` runs
(scene build included, bake excluded); errors are relative mean absolute errors of linear RGB
over the object's pixels against the high-spp Mitsuba image. Everything uses the same camera
and the same panorama (baked to 512 px faces for our methods).

The paper's anchor: raster 17 ms vs ray traced 7 min 32 s at 500 x 500 (one i7 core).
"""
from __future__ import annotations

import argparse
import csv
import tempfile
import time
from dataclasses import replace
from pathlib import Path

SCENES = ("glass_sphere_ior1.5", "glass_sphere_ior1.3", "mirror_sphere", "glass_bunny_ior1.5",
          "glass_torus_ior1.5", "glass_sphere_ior2.4")
RAYTRACE_BOUNCES = (1, 2, 8)
FACE = 512
TARGET_SCENE = "glass_sphere_ior1.5"
PAPER = {"raster_ms": 17.0, "raytrace_ms": (7 * 60 + 32) * 1000.0, "size": 500}


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", default=",".join(SCENES), help="comma-separated bench.scenes names")
    p.add_argument("--sizes", default="256,512")
    p.add_argument("--repeat", type=int, default=3, help="warm runs timed per case (median)")
    p.add_argument("--spp", type=int, default=256, help="Mitsuba reference samples per pixel")
    p.add_argument("--peer-spp", type=int, default=16, help="Mitsuba equal-effort run")
    p.add_argument("--out", default="bench-results", help="folder for refraction.csv")
    p.add_argument("--cache", default=None, help="bake cache (default: a temporary folder)")
    p.add_argument("--quick", action="store_true", help="one scene at 64 px, one repeat")


def run(args: argparse.Namespace) -> int:
    from bench import scenes
    from bench.metrics import median_ms, with_linear
    from bench.reference import relative_mae, render_reference
    from core.options import RenderOptions
    from pipeline.bake import bake_environment
    from renderer.methods.raytrace import render_raytrace
    from renderer.raster.render import available_methods, render

    try:
        import mitsuba  # noqa: F401  (the peer and the reference)
    except ImportError:
        print("error: bench refraction needs Mitsuba 3: pip install -e '.[reference]'")
        return 2
    if args.quick:
        args.scenes, args.sizes, args.repeat = SCENES[0], "64", 1
        args.spp, args.peer_spp = min(args.spp, 64), min(args.peer_spp, 4)
    cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="bench-refraction-"))
    try:
        raster = [m for m in ("single", "wyman") if m in available_methods()]
    except Exception as exc:  # a raster method module that fails to import: say so, go on
        print(f"raster refraction methods unavailable: {exc!r}")
        raster = []
    rows = []
    print(f"{'scene':28s} {'size':>5s} {'method':16s} {'time_ms':>10s} {'rel_mae':>8s}")
    cases = [(name, int(size)) for name in args.scenes.split(",") for size in args.sizes.split(",")]
    if not args.quick:
        cases.append((TARGET_SCENE, int(PAPER["size"])))  # the paper's and the 500 x 500 case
    for name, size in cases:
        spec = scenes.scene(name)
        asset = scenes.baked_asset(spec, cache)
        env = bake_environment(spec.env, cache, face_size=FACE)
        opts = RenderOptions(background="env", width=size, height=size, yaw=spec.yaw, pitch=spec.pitch,
                             fov=spec.fov, distance=spec.camera_distance(size, size))
        t0 = time.perf_counter()
        ref = render_reference(spec, size, args.spp)
        ref_ms = (time.perf_counter() - t0) * 1e3

        def row(method, ms, image):
            err = relative_mae(image, ref) if image is not None else float("nan")
            rows.append({"scene": name, "size": size, "method": method,
                         "time_ms": round(ms, 2), "rel_mae": round(err, 4)})
            print(f"{name:28s} {size:5d} {method:16s} {ms:10.1f} {err:8.4f}", flush=True)

        for method in raster:
            ms, frame = median_ms(lambda: with_linear(render(asset, env, replace(opts, method=method))),
                                   args.repeat)
            row(method, ms, frame.linear)
        for b in RAYTRACE_BOUNCES:
            ms, frame = median_ms(lambda: render_raytrace(asset, env, replace(opts, bounces=b)),
                                   args.repeat)
            row(f"raytrace-{b}", ms, frame.linear)
        t0 = time.perf_counter()
        peer = render_reference(spec, size, args.peer_spp)
        row(f"mitsuba-{args.peer_spp}spp", (time.perf_counter() - t0) * 1e3, peer)
        row(f"mitsuba-{args.spp}spp", ref_ms, None)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "refraction.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["scene", "size", "method", "time_ms", "rel_mae"])
        w.writeheader()
        w.writerows(rows)
    _summary(rows)
    print(f"wrote {out / 'refraction.csv'}")
    return 0


def _summary(rows: list[dict]) -> None:
    print(f"\npaper anchor ({PAPER['size']}x{PAPER['size']}): raster {PAPER['raster_ms']:.0f} ms, "
          f"ray traced {PAPER['raytrace_ms'] / 1000:.0f} s (one i7 core, no threads)")
    for r in rows:
        if r["method"] == "raytrace-8" and r["scene"] == TARGET_SCENE:
            peer = [p for p in rows if p["scene"] == r["scene"] and p["size"] == r["size"]
                    and p["method"].startswith("mitsuba") and p is not r]
            ratio = ", ".join(f"{p['method']} {p['time_ms'] / r['time_ms']:.1f}x our time"
                              for p in peer)
            paper = (f"; the paper's ray tracer took {PAPER['raytrace_ms'] / r['time_ms']:.0f}x "
                     f"ours, its raster {PAPER['raster_ms'] / r['time_ms']:.3f}x"
                     if r["size"] == PAPER["size"] else "")
            print(f"ours, glass sphere IOR 1.5 at {r['size']} px, 8 bounces: {r['time_ms']:.0f} ms, "
                  f"relative error {r['rel_mae']:.3f} (targets at 500 px: <= 1500 ms, <= 0.03); "
                  f"{ratio}{paper}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    configure(parser)
    raise SystemExit(run(parser.parse_args()))
