"""NurbsPatch, NurbsCurves and HermiteCurves as Storm draws them (pipeline/usd/nurbs.py,
measured in bench/RESULTS.md "nurbs9"): a patch is the mesh of its control hull (order,
knots and trim curves ignored), NurbsCurves and HermiteCurves linear curves through their
points at their widths. Each changes the pixels where the prim is, in the raster and the ray
tracer; counts that do not fit are skipped naming the prim; a hull over the triangle limit
is refused before its faces are made; a gprim type still not drawn is named in its warning."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import LimitExceeded
from core.options import RenderOptions
from pipeline.bake import bake_environment, build_baked
from pipeline.environment import uniform
from pipeline.ingest import load_scene
from pipeline.limits import Limits
from pipeline.usd import curves
from pipeline.usd.nurbs import hull_faces
from renderer import render

HEADER = '#usda 1.0\n(\n    defaultPrim = "W"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n'
# a dark card behind, at z = -1, so that both frames share the bounds with and without the prim
CARD = """    def Mesh "Card"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-2, -2, -1), (2, -2, -1), (2, 2, -1), (-2, 2, -1)]
        color3f[] primvars:displayColor = [(0.05, 0.05, 0.05)]
    }
"""


def _patch(nu: int = 3, nv: int = 3, order: int = 3, extra: str = "", z: float = 0.5) -> str:
    pts = ", ".join(f"({-1 + 2 * i / (nu - 1)}, {-1 + 2 * j / (nv - 1)}, {z if (i, j) == (nu // 2, nv // 2) else 0})"
                    for j in range(nv) for i in range(nu))
    knots = lambda n: [0] * order + [k / (n - order + 1) for k in range(1, n - order + 1)] + [1] * order  # noqa: E731
    return f"""    def NurbsPatch "Patch"
    {{
        int uVertexCount = {nu}
        int vVertexCount = {nv}
        int uOrder = {order}
        int vOrder = {order}
        double[] uKnots = {knots(nu)}
        double[] vKnots = {knots(nv)}
        point3f[] points = [{pts}]
        color3f[] primvars:displayColor = [(1, 0, 0)]
{extra}    }}
"""


NURBS_CURVES = """    def NurbsCurves "Nurbs"
    {
        int[] curveVertexCounts = [4]
        int[] order = [4]
        double[] knots = [0, 0, 0, 0, 1, 1, 1, 1]
        point3f[] points = [(-1, 0.5, 0), (-0.3, 1.5, 0), (0.3, -0.5, 0), (1, 0.5, 0)]
        float[] widths = [0.2] (interpolation = "constant")
        color3f[] primvars:displayColor = [(0, 1, 0)]
    }
"""
HERMITE = """    def HermiteCurves "Hermite"
    {
        int[] curveVertexCounts = [2]
        point3f[] points = [(-1, -1, 0), (1, -1, 0)]
        vector3f[] tangents = [(0, 5, 0), (0, -5, 0)]
        float[] widths = [0.2] (interpolation = "constant")
        color3f[] primvars:displayColor = [(0, 0, 1)]
    }
