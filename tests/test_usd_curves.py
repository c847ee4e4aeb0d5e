"""BasisCurves and Points (pipeline/usd/curves.py): read as tubes and small spheres of their
widths, evaluated per basis and wrap; drawn where they are by the raster and the ray tracer;
wider curves cover more; the vertex budget thins or refuses with a warning naming the prim;
purpose and visibility as for meshes; no "not read" warning for them any more."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import EmptyScene
from core.options import RenderOptions
from pipeline.bake import bake_environment, build_baked
from pipeline.environment import uniform
from pipeline.ingest import load_scene
from pipeline.usd import curves
from pipeline.usd import stage as usd_stage
from renderer import render

HEADER = '#usda 1.0\n(\n    defaultPrim = "W"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n'


def _curve(width: float, extra: str = "", name: str = "C") -> str:
    return f"""    def BasisCurves "{name}"
    {{
        uniform token type = "linear"
        int[] curveVertexCounts = [2]
        point3f[] points = [(-1, 0, 0), (1, 0, 0)]
        float[] widths = [{width}] (interpolation = "constant")
        color3f[] primvars:displayColor = [(1, 0, 0)]
{extra}    }}
"""


POINTS = """    def Points "P"
    {
        point3f[] points = [(0, 0.8, 0)]
        float[] widths = [0.4]
        color3f[] primvars:displayColor = [(0, 0, 1)]
    }
    def Points "Anchor"
    {
        point3f[] points = [(0, -0.8, 0)]
        float[] widths = [0.01]
    }
"""


def _write(tmp_path, body: str, name: str = "s.usda"):
    path = tmp_path / name
    path.write_text(HEADER + 'def Xform "W"\n{\n' + body + "}\n")
    return path


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    return bake_environment(uniform.name((0.5,) * 3), tmp_path_factory.mktemp("sky"), face_size=16)


OPTIONS = RenderOptions(width=64, height=64, tonemap="none", background="transparent",
                        shadow=0.0, yaw=0.0, pitch=0.0, method="opaque")


def _frames(tmp_path, sky, width: float, key: str):
    scene = load_scene(_write(tmp_path, _curve(width) + POINTS, f"{key}.usda"))
    asset = build_baked(scene, key=f"curves-{key}")
    return scene, {m: render(asset, sky, dataclasses.replace(OPTIONS, method=m)).linear
                   for m in ("opaque", "raytrace")}


def test_curve_and_points_render_where_they_are(tmp_path, sky):
    scene, frames = _frames(tmp_path, sky, 0.1, "thin")
    assert not [w for w in scene.warnings if "not read" in w], scene.warnings
    names = {m.name for m in scene.meshes}
    assert {"/W/C", "/W/P", "/W/Anchor"} <= names
    for method, img in frames.items():
        alpha = img[..., 3]
        rows = np.flatnonzero(alpha.max(axis=1) > 0.5)
        # framed on x in [-1, 1], y in [-0.8, 1.0]: the curve's row sits below the middle and
        # spans most of the width, red; the point's blob above it, blue
        curve_row = int(np.argmax((alpha > 0.5).sum(axis=1)))
        assert (alpha[curve_row] > 0.5).sum() > 0.6 * img.shape[1], method
        rgb = img[curve_row, img.shape[1] // 4, :3]
        assert rgb[0] > 3 * max(rgb[1], rgb[2]), (method, rgb)
        top = int(rows.min())
        assert top < curve_row - 5, method
        blob = img[top + 2, img.shape[1] // 2 - 2: img.shape[1] // 2 + 3, :3].mean(axis=0)
        assert blob[2] > 3 * max(blob[0], blob[1]), (method, blob)


def test_width_changes_coverage(tmp_path, sky):
    _, thin = _frames(tmp_path, sky, 0.05, "w05")
    _, wide = _frames(tmp_path, sky, 0.2, "w20")
    for method in thin:
        # the same framing (the points bound it): coverage grows with the width, the ray
        # tracer agreeing with the raster within a pixel row
        a = (thin[method][..., 3] > 0.5).sum()
        b = (wide[method][..., 3] > 0.5).sum()
        assert b > a * 1.5, (method, a, b)
    assert abs(int((thin["opaque"][..., 3] > 0.5).sum()) -
               int((thin["raytrace"][..., 3] > 0.5).sum())) < 64


def test_tube_radius_and_bases():
    # bezier interpolates its end vertices; bspline of 4 collinear points starts at (P0 + 4 P1 + P2) / 6
    s, lengths, closed = curves.sample_curves(np.array([4]), "cubic", "bezier", "nonperiodic")
    p = np.array([[0, 0, 0], [1, 1, 0], [2, 1, 0], [3, 0, 0]], float)
    at = curves.evaluate(p, "vertex", s)
    np.testing.assert_allclose(at[[0, -1]], p[[0, 3]], atol=1e-12)
    assert lengths == [curves.SAMPLES + 1] and closed == [False]
    s, _, _ = curves.sample_curves(np.array([4]), "cubic", "bspline", "nonperiodic")
    np.testing.assert_allclose(curves.evaluate(p, "vertex", s)[0], (p[0] + 4 * p[1] + p[2]) / 6)
    # a periodic catmullRom passes through every vertex and closes
    ring = np.array([[np.cos(a), np.sin(a), 0] for a in np.arange(6) * np.pi / 3])
    s, lengths, closed = curves.sample_curves(np.array([6]), "cubic", "catmullRom", "periodic")
    at = curves.evaluate(ring, "vertex", s)
    np.testing.assert_allclose(at[::curves.SAMPLES], np.roll(ring, -1, axis=0), atol=1e-12)  # segment i: P(i+1) to P(i+2)
    assert closed == [True] and curves.varying_count(6, "cubic", "catmullRom", "periodic") == 6
    pos, nrm, tri, src = curves.tubes(at, np.full(len(at), 0.05), lengths, closed)
    np.testing.assert_allclose(np.linalg.norm(pos - at[src], axis=1), 0.05, atol=1e-9)
    assert tri.max() < len(pos) and len(tri) == lengths[0] * 2 * curves.SIDES
    with pytest.raises(curves.CurveError):
        curves.segment_count(5, "cubic", "bezier", "nonperiodic")


def test_primvars_widths_and_defaults(tmp_path):
    body = """    def BasisCurves "V"
    {
        uniform token type = "linear"
        int[] curveVertexCounts = [2, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 2, 0), (1, 2, 0)]
        float[] widths = [0.1, 0.1, 0.3, 0.5] (interpolation = "vertex")
        color3f[] primvars:displayColor = [(1, 0, 0), (0, 1, 0)] (interpolation = "uniform")
    }
    def Points "One"
    {
        point3f[] points = [(0, 9, 0), (3, 9, 0)]
        float[] widths = [0.3]
    }
    def BasisCurves "Bare"
    {
        uniform token type = "linear"
        int[] curveVertexCounts = [2]
        point3f[] points = [(0, 5, 0), (1, 5, 0)]
    }
