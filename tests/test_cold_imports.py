"""What a cold `asset-preview render` of a USD stage loads: a new process renders a real stage
and reports the modules it imported and the processes it started."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "tests" / "assets"

# Modules the cold USD thumbnail path does not use: the tracers' JIT and Embree, scipy (hulls),
# trimesh, the service's web stack, pydantic (core/schema.py builds it only for a refusal),
# MaterialX (a stage without .mtlx), importlib.metadata, PIL's text drawing (views sheets),
# the multi-frame renderer, and pxr's UsdSkel / UsdLux bindings for a stage with neither.
HEAVY = ("numba", "llvmlite", "scipy", "trimesh", "embreex", "fastapi", "starlette", "uvicorn",
         "pydantic", "pydantic_core", "MaterialX", "importlib.metadata", "PIL.ImageDraw",
         "PIL.ImageFont", "renderer.sequence", "renderer.methods.raytrace", "pxr.UsdSkel",
         "pxr.UsdLux")

_CODE = """if True:
    import json, sys
    spawned = []
    def audit(event, args):
        if event in ("subprocess.Popen", "os.posix_spawn", "os.fork", "os.exec"):
            spawned.append(str(args[0]))
    sys.addaudithook(audit)
    from cli.main import main
    rc = main(sys.argv[1:])
    import os
    print(json.dumps({"rc": rc, "modules": sorted(sys.modules), "spawned": spawned,
                      "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""


def _cold_render(stage, tmp_path, env: dict | None = None) -> dict:
    argv = ["render", str(stage), "--out", str(tmp_path / "x.png"), "--cache", str(tmp_path / "cache"),
            "--size", "64"]
    out = subprocess.run([sys.executable, "-c", _CODE, *argv], cwd=ROOT, capture_output=True,
                         text=True, check=True, env=env)
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["rc"] == 0 and (tmp_path / "x.png").is_file(), out.stderr
    return report


def test_cold_usd_render_imports_nothing_heavy_and_starts_no_process(tmp_path):
    report = _cold_render(ASSETS / "usd" / "TextureCoordinateTest" / "TextureCoordinateTest.usda", tmp_path)
    loaded = set(report["modules"])
    assert "pxr.Usd" in loaded and "moderngl" in loaded  # the path did read USD and draw
    assert sorted(m for m in HEAVY if m in loaded) == []
    # glcontext asks ctypes.util.find_library for libGL and libEGL: `ldconfig -p` forks
    assert report["spawned"] == []


def test_a_skinned_stage_still_loads_usdskel(tmp_path):
    report = _cold_render(ASSETS / "usd" / "skel" / "bending_arm.usda", tmp_path)
    assert "pxr.UsdSkel" in report["modules"]


def test_a_cold_render_keeps_openblas_to_one_thread_unless_told(tmp_path):
    # numpy's OpenBLAS starts its thread pool as it loads; the render never needs it (cli.main)
    stage = ASSETS / "usd" / "TextureCoordinateTest" / "TextureCoordinateTest.usda"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    assert _cold_render(stage, tmp_path / "a", env)["blas_threads"] == "1"
    assert _cold_render(stage, tmp_path / "b", {**env, "OPENBLAS_NUM_THREADS": "2"})["blas_threads"] == "2"
