"""Hydra Storm as the USD reference: where its interpreter is, the wrapper layer both
renderers look through, and one Storm render in a new process.

Storm comes from the bpy wheel (`pip install bpy==5.0.1 moderngl` into a venv of its own,
docs/usd.md); ASSET_PREVIEW_STORM_PYTHON names that venv's python. Without it, whatever
needs Storm skips and says why (`storm_python()`).

The wrapper (`write_wrapper`) sits beside the stage, sublayers it, copies the root layer's
stage metadata (up axis, units, default prim, time codes: a sublayer's are not the stage's)
and adds `/BenchCamera` framing the stage's bounds from three-quarter above, square 256 px
aperture; and, when the stage has no light of its own, `/BenchDome`, a dome light with a
uniform white texture (Storm draws no light from a dome without one). Both renderers use it
through their camera option, under the same light.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ENV = "ASSET_PREVIEW_STORM_PYTHON"
WORKER = Path(__file__).with_name("storm_worker.py")
CAMERA = "/BenchCamera"
DOME_TEXTURE = "bench_dome_white.png"
# Storm sizes a dome light's cube map and its split-sum BRDF table from the texture's width
# (width / 4): this 16-px texture makes a 4 x 4 table whose first texel sits at N.E = 0.125,
# which grazing views and single-sided back faces (N.E = 0) read, where a 512-px HDRI's is at
# 0.004. Kept small: at 512 px Storm's first image took 4 minutes a stage here (llvmpipe).
DOME_SIZE = (16, 8)
BLACK_ENV = "bench_black.png"
YAW, PITCH = 30.0, 25.0
FOCAL, APERTURE = 35.0, 20.0  # mm: a vertical field of view of 2 atan(10/35) = 31.9 degrees
_METADATA = ("upAxis", "metersPerUnit", "defaultPrim", "timeCodesPerSecond", "framesPerSecond",
             "startTimeCode", "endTimeCode")


def storm_python() -> tuple[str | None, str]:
    """(the Storm interpreter or None, why not)."""
    path = os.environ.get(ENV, "").strip()
    if not path:
        return None, f"Storm reference not set up: {ENV} names no interpreter (docs/usd.md)"
    if not os.access(path, os.X_OK):
        return None, f"{ENV}={path}: not an executable"
    return path, ""


@dataclass
class Wrapper:
    path: Path
    own_lights: bool  # the stage lights itself: no dome added, ours gets a black environment
    own_dome: bool
    black_env: Path | None = None
    notes: list[str] = field(default_factory=list)


def _look_at(eye, target, up):
    """A camera-to-world matrix (USD row vectors): looking down -Z at target, +Y toward up."""
    from pxr import Gf
    return Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(*up)).GetInverse()


def write_wrapper(stage_path: Path, name: str | None = None) -> Wrapper:
    """Write `<stem>.bench.usda` beside `stage_path` (which must be in a writable copy)."""
    from PIL import Image
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

    stage_path = Path(stage_path)
    folder = stage_path.parent
    out = folder / (name or f"{stage_path.stem}.bench.usda")
    stage = Usd.Stage.Open(str(stage_path), Usd.Stage.LoadAll)
    time_code = Usd.TimeCode.EarliestTime()
    up_z = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    lights = [p for p in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies())
              if p.HasAPI(UsdLux.LightAPI)]
    own_dome = any(p.IsA(UsdLux.DomeLight) for p in lights)
    cache = UsdGeom.BBoxCache(time_code, [UsdGeom.Tokens.default_, UsdGeom.Tokens.render], True)
    box = cache.ComputeWorldBound(stage.GetPseudoRoot()).ComputeAlignedRange()
    notes = []
    if box.IsEmpty():
        notes.append("empty bounds: camera frames the unit cube")
        box = Gf.Range3d(Gf.Vec3d(-1, -1, -1), Gf.Vec3d(1, 1, 1))
    centre = (box.GetMin() + box.GetMax()) / 2
    radius = max((box.GetMax() - box.GetMin()).GetLength() / 2, 1e-6)
    half = math.atan(APERTURE / 2 / FOCAL)
    dist = radius / math.sin(half) * 1.02
    yaw, pitch = math.radians(YAW), math.radians(PITCH)
    d = (math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch))
    if up_z:  # the same view of a Z-up stage: its front is -Y
        d, up = (d[0], -d[2], d[1]), (0, 0, 1)
    else:
        up = (0, 1, 0)
    eye = [centre[i] + dist * d[i] for i in range(3)]
    layer = Sdf.Layer.CreateNew(str(out)) if not out.exists() else Sdf.Layer.FindOrOpen(str(out))
    layer.Clear()
    src = Sdf.Layer.FindOrOpen(str(stage_path))
    for key in _METADATA:
        if src and src.pseudoRoot.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, src.pseudoRoot.GetInfo(key))
    layer.subLayerPaths.append(f"./{stage_path.name}")
    wrapper = Usd.Stage.Open(layer)
    wrapper.SetEditTarget(Usd.EditTarget(layer))
    cam = UsdGeom.Camera.Define(wrapper, CAMERA)
    cam.CreateFocalLengthAttr(FOCAL)
    cam.CreateHorizontalApertureAttr(APERTURE)
    cam.CreateVerticalApertureAttr(APERTURE)
    cam.CreateClippingRangeAttr(Gf.Vec2f(max(dist - 1.5 * radius, dist * 1e-3), dist + 1.5 * radius))
    cam.AddTransformOp().Set(_look_at(eye, centre, up))
    result = Wrapper(out, own_lights=bool(lights), own_dome=own_dome, notes=notes)
    if not lights:
        Image.new("RGB", DOME_SIZE, (255, 255, 255)).save(folder / DOME_TEXTURE)
        dome = UsdLux.DomeLight.Define(wrapper, "/BenchDome")
        dome.CreateTextureFileAttr(Sdf.AssetPath(f"./{DOME_TEXTURE}"))
        dome.CreateIntensityAttr(1.0)
    elif not own_dome:
        result.black_env = folder / BLACK_ENV
        Image.new("RGB", (16, 8), (0, 0, 0)).save(result.black_env)
    layer.Save()
    return result


@dataclass
class StormFrame:
    image: Path | None
    first_image_s: float  # from spawning the process to the first image on disk
    first_image_cpu_s: float | None  # CPU seconds (all threads) of the process up to then
    warm_s: float | None  # a second image of the stage in the same process
    report: dict
    error: str = ""


def render_storm(python: str, stage: Path, out: Path, width: int = 256, warm: bool = True,
                 timeout: float = 300.0, complexity: float = 1.0) -> StormFrame:
    """One Storm render of `stage` through CAMERA in a new process (and a warm second one);
    `complexity` as usdview's (1.0 Low: subdivision cages drawn as they are; 1.1, 1.2, 1.3:
    refined 1, 2, 3 levels)."""
    with tempfile.TemporaryDirectory() as tmp:
        job = Path(tmp) / "job.json"
        warm_out = out.with_name(out.stem + ".warm.png")
        job.write_text(json.dumps({"stage": str(stage), "camera": CAMERA, "out": str(out), "width": width,
                                   "warm_out": str(warm_out) if warm else None,
                                   "complexity": complexity}))
        start = time.perf_counter()
        proc = subprocess.Popen([python, str(WORKER), str(job)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        first = math.nan
        lines = []
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                if line.strip() == "FIRST":
                    first = time.perf_counter() - start
                else:
                    lines.append(line)
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            return StormFrame(None, math.nan, None, None, {}, f"timed out after {timeout:.0f} s")
        stderr = proc.stderr.read() if proc.stderr else ""
        if warm_out.exists():
            warm_out.unlink()
    report: dict = {}
    for line in reversed(lines):
        if line.startswith("{"):
            report = json.loads(line)
            break
    if proc.returncode or not report:
        tail = [ln for ln in stderr.splitlines() if "HgiGLPostPendingGLErrors" not in ln][-3:]
        return StormFrame(None, math.nan, None, None, report, f"exit {proc.returncode}: {' | '.join(tail)}")
    written = report.get("first", {}).get("written")
    return StormFrame(out if written else None, first, report.get("first_image_cpu_s"), report.get("warm_s"), report,
                      "" if written else "no image written")


def copy_tree(src: Path, dst: Path) -> Path:
    """A writable copy of a stage folder (the wrappers go beside the stages)."""
    shutil.copytree(src, dst, dirs_exist_ok=True)
    for p in dst.rglob("*"):
        if p.is_file():
            p.chmod(0o644)
    return dst
