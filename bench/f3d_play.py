"""f3d playing a glTF animation at given times (the f3d column of bench.animation).

    python -m bench.f3d_play ASSET SIZE '[t0, t1, ...]' [ANIMATION]

Run in a process of its own, importing nothing of the project: f3d's wheel bundles its own
OpenSSL and VTK, which must load before any other copy (an import after pxr or moderngl
fails on OPENSSL_3.2.0). Setup is the EGL engine, its window and loading the file (f3d's
default camera fitted to it, its default lights, no anti-aliasing or tone mapping) and one
first draw; then per frame `scene.animation.load_time(t)` and `window.render_to_image()`,
read back to host memory as ours is. Prints one line of figures, or why it did not run.
"""
from __future__ import annotations

import json
import sys
import time


def main(argv: list[str]) -> int:
    asset, size, times = argv[0], int(argv[1]), [float(t) for t in json.loads(argv[2])]
    animation = argv[3] if len(argv) > 3 else None
    try:
        import f3d
    except ImportError as exc:
        print(f"not run (f3d does not import: {exc})")
        return 0
    f3d.Log.set_verbose_level(f3d.Log.QUIET)
    t0 = time.perf_counter()
    f3d.Engine.autoload_plugins()
    engine = f3d.Engine.create_egl()
    engine.window.size = (size, size)
    engine.options["ui.loader_progress"] = False
    try:
        engine.scene.add(asset)
    except Exception as exc:  # f3d raises its own, per reader
        print(f"not run (f3d cannot load it: {exc})")
        return 0
    anim = engine.scene.animation
    names = anim.get_names()
    if not names:
        print("not run (f3d finds no animation in it)")
        return 0
    index = 0 if animation is None else (names.index(animation) if animation in names else
                                         int(animation) if animation.isdigit() else -1)
    if not 0 <= index < len(names):
        print(f"not run (f3d has no animation {animation!r}: {names})")
        return 0
    if index != 0:  # f3d plays the first by default; another is chosen before loading
        engine.options["scene.animation.indices"] = [index]
        engine.scene.clear()
        engine.scene.add(asset)
        anim = engine.scene.animation
    anim.load_time(times[0])
    engine.window.render_to_image()  # the first draw: shaders, uploads (setup, as ours)
    t1 = time.perf_counter()
    for t in times:
        anim.load_time(t)
        image = engine.window.render_to_image()
    t2 = time.perf_counter()
    if (image.width, image.height) != (size, size):
        print(f"not run (f3d drew {image.width} x {image.height}, not {size} px)")
        return 0
    n = len(times)
    print(f"{t2 - t0:.2f} s with setup, {n / (t2 - t1):.1f} frames/s after it: setup "
          f"{1000 * (t1 - t0):.0f} ms, {1000 * (t2 - t1) / n:.1f} ms/frame "
          f"(animation {names[index]!r}, its range {anim.get_time_range()})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
