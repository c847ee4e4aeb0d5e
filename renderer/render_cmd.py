"""`asset-preview render PATH --out FILE`: bake into the cache when needed, then render."""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys

log = logging.getLogger(__name__)

_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".webp", ".npy", ".exr")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", help="asset file (.gltf .glb .usd .usda .usdc .usdz .obj .ply .stl)")
    p.add_argument("--out", required=True, help="image file: .png .jpg .webp (tone-mapped) or .npy .exr (linear)")
    p.add_argument("--size", type=int, default=512, help="width and height in pixels (default 512)")
    p.add_argument("--width", type=int, help="overrides --size")
    p.add_argument("--height", type=int, help="overrides --size")
    p.add_argument("--env", default=None, help="bundled environment name or panorama file (default: footprint_court)")
    p.add_argument("--yaw", type=float, default=0.0, help="degrees; 0 looks from +Z, positive turns toward +X")
    p.add_argument("--pitch", type=float, default=0.0, help="degrees; positive looks from above")
    p.add_argument("--fov", type=float, default=40.0, help="vertical field of view, degrees")
    p.add_argument("--distance", type=float, default=None, help="scene units from the bounds centre (default: auto-frame)")
    p.add_argument("--method", default="auto", choices=["auto", "opaque", "single", "wyman", "raytrace"])
    p.add_argument("--tonemap", default="neutral", choices=["neutral", "aces", "none"])
    p.add_argument("--exposure", type=float, default=0.0, help="stops (EV)")
    p.add_argument("--background", default="env", help="env | transparent | #rrggbb")
    p.add_argument("--blur", type=float, default=0.0, help="background blur, 0..1 (roughness of the mip shown)")
    p.add_argument("--msaa", type=int, default=4, help="samples per pixel (0 or 1: off)")
    p.add_argument("--multiscatter", action="store_true", help="multiple-scattering energy compensation")
    p.add_argument("--no-lights", action="store_true", help="ignore the asset's KHR_lights_punctual lights")
    p.add_argument("--base-color", help="override: linear r,g,b for every mesh")
    p.add_argument("--metallic", type=float, help="override for every mesh")
    p.add_argument("--roughness", type=float, help="override for every mesh")
    p.add_argument("--ior", type=float, help="override for every mesh (with --transmission: glass)")
    p.add_argument("--transmission", type=float, help="override for every mesh, 0..1")
    p.add_argument("--tir", choices=["paper", "reflect"], default=None,
                   help="wyman: total internal reflection treatment (default: reflect)")
    p.add_argument("--debug", choices=["backface_normals", "tir", "exit_distance"], default=None,
                   help="wyman debug view")
    p.add_argument("--quality", type=int, default=None, help="JPEG / WebP quality")
    p.add_argument("--linear", help="also write the linear frame (.exr or .npy)")
    p.add_argument("--cache", default=None, help="cache directory (default $ASSET_PREVIEW_CACHE or ./.cache)")
    p.add_argument("--json", action="store_true", help="print the plan and timings as JSON")
    p.add_argument("--explain", action="store_true", help="print the method chosen for each "
                   "object and why (auto's decisions, renderer/auto.py)")
    p.add_argument("--time-budget", type=float, default=None, metavar="MS",
                   help="lets auto ray trace objects raster methods fail on, within MS milliseconds")


def _fail(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    for path in filter(None, (args.out, args.linear)):
        if os.path.splitext(path)[1].lower() not in _IMAGE_EXT:
            return _fail(f"{path}: unknown output extension (use {' '.join(_IMAGE_EXT)})")
    if args.linear and os.path.splitext(args.linear)[1].lower() not in (".npy", ".exr"):
        return _fail(f"{args.linear}: --linear takes .npy or .exr")
    try:
        override = _override(args)
    except ValueError as exc:
        return _fail(str(exc))

    import pipeline
    from pipeline.environment import default_face_size
    from pipeline.panorama import DEFAULT_ENVIRONMENT

    from .options import RenderOptions
    from .render import UnsupportedMethod, render, validate_options

    width = args.width or args.size
    height = args.height or args.size
    try:
        options = RenderOptions(
            width=width, height=height, yaw=args.yaw, pitch=args.pitch, fov=args.fov,
            distance=args.distance, method=args.method, tonemap=args.tonemap,
            exposure=args.exposure, background=args.background, background_blur=args.blur,
            override=override, msaa=args.msaa, lights=not args.no_lights,
            multiscatter=args.multiscatter, tir=args.tir, debug=args.debug,
            time_budget_ms=args.time_budget)
        validate_options(options)  # reject bad options before spending time on a bake
    except ValueError as exc:
        return _fail(str(exc))
    asset = pipeline.bake_asset(args.path, args.cache)
    face, env_why = default_face_size(max(width, height)), "default for the output size"
    if options.method == "auto":  # auto sizes the environment for the output and materials
        from .auto import environment_face_size
        face, env_why = environment_face_size(asset, width, height, options.background, override)
    env = pipeline.bake_environment(args.env or DEFAULT_ENVIRONMENT, args.cache,
                                    face_size=face)
    try:
        frame = render(asset, env, options)
    except (UnsupportedMethod, ValueError) as exc:
        return _fail(str(exc))
    frame.save(args.out, quality=args.quality)
    if args.linear:
        frame.save(args.linear)
    if args.explain:
        auto = frame.plan.get("auto", {})
        print(f"environment: {face} px faces: {env_why}")
        if auto:
            print(f"request: {auto['request']}")
        for o in auto.get("objects") or frame.plan.get("objects", []):
            alike = f" and {o['count'] - 1} more" if o.get("count", 1) > 1 else ""
            print(f"{o['mesh']}{alike}: {o['method']}: {o['why']}")
    if args.json:
        print(json.dumps({"out": args.out, "plan": frame.plan, "timings": frame.timings}, indent=1))
    log.info("wrote %s (%dx%d) in %.1f ms", args.out, width, height,
             frame.timings.get("total_ms", frame.timings.get("total", float("nan"))))  # raytrace: "total"
    return 0


def _override(args):
    from .options import MaterialOverride
    color = None
    if args.base_color:
        try:
            color = tuple(float(x) for x in args.base_color.split(","))
        except ValueError:
            color = ()
        if len(color) != 3:
            raise ValueError(f"--base-color {args.base_color!r}: expected r,g,b (linear, 0..1)")
    ov = MaterialOverride(base_color=color, metallic=args.metallic, roughness=args.roughness,
                          ior=args.ior, transmission=args.transmission)
    return None if ov.is_empty() else ov