"""
    scene = load_scene(_write(tmp_path, body))
    by = {m.name: m for m in scene.meshes}
    v = by["/W/V"]
    second = v.positions[:, 1] > 1
    np.testing.assert_allclose(v.colors[~second, :3], [[1, 0, 0]] * int((~second).sum()))
    np.testing.assert_allclose(v.colors[second, :3], [[0, 1, 0]] * int(second.sum()))
    r = np.abs(v.positions[second][:, 1] - 2).max()  # vertex widths: up to 0.5 at the end
    assert r == pytest.approx(0.25, abs=1e-4)
    one = by["/W/One"]  # one width under the schema's vertex default: constant, as Storm reads it
    np.testing.assert_allclose(np.ptp(one.positions, axis=0), [3.3, 0.3, 0.3], atol=1e-4)
    assert not [w for w in scene.warnings if "widths" in w], scene.warnings
    bare = by["/W/Bare"]  # no widths: Storm's fallback
    assert np.abs(bare.positions[:, 1] - 5).max() == pytest.approx(curves.DEFAULT_WIDTH / 2, abs=1e-4)


def test_budget_thins_then_refuses(tmp_path, monkeypatch):
    n = 50
    pts = ", ".join(f"({i * 0.1}, 0, 0), ({i * 0.1}, 1, 0)" for i in range(n))
    body = f"""    def BasisCurves "Grass"
    {{
        uniform token type = "linear"
        int[] curveVertexCounts = [{", ".join(["2"] * n)}]
        point3f[] points = [{pts}]
        float[] widths = [0.01]
    }}
"""
    path = _write(tmp_path, body)
    full = load_scene(path)
    per = 2 * curves.SIDES
    assert len(full.meshes[0].positions) == n * per
    monkeypatch.setattr(usd_stage, "CURVE_BUDGET", n * per // 4)
    thinned = load_scene(path)
    assert any("/W/Grass" in w and "every 5th drawn" in w for w in thinned.warnings), thinned.warnings
    assert len(thinned.meshes[0].positions) == 10 * per  # curves 0, 5, ..., 45
    monkeypatch.setattr(usd_stage, "CURVE_BUDGET", per // 2)  # not even one curve fits
    with pytest.raises(EmptyScene, match="/W/Grass: 50 curves would make .* skipped"):
        load_scene(path)


def test_purpose_visibility_and_bad_topology(tmp_path):
    body = (_curve(0.1, '        uniform token purpose = "guide"\n', "Guide")
            + _curve(0.1, '        token visibility = "invisible"\n', "Hidden")
            + """    def BasisCurves "Odd"
    {
        uniform token type = "cubic"
        uniform token basis = "bezier"
        int[] curveVertexCounts = [5]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0)]
    }
