"""`python -m bench.path_nee_time`: the path integrator's cost of next-event estimation toward
emitters, in one process: EmissiveStrengthTest at 128 px from bench fidelity's view, NEE off and
on interleaved (path_trace.EMITTER_NEE), `--repeat` frames each; prints every frame and the
medians' ratio (a shared machine's load scales both alike)."""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from bench.assets import CORPUS


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=Path, default=CORPUS / "gltf-samples", help="Khronos sample models folder")
    p.add_argument("--paths", type=int, default=16, help="paths a pixel")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--cache", type=Path, default=None)
    args = p.parse_args()
    from bench.fidelity import VIEW
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer.methods import path_trace
    from renderer.methods.raytrace import render_raytrace

    cache = args.cache or Path(tempfile.mkdtemp(prefix="bench-nee-"))
    asset = bake_asset(args.samples / "EmissiveStrengthTest/glTF-Binary/EmissiveStrengthTest.glb", cache)
    env = bake_environment("footprint_court", cache, face_size=256)
    o = RenderOptions(width=args.size, height=args.size, background="transparent", shadow=0.0, tonemap="aces",
                      method="raytrace", integrator="path", samples=args.paths, yaw=VIEW["yaw"],
                      pitch=VIEW["pitch"], fov=VIEW["fov"])
    render_raytrace(asset, env, o.replace(width=32, height=32))  # numba's cached code loads
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(args.repeat):
        for nee in (False, True):
            path_trace.EMITTER_NEE = nee
            t0 = time.perf_counter()
            frame = render_raytrace(asset, env, o)
            times[nee].append((time.perf_counter() - t0) * 1e3)
            print(f"NEE {'on ' if nee else 'off'} {times[nee][-1]:8.0f} ms  passes {frame.plan['passes']}  "
                  f"split {frame.plan['split_ms']}", flush=True)
    off, on = statistics.median(times[False]), statistics.median(times[True])
    print(f"median off {off:.0f} ms, on {on:.0f} ms: {on / off:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
