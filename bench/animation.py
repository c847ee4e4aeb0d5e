"""Animated previews against the same frames as separate renders (issue 27).

    python -m bench.animation ASSET [--fps 12] [--size 256] [--animation NAME]

A: one `--animate` preview: the rest bake once, a Rig (pipeline.gltf.rig: the document read
and the scene baked once, "setup"), then per frame a pose (only what moves recomputed) and
one draw on one GPU upload whose moved buffers are rewritten, every frame by one camera. A
USD stage: a UsdRig (pipeline.usd.rig: the stage composed and read once, per frame only its
time-varying prims). With --whole, A reads each frame whole instead (the path before the rigs): a
pose ingested and built in memory, and uploaded, per frame.
B: the same times as separate stills: per frame a `--time` bake into a fresh cache (ingest,
build, store) and a render, as a client asking for each moment would cause.
Both in this process, after a warm-up render, so neither pays for the GL context or imports.
C: f3d (the `f3d` Python module, when installed) playing the same animation at the same
times and size through its EGL engine: setup is the engine, its window and loading the
file; then per frame `scene.animation.load_time(t)` and `window.render_to_image()` (read
back to host memory, as ours is). f3d's own defaults otherwise (no anti-aliasing or tone
mapping, its default lights and camera, fitted once to the first frame); --no-f3d skips it.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time

from core.animation import Moment
from core.options import RenderOptions
from pipeline.animate import frame_times, posed
from pipeline.bake import bake_asset, bake_environment
from pipeline.gltf.rig import Rig
from pipeline.usd.rig import UsdRig
from renderer.raster import gpu
from renderer.raster.render import render
from renderer.sequence import render_animation


def main(argv=None) -> None:
    p = argparse.ArgumentParser()
    p.add_argument("asset")
    p.add_argument("--fps", type=float, default=12)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--animation", default=None)
    p.add_argument("--whole", action="store_true",
                   help="A reads each frame whole (the path before the rig, and USD's)")
    p.add_argument("--no-f3d", action="store_true", help="leave out the f3d column (C)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as cache:
        base = bake_asset(args.asset, cache)
        env = bake_environment("studio", cache, face_size=64)
        options = RenderOptions(width=args.size, height=args.size, animate=args.fps,
                                animation=args.animation)
        render(base, env, RenderOptions(width=args.size, height=args.size))  # warm-up
        times, motion = frame_times(base, args.fps, args.animation)
        t0 = time.perf_counter()
        rig: Rig | UsdRig | None = None
        if args.whole:
            pass
        elif args.asset.lower().endswith((".usd", ".usda", ".usdc", ".usdz")):
            rig = UsdRig(args.asset, base, times[0])  # pipeline.usd.rig: the stage read once
        else:
            rig = Rig(args.asset, base, args.animation)
        ts = time.perf_counter()
        poses = ([rig.pose(t, f"{base.key}:{t}") for t in times] if rig is not None else
                 [posed(args.asset, base, Moment(t, args.animation)) for t in times])
        t1 = time.perf_counter()
        writes = dict(gpu.stats)
        render_animation(poses, env, options, motion)
        t2 = time.perf_counter()
        writes = {k: gpu.stats[k] - writes[k] for k in ("asset_uploads", "poses", "vertex_writes")}
        for t in times:
            still = bake_asset(args.asset, cache, moment=Moment(t, args.animation))
            render(still, env, RenderOptions(width=args.size, height=args.size))
        t3 = time.perf_counter()
    n = len(times)
    print(f"{args.asset}: {n} frames at {args.fps:g} fps, {args.size} px")
    print(f"A animated preview{' (each frame read whole)' if args.whole else ''}: {t2 - t0:.2f} s "
          f"({n / (t2 - t0):.1f} frames/s): setup {1000 * (ts - t0):.0f} ms, "
          f"poses {1000 * (t1 - ts) / n:.1f} ms/frame, draws {1000 * (t2 - t1) / n:.1f} ms/frame; "
          f"GPU: {writes}")
    print(f"B separate stills:  {t3 - t2:.2f} s ({n / (t3 - t2):.1f} frames/s)")
    if not args.no_f3d:
        print(f"C f3d:              {f3d_frames(args.asset, times, args.size, args.animation)}")


def f3d_frames(asset: str, times: list[float], size: int, animation: str | None = None) -> str:
    """f3d rendering the animation at `times`, `size` px square (bench.f3d_play, in a process
    of its own: f3d's bundled libraries must load before the ones this process has), as a
    line of figures, or why not."""
    cmd = [sys.executable, "-m", "bench.f3d_play", asset, str(size), json.dumps(times)]
    if animation is not None:
        cmd.append(animation)
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    lines = run.stdout.strip().splitlines()
    if run.returncode != 0 or not lines:
        return f"not run (f3d failed: {(run.stderr.strip().splitlines() or ['?'])[-1]})"
    return lines[-1]

if __name__ == "__main__":
    main()
