"""`asset-preview render PATH --out FILE`: bake into the cache when needed, then render."""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys

from cli import sandbox

log = logging.getLogger(__name__)

_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".webp", ".gif", ".npy", ".exr")


def configure(p: argparse.ArgumentParser) -> None:
    from core.options import add_arguments
    p.add_argument("path", help="asset file (.gltf .glb .usd .usda .usdc .usdz .obj .ply .stl)")
    from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
    p.add_argument("--out", required=True, help="image file: .png .jpg .webp (tone-mapped) or .npy "
                   ".exr (linear); with --turntable an animated .webp or .gif")
    p.add_argument("--env", default=None, help="bundled environment name or panorama file "
                   f"(default: {DEFAULT_ENVIRONMENT}, generated in code)")
    p.add_argument("--quality", type=int, default=None, help="JPEG / WebP quality")
    p.add_argument("--linear", help="also write the linear frame (.exr or .npy)")
    p.add_argument("--cache", default=None, help="cache directory (default $ASSET_PREVIEW_CACHE or ./.cache)")
    sandbox.add_argument(p)
    p.add_argument("--json", action="store_true", help="print the plan and timings as JSON")
    p.add_argument("--explain", action="store_true", help="print the method chosen for each "
                   "object and why (auto's decisions, renderer/methods/auto.py)")
    add_arguments(p)


def _fail(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    for path in filter(None, (args.out, args.linear)):
        if os.path.splitext(path)[1].lower() not in _IMAGE_EXT:
            return _fail(f"{path}: unknown output extension (use {' '.join(_IMAGE_EXT)})")
    if args.linear and os.path.splitext(args.linear)[1].lower() not in (".npy", ".exr"):
        return _fail(f"{args.linear}: --linear takes .npy or .exr")
    out_ext = os.path.splitext(args.out)[1].lower()
    from core.options import describe_error, from_arguments
    from pipeline.bake import asset_options, bake_asset, bake_environment
    from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
    from pipeline.lighting import environment_source
    from renderer.methods.auto import environment_face_size
    from renderer.raster.render import UnsupportedMethod, render, validate_options

    try:
        options = from_arguments(args)
        validate_options(options)  # reject bad options before spending time on a bake
    except ValueError as exc:  # pydantic's ValidationError is one (core.schema)
        return _fail(describe_error(exc))
    if options.turntable and not options.animate and out_ext not in (".webp", ".gif"):
        return _fail(f"{args.out}: --turntable writes an animated .webp or .gif")
    if options.animate and out_ext not in (".webp", ".gif", ".png"):
        return _fail(f"{args.out}: --animate writes an animated .webp, .gif or .png (APNG)")
    if out_ext == ".gif" and not (options.turntable or options.animate):
        return _fail(f"{args.out}: .gif is for --turntable; use .png .jpg or .webp")
    from core.animation import requested
    asset = bake_asset(args.path, args.cache, root=sandbox.root(args),
                       moment=None if options.animate else requested(options), **asset_options(options))
    face, env_why = environment_face_size(asset, options)
    env_source = environment_source(asset, args.path, args.env, DEFAULT_ENVIRONMENT, options.lights)
    env = bake_environment(env_source, args.cache, face_size=face)
    # renderer.sequence (and the PIL drawing it labels views with) only for several frames
    try:
        if options.animate:  # one pose per frame, one camera over the whole motion
            from pipeline.animate import poses_for
            from renderer.sequence import render_animation
            posed_assets, motion = poses_for(args.path, asset, options, sandbox.root(args))
            frames = render_animation(posed_assets, env, options, motion or {})
            frame = frames[0]
        elif options.turntable:  # N frames from this one bake and one upload
            from renderer.sequence import render_turntable
            frames = render_turntable(asset, env, options, keep_linear=bool(args.linear))
            frame = frames[0]
        elif options.views:
            from renderer.sequence import render_views
            frame = render_views(asset, env, options)
        else:
            frame = render(asset, env, options)
    except (UnsupportedMethod, ValueError) as exc:
        return _fail(str(exc))
    if options.animate or options.turntable:
        from renderer.sequence import encode_animation
    if options.animate:
        with open(args.out, "wb") as f:
            f.write(encode_animation(frames, out_ext[1:], args.quality, 1000.0 / options.animate))
    elif options.turntable:
        with open(args.out, "wb") as f:
            f.write(encode_animation(frames, out_ext[1:], args.quality))
    else:
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
        print(json.dumps({"out": args.out, "plan": frame.plan, "timings": frame.timings.as_dict()}, indent=1))
    log.info("wrote %s (%dx%d) in %.1f ms", args.out, options.width, options.height,
             frame.timings.total_ms)
    return 0