"""


def _write(tmp_path, body: str, name: str = "s.usda"):
    path = tmp_path / name
    path.write_text(HEADER + 'def Xform "W"\n{\n' + body + CARD + "}\n")
    return path


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    return bake_environment(uniform.name((0.8,) * 3), tmp_path_factory.mktemp("sky"), face_size=16)


OPTIONS = RenderOptions(width=64, height=64, tonemap="none", background="transparent",
                        shadow=0.0, yaw=0.0, pitch=0.0, method="opaque")


def _frames(path, key: str):
    scene = load_scene(path)
    asset = build_baked(scene, key=f"nurbs-{key}")
    return scene, asset


def test_hull_topology():
    counts, idx = hull_faces(3, 2)
    assert counts.tolist() == [4, 4]
    # Storm's order: row v, column u, u fastest; right-handed quads
    assert idx.reshape(-1, 4).tolist() == [[0, 1, 4, 3], [1, 2, 5, 4]]


def test_patch_is_its_hull(tmp_path):
    """The mesh is the control hull: its vertices the control points (the bump's apex at
    the control point's height, where a cubic surface would pass below it), whatever the
    order, and a trimmed patch draws whole."""
    for order in (2, 3):
        scene = load_scene(_write(tmp_path, _patch(order=order), f"o{order}.usda"))
        mesh = next(m for m in scene.meshes if m.name == "/W/Patch")
        assert len(mesh.indices) == 8  # 2 x 2 quads
        assert mesh.positions[:, 2].max() == pytest.approx(0.5)
        assert any("control hulls" in w for w in scene.warnings)
    trim = ("        int[] trimCurve:counts = [1]\n        int[] trimCurve:orders = [2]\n"
            "        int[] trimCurve:vertexCounts = [4]\n        double[] trimCurve:knots = [0, 0, 0.5, 1, 1, 1]\n"
            "        double3[] trimCurve:points = [(0.4, 0.4, 1), (0.6, 0.4, 1), (0.6, 0.6, 1), (0.4, 0.4, 1)]\n")
    scene = load_scene(_write(tmp_path, _patch(extra=trim), "trim.usda"))
    assert len(next(m for m in scene.meshes if m.name == "/W/Patch").indices) == 8
    assert any("trim curves are not applied" in w for w in scene.warnings)


@pytest.mark.parametrize("body,name,channel", [(_patch(), "/W/Patch", 0), (NURBS_CURVES, "/W/Nurbs", 1),
                                               (HERMITE, "/W/Hermite", 2)])
def test_each_gprim_changes_pixels_where_it_is(tmp_path, sky, body, name, channel):
    """Beside the stage without it (the card alone fixes the framing), the prim's colour
    appears where the prim projects, in the raster and the ray tracer."""
    with_prim = _write(tmp_path, body, "with.usda")
    without = _write(tmp_path, "", "without.usda")
    scene, asset = _frames(with_prim, f"with-{channel}")
    assert name in {m.name for m in scene.meshes}
    assert not [w for w in scene.warnings if "not read" in w], scene.warnings
    _, bare = _frames(without, f"without-{channel}")
    for method in ("opaque", "raytrace"):
        opts = dataclasses.replace(OPTIONS, method=method)
        a = render(asset, sky, opts).linear
        b = render(bare, sky, opts).linear
        changed = np.abs(a[..., :3] - b[..., :3]).max(axis=2) > 0.05
        assert changed.sum() > 20, (method, int(changed.sum()))
        rgb = a[changed][:, :3].mean(axis=0)
        assert rgb[channel] > 2 * np.delete(rgb, channel).max(), (method, rgb)


def test_curves_are_linear_through_their_points(tmp_path):
    """Storm's topology: order, knots and tangents ignored, the tube's centre line passes
    through every point (a cubic through these would not reach (-0.3, 1.5))."""
    scene = load_scene(_write(tmp_path, NURBS_CURVES + HERMITE))
    nurbs = next(m for m in scene.meshes if m.name == "/W/Nurbs")
    # linear: each segment's own two rings of SIDES vertices, 3 segments
    assert len(nurbs.positions) == 3 * 2 * curves.SIDES
    # the rings at the apex (square to each segment) reach past the point: a cubic's would
    # stay under 1.0 there
    assert 1.5 < nurbs.positions[:, 1].max() <= 1.6 + 1e-4
    hermite = next(m for m in scene.meshes if m.name == "/W/Hermite")
    assert np.abs(hermite.positions[:, 1] + 1).max() == pytest.approx(0.1, abs=1e-4)
    assert any("HermiteCurves" in w and "tangents ignored" in w for w in scene.warnings)
    assert any("NurbsCurves" in w and "order and knots ignored" in w for w in scene.warnings)


def test_bad_counts_skip_and_hostile_hulls_refuse(tmp_path):
    bad = _patch().replace("int uVertexCount = 3", "int uVertexCount = 4")
    scene = load_scene(_write(tmp_path, bad + NURBS_CURVES, "bad.usda"))
    assert "/W/Patch" not in {m.name for m in scene.meshes}
    assert any("/W/Patch" in w and "4 x 3" in w and "skipped" in w for w in scene.warnings)
    # over the triangle limit: refused from the counts, before any face is made
    huge = _patch(nu=40, nv=40)
    limits = Limits(max_triangles=1000)
    with pytest.raises(LimitExceeded, match="/W/Patch: a 40 x 40 hull makes 3042 triangles"):
        load_scene(_write(tmp_path, huge, "huge.usda"), limits=limits)
    bad_curves = NURBS_CURVES.replace("curveVertexCounts = [4]", "curveVertexCounts = [9]")
    scene = load_scene(_write(tmp_path, bad_curves, "badc.usda"))
    assert any("/W/Nurbs" in w and "curveVertexCounts" in w for w in scene.warnings)


def test_gprims_not_drawn_are_named(tmp_path):
    tet = """    def TetMesh "Tet"
    {
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
        int4[] tetVertexIndices = [(0, 1, 2, 3)]
    }
"""
    scene = load_scene(_write(tmp_path, tet))
    assert any("TetMesh prims are not read; skipped: /W/Tet" in w for w in scene.warnings), scene.warnings
