"""`asset-preview bench encode`: thumbnail encoding, time and size per format and setting.

A rendered Duck (opaque, environment background; and transparent, RGBA) at each size, encoded
by Frame.encode (PNG: Sub filter + ISA-L deflate level 1; WebP: method 0, lossy alpha 70; JPEG:
libjpeg-turbo) beside Pillow's PNG at compress_level 1 (what Frame.encode used before) and 6
(Pillow's default) and WebP at its default method 4, on the same pixels in the same run.
Medians of --repeat, wall and CPU; PNGs are decoded back and compared with the pixels.
"""
from __future__ import annotations

import argparse
import io
import statistics
import time
from functools import partial
from typing import Callable


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sizes", default="256,512,1024")
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--cache", default=None, help="bake cache (default: a temporary folder)")


def run(args: argparse.Namespace) -> int:
    import tempfile

    import numpy as np
    from PIL import Image

    from bench.assets import ASSETS
    from core.cubemap import default_face_size
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer.raster.render import render
    cache = args.cache or tempfile.mkdtemp(prefix="bench-encode-")
    asset = bake_asset(ASSETS / "gltf" / "Duck.glb", cache)

    def pillow(px, fmt, **kw) -> bytes:
        buf = io.BytesIO()
        Image.fromarray(px).save(buf, fmt, **kw)
        return buf.getvalue()

    # CPU time beside wall: encoding is one thread, so CPU ms is its cost on a busy machine
    print(f"{'px':>5} {'image':>12} {'encoder':>34} {'ms':>7} {'cpu ms':>7} {'KB':>8}")
    for size in (int(s) for s in args.sizes.split(",")):
        env = bake_environment("footprint_court", cache, face_size=default_face_size(size))
        for background in ("env", "transparent"):
            frame = render(asset, env, RenderOptions(width=size, height=size, yaw=30.0, pitch=20.0,
                                                     background=background))
            px = frame.rgba8[..., :3].copy() if background == "env" else frame.rgba8
            decoded = np.asarray(Image.open(io.BytesIO(frame.encode("png"))))
            assert np.array_equal(decoded, px), "PNG does not decode to the frame's pixels"
            cases: dict[str, Callable[[], bytes]] = {
                "ours png": partial(frame.encode, "png"),
                "pillow png level 1": partial(pillow, px, "PNG", compress_level=1),
                "pillow png level 6": partial(pillow, px, "PNG", compress_level=6),
                "ours webp q90 (method 0, alpha 70)": partial(frame.encode, "webp"),
                "pillow webp q90 method 4": partial(pillow, px, "WEBP", quality=90),
                "ours jpeg q90": partial(frame.encode, "jpeg")}
            for name, fn in cases.items():
                times, cpu, data = [], [], b""
                for _ in range(args.repeat):
                    t, c = time.perf_counter(), time.process_time()
                    data = fn()
                    times.append(time.perf_counter() - t)
                    cpu.append(time.process_time() - c)
                label = "RGB" if background == "env" else "RGBA"
                print(f"{size:>5} {label:>12} {name:>34} {1e3 * statistics.median(times):7.2f} "
                      f"{1e3 * statistics.median(cpu):7.2f} "
                      f"{len(data) / 1024:8.1f}", flush=True)
    return 0