""" + _curve(0.1))
    scene = load_scene(_write(tmp_path, body))
    assert {m.name for m in scene.meshes} == {"/W/C"}
    assert any("/W/Odd" in w and "bezier curve of 5 vertices" in w for w in scene.warnings)
    guides = load_scene(_write(tmp_path, body, "g.usda"), purposes=("render", "guide"))
    assert "/W/Guide" in {m.name for m in guides.meshes}


def test_material_binding_on_curves_and_points(tmp_path):
    body = """    def Material "Gold"
    {
        token outputs:surface.connect = </W/Gold/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.9, 0.6, 0.1)
            token outputs:surface
        }
    }
    def BasisCurves "C" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        uniform token type = "linear"
        int[] curveVertexCounts = [2]
        point3f[] points = [(-1, 0, 0), (1, 0, 0)]
        float[] widths = [0.1] (interpolation = "constant")
        color3f[] primvars:displayColor = [(0, 0, 1)]
        rel material:binding = </W/Gold>
    }
    def Points "P" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        point3f[] points = [(0, 1, 0)]
        float[] widths = [0.2]
        rel material:binding = </W/Gold>
    }
"""
    scene = load_scene(_write(tmp_path, body))
    for inst in scene.instances:
        mesh, mat = scene.meshes[inst.mesh], scene.materials[inst.material]
        # the material's own diffuse wins over displayColor, as on meshes
        assert mat.base_color[:3] == pytest.approx((0.9, 0.6, 0.1), abs=1e-6), mesh.name
        assert mesh.colors is None, mesh.name


FACING = """    def DistantLight "Sun"
    {
        float inputs:intensity = 3
        bool inputs:normalize = 1
        float3 xformOp:rotateXYZ = (0, 60, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }
    def Points "P"
    {
        point3f[] points = [(-0.8, 0, 0)]
        float[] widths = [1.2]
        color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]
    }
    def Mesh "Card"
    {
        uniform bool doubleSided = 1
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(0.4, -0.6, 0), (1.6, -0.6, 0), (1.6, 0.6, 0), (0.4, 0.6, 0)]
        color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]
    }
"""


@pytest.mark.parametrize("method,integrator", [("opaque", "tree"), ("raytrace", "tree"),
                                               ("raytrace", "path")])
def test_points_are_discs_facing_the_viewer(tmp_path, method, integrator):
    """Storm draws a point as a screen-facing disc lit with the eye's axis as its normal
    (hdSt points.glslfx: Neye = (0, 0, 1)), not a sphere: under a light from the side the disc
    is as bright on its far side as on its lit one, and as bright as a card facing the
    camera with the same colour beside it (a sphere's halves differ by more than 2x here)."""
    dark = bake_environment(uniform.name((0.0,) * 3), tmp_path / "dark", face_size=16)
    scene = load_scene(_write(tmp_path, FACING, "facing.usda"))
    point = next(i for i, m in enumerate(scene.meshes) if m.name == "/W/P")
    card = next(i for i, m in enumerate(scene.meshes) if m.name == "/W/Card")
    faces = {i.mesh: scene.materials[i.material].face_viewer for i in scene.instances}
    assert faces[point] and not faces[card]
    asset = build_baked(scene, key=f"points-facing-{method}-{integrator}")
    img = render(asset, dark, dataclasses.replace(OPTIONS, width=96, height=96, method=method,
                                                  integrator=integrator, samples=16)).linear
    covered = img[..., 3] > 0.99
    cols = np.flatnonzero(covered.any(axis=0))
    # the point covers the left part of the frame, the card the right; split them at the gap
    gaps = np.flatnonzero(np.diff(cols) > 1)
    assert len(gaps) == 1, cols
    disc_cols = cols[: gaps[0] + 1]
    card_cols = cols[gaps[0] + 1:]
    lum = img[..., :3].mean(axis=-1)
    mid = (disc_cols[0] + disc_cols[-1]) // 2
    row = slice(40, 56)  # the middle rows, inside both
    left = lum[row, disc_cols[0] + 3: mid - 2][covered[row, disc_cols[0] + 3: mid - 2]].mean()
    right = lum[row, mid + 2: disc_cols[-1] - 2][covered[row, mid + 2: disc_cols[-1] - 2]].mean()
    card = lum[row, card_cols[0] + 3: card_cols[-1] - 2].mean()
    assert card > 0.05, card
    # the path integrator adds the light the card throws back onto the disc's near side
    near = 0.08 if integrator == "path" else 0.03
    assert left == pytest.approx(right, rel=near), (left, right)
    assert left == pytest.approx(card, rel=0.05), (left, card)
