"""Back faces of single-sided surfaces (core/storm.py; bench/RESULTS.md "nurbs9"): a USD gprim
with doubleSided = 0 seen from behind is drawn and lit as Storm lights it, its normal as
authored (N.E clamped to 0): under a uniform environment of radiance L its colour is
L (F0 A + B) + L base (1 - F0), (A, B) Storm's table at N.E = 0, in the raster, the tree
tracer and the path tracer alike; its front is shaded as before. glTF's doubleSided = false
still culls back faces (the glTF spec): nothing is drawn from behind."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core import storm
from core.options import RenderOptions
from pipeline.bake import bake_environment, build_baked
from pipeline.environment import uniform
from pipeline.ingest import load_scene
from renderer import render
from tests.gltf_builder import Builder

L = 0.8  # the environment's radiance
BASE = (0.2, 0.4, 0.9)
ROUGHNESS = 0.5

CARD = f"""#usda 1.0
(
    defaultPrim = "W"
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "W"
{{
    def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        normal3f[] normals = [(0, 0, 1), (0, 0, 1), (0, 0, 1), (0, 0, 1)] (interpolation = "vertex")
        uniform bool doubleSided = DS
        rel material:binding = </W/Looks/M>
    }}
    def Scope "Looks"
    {{
        def Material "M"
        {{
            token outputs:surface.connect = </W/Looks/M/S.outputs:surface>
            def Shader "S"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = {BASE}
                float inputs:roughness = {ROUGHNESS}
                token outputs:surface
            }}
        }}
    }}
}}
"""

OPTIONS = RenderOptions(width=32, height=32, tonemap="none", background="transparent", shadow=0.0,
                        pitch=0.0, method="opaque")
METHODS = {"raster": {"method": "opaque"}, "raytrace": {"method": "raytrace"},
           "path": {"method": "raytrace", "integrator": "path", "samples": 16, "noise": 0.0}}


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    return bake_environment(uniform.name((L,) * 3), tmp_path_factory.mktemp("sky"), face_size=16)


def _centre(asset, sky, yaw: float, **kw) -> np.ndarray:
    img = render(asset, sky, dataclasses.replace(OPTIONS, yaw=yaw, **kw)).linear
    return img[12:20, 12:20].reshape(-1, 4).mean(axis=0)


def _card(tmp_path, double_sided: int, key: str):
    path = tmp_path / f"{key}.usda"
    path.write_text(CARD.replace("= DS", f"= {double_sided}"))
    return build_baked(load_scene(path), key=f"back-faces-{key}")


def test_table_is_storms_at_grazing():
    """The integral at N.E -> 0: finite, A + B past 1 at low roughness (Schlick-Smith's G
    over N.E grows there), matching the values read off hdSt's formula (roughness 0.3)."""
    a, b = storm.back_face_albedo([0.3])
    assert (a[0], b[0]) == pytest.approx((0.512, 0.324), abs=0.005)
    table = storm.back_face_table()
    assert table.shape == (storm.TABLE_SIZE, 2) and np.isfinite(table).all()
    assert "vec2[33](" in storm.glsl_table()


@pytest.mark.parametrize("name", list(METHODS))
def test_single_sided_back_face_is_lit_as_storm_lights_it(tmp_path, sky, name):
    single = _card(tmp_path, 0, "single")
    double = _card(tmp_path, 1, "double")
    a, b = storm.back_face_albedo([ROUGHNESS])
    f0 = 0.04  # UsdPreviewSurface's ior 1.5
    expected = L * (f0 * a[0] + b[0]) + L * np.array(BASE) * (1 - f0)
    front = {yaw: _centre(single, sky, yaw, **METHODS[name]) for yaw in (0.0, 180.0)}
    behind = min(front, key=lambda y: abs(front[y][:3] - expected).max())
    seen = front[behind]
    assert seen[3] == pytest.approx(1.0, abs=1e-3)
    np.testing.assert_allclose(seen[:3], expected, rtol=0.03, err_msg=name)
    # the other side is the front, shaded as a double-sided card's front (not Storm's back)
    other = front[180.0 - behind]
    np.testing.assert_allclose(other, _centre(double, sky, 180.0 - behind, **METHODS[name]), atol=0.01)
    assert abs(other[:3] - expected).max() > 0.05
    # a double-sided card seen from behind is lit as its front
    np.testing.assert_allclose(_centre(double, sky, behind, **METHODS[name]), other, atol=0.02)


@pytest.mark.parametrize("name", list(METHODS))
def test_gltf_single_sided_back_faces_are_culled(tmp_path, sky, name):
    b = Builder()
    mat = b.material(pbrMetallicRoughness={"baseColorFactor": [*BASE, 1.0]}, doubleSided=False)
    b.node(b.mesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32),
                  np.array([0, 1, 2, 0, 2, 3], np.uint32), material=mat,
                  NORMAL=np.tile([0, 0, 1], (4, 1)).astype(np.float32)))
    path = b.write(tmp_path / "card.glb")
    asset = build_baked(load_scene(path), key="back-faces-gltf")
    alphas = sorted(_centre(asset, sky, yaw, **METHODS[name])[3] for yaw in (0.0, 180.0))
    assert alphas[0] == pytest.approx(0.0, abs=1e-3) and alphas[1] == pytest.approx(1.0, abs=1e-3)


def _lit_card(tmp_path, double_sided: int, rotate_x: float, key: str):
    light = f"""    def DistantLight "Sun"
    {{
        float inputs:intensity = 3
        bool inputs:normalize = 1
        float3 xformOp:rotateXYZ = ({rotate_x}, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
"""
    path = tmp_path / f"{key}.usda"
    path.write_text(CARD.replace("= DS", f"= {double_sided}").replace('def Scope "Looks"', light + '    def Scope "Looks"'))
    return build_baked(load_scene(path), key=f"back-faces-lit-{key}")


@pytest.mark.parametrize("name", list(METHODS))
def test_back_face_takes_light_from_its_authored_side(tmp_path, tmp_path_factory, name):
    """Under a distant light and no environment, a single-sided card seen from behind is lit
    (diffuse only) by a light on the side its normal faces, and dark under one on the
    viewer's side, where a double-sided card is lit; the three methods agree."""
    dark = bake_environment(uniform.name((0.0,) * 3), tmp_path_factory.mktemp("dark"), face_size=16)
    behind = 180.0  # yaw 0 looks from +Z, the side the card's normal faces
    far_side = _centre(_lit_card(tmp_path, 0, -36.87, "far"), dark, behind, **METHODS[name])
    near_side = _centre(_lit_card(tmp_path, 0, -143.13, "near"), dark, behind, **METHODS[name])
    double = _centre(_lit_card(tmp_path, 1, -143.13, "double"), dark, behind, **METHODS[name])
    raster = _centre(_lit_card(tmp_path, 0, -36.87, "far-raster"), dark, behind, **METHODS["raster"])
    assert far_side[:3].max() > 0.05, far_side
    np.testing.assert_allclose(far_side[:3], raster[:3], rtol=0.05)
    assert near_side[:3].max() < 0.005, near_side
    assert double[:3].max() > 0.05, double
