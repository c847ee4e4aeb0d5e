"""Hydra Storm (usdview's renderer) as a reference: run by the Storm interpreter, not ours.

    STORM_PYTHON bench/storm_worker.py JOB.json

Runs under the Python of the bpy wheel (Blender as a module bundles USD with UsdImagingGL
and UsdAppUtils; usd-core in our venv has no imaging, and two pxr copies must not share a
process). It imports nothing from this project. JOB: {"stage", "camera" (prim path), "out"
(PNG), "width", "warm_out" (optional: a second image after the first, in this process),
"complexity" (optional, usdview's: 1.0 draws subdivision cages, 1.2 refines two levels)}.
Prints one JSON line: the times of each step and whether each image was written.
"""
from __future__ import annotations

import glob
import json
import os
import sys
import time


def _pxr_path() -> None:
    # bpy keeps its pxr under bpy/<version>/python/lib/pythonX.Y/site-packages; importing bpy
    # itself (all of Blender) is not needed to use it.
    import importlib.util
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("storm_worker: this interpreter has no bpy (pip install bpy==5.0.1)")
    base = list(spec.submodule_search_locations)[0]
    found = glob.glob(os.path.join(base, "*", "python", "lib", "python3*", "site-packages", "pxr"))
    if not found:
        raise SystemExit(f"storm_worker: no pxr under {base}")
    sys.path.insert(0, os.path.dirname(found[0]))


def main(job_path: str) -> int:
    t0 = time.perf_counter()
    with open(job_path) as f:
        job = json.load(f)
    times: dict[str, float] = {}
    import moderngl
    # Storm needs GL 4.5 core; moderngl makes the EGL context current for the recorder.
    ctx = moderngl.create_standalone_context(backend="egl", require=450)  # type: ignore[arg-type]  # the stub types **settings wrongly
    times["gl_context_s"] = time.perf_counter() - t0
    t = time.perf_counter()
    _pxr_path()
    from pxr import Tf, Usd, UsdAppUtils, UsdGeom
    times["pxr_import_s"] = time.perf_counter() - t
    result: dict = {"renderer": ctx.info["GL_RENDERER"], "usd": ".".join(map(str, Usd.GetVersion()))}

    def frame(out: str) -> dict:
        t = time.perf_counter()
        stage = Usd.Stage.Open(job["stage"])
        open_s = time.perf_counter() - t
        cam = UsdGeom.Camera.Get(stage, job["camera"])
        if not cam:
            raise SystemExit(f"storm_worker: {job['stage']}: no camera {job['camera']}")
        t = time.perf_counter()
        rec = UsdAppUtils.FrameRecorder("HdStormRendererPlugin", True)
        rec.SetImageWidth(int(job["width"]))
        rec.SetComplexity(float(job.get("complexity", 1.0)))  # > 1: subdivision refined
        # The same light as ours: the stage's own lights (or the wrapper's dome), no
        # headlight; sRGB encoding, no tone curve (ours renders with --tonemap none).
        rec.SetCameraLightEnabled(False)
        rec.SetColorCorrectionMode("sRGB")
        rec.SetIncludedPurposes(["default", "render"])
        error = ""
        try:
            rec.Record(stage, cam, Usd.TimeCode.EarliestTime(), out)
        except Tf.ErrorException as exc:
            # HgiGL posts "invalid enum" GL errors on Mesa (state it saves and restores);
            # the frame is still written: kept as a note, the image decides.
            error = str(exc).strip().splitlines()[0][-200:] if str(exc).strip() else "Tf error"
        return {"open_s": open_s, "record_s": time.perf_counter() - t, "written": os.path.isfile(out),
                "error": error}

    result["first"] = frame(job["out"])
    result["first_image_s"] = time.perf_counter() - t0
    result["first_image_cpu_s"] = time.process_time()  # all threads, since the process started
    print("FIRST", flush=True)  # the parent times the first image by this line's arrival
    if job.get("warm_out"):
        t = time.perf_counter()
        result["warm"] = frame(job["warm_out"])
        result["warm_s"] = time.perf_counter() - t
    result["times"] = times
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
