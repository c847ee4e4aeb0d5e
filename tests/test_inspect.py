"""`asset-preview inspect` as a user runs it: a subprocess, its stdout, stderr and exit code."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
from gltf_builder import cube


def inspect(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cli.main", "inspect", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_json_shape(assets):
    path = assets / "gltf" / "CesiumMilkTruck.glb"
    proc = inspect(path, "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert {"file", "format", "meshes", "triangles", "vertices", "materials", "textures",
            "bounds", "warnings"} <= set(info)
    assert info["file"] == str(path) and info["format"] == "glb"
    assert info["triangles"] == 3624 and info["textures"] == 1 and info["meshes"] == 4
    assert len(info["bounds"]) == 2 and all(len(b) == 3 for b in info["bounds"])
    assert info["bounds"][0][0] < info["bounds"][1][0]
    names = {m["name"]: m["class"] for m in info["materials"]}
    assert names == {"truck": "opaque", "glass": "opaque", "window_trim": "opaque",
                     "wheels": "opaque"}
    assert info["warnings"] == []


def test_text_output(assets):
    proc = inspect(assets / "mesh" / "bunny.ply")
    assert proc.returncode == 0, proc.stderr
    assert "triangles 16301" in proc.stdout and "material 'default': opaque" in proc.stdout


def test_rejected_asset_exits_3(tmp_path):
    path = cube(tmp_path / "c.glb")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    proc = inspect(path, "--json")
    assert proc.returncode == 3
    assert proc.stdout == ""
    assert proc.stderr.startswith(f"error: {path}: ") and "truncated" in proc.stderr
    assert "Traceback" not in proc.stderr
    missing = inspect(tmp_path / "none.gltf")
    assert missing.returncode == 3 and missing.stderr.strip() == f"error: {tmp_path / 'none.gltf'}: no such file"


@pytest.mark.parametrize("args", [[], ["a.glb", "--no-such-flag"]])
def test_usage_errors_exit_2(args):
    proc = inspect(*args)
    assert proc.returncode == 2 and "usage:" in proc.stderr


def test_reference_refused_names_the_flag(tmp_path):
    # the CLI's refusal names the flag that set the sandbox (the service speaks of the upload)
    doc = json.loads(cube(tmp_path / "c.gltf", "gltf").read_text())
    doc["buffers"][0]["uri"] = "../c.bin"
    (tmp_path / "a").mkdir()
    path = tmp_path / "a" / "escape.gltf"
    path.write_text(json.dumps(doc))
    proc = inspect(path, "--sandbox", path.parent)
    assert proc.returncode == 3 and "leaves the root" in proc.stderr, proc.stderr
    assert "--sandbox DIR" in proc.stderr
    assert inspect(path, "--sandbox", tmp_path).returncode == 0
    assert inspect(path).returncode == 0  # a trusted local file reads its neighbours


PART = """#usda 1.0
def Mesh "M" {
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
}
"""
BROKEN_REFS = """#usda 1.0
(
    defaultPrim = "W"
)
def Xform "W" {
    def "A" (references = @./part.usda@</Nope>) {}
    def "B" (references = @./part.usda@</M>) {}
    def "C" (references = @./missing.usda@</M>) {}
}
"""


def test_usd_warnings_once_and_pxr_diagnostics_captured(tmp_path):
    (tmp_path / "part.usda").write_text(PART)
    path = tmp_path / "main.usda"
    path.write_text(BROKEN_REFS)
    proc = inspect(path)
    assert proc.returncode == 0, proc.stderr
    # pxr's raw lines (`Warning: in _ReportErrors at line ... of stage.cpp`) do not leak to stderr,
    # nor does our logger repeat what the output lists
    assert "_ReportErrors" not in proc.stderr and "stage.cpp" not in proc.stderr, proc.stderr
    assert "WARNING" not in proc.stderr and "metersPerUnit" not in proc.stderr, proc.stderr
    lines = [line for line in proc.stdout.splitlines() if "warning:" in line]
    assert len(lines) == len(set(lines)) == 3, proc.stdout  # </Nope>, missing.usda, metersPerUnit
    assert sum("missing.usda" in line for line in lines) == 1 and sum("Nope" in line for line in lines) == 1


def test_pxr_diagnostics_become_warnings():
    from pxr import Tf, UsdUtils

    from pipeline.usd.stage import _take_diagnostics
    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    Tf.Warn("odd thing (instantiating stage on stage @x.usda@ <0x1234>)")
    Tf.Warn("composition said this already")
    warnings = ["composition: composition said this already"]
    _take_diagnostics(delegate, warnings)
    del delegate
    assert warnings == ["composition: composition said this already", "USD: odd thing"]
