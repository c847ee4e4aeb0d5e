"""UsdPreviewSurface's specular workflow (specularColor is F0, textured or not, as Storm
shades it) and what Hydra draws a gprim with when it has no material: its displayColor /
displayOpacity, whose fallback is UsdImaging's 0.5 grey."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from cli.main import main
from core.colour import srgb_to_linear
from pipeline.ingest import load_scene

CARD = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{
    def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] ( interpolation = "vertex" )
        rel material:binding = </World/M>
    }
    def Material "M"
    {
        token outputs:surface.connect = </World/M/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.1, 0.1, 0.1)
            int inputs:useSpecularWorkflow = 1
            SPEC
            float inputs:metallic = 1
            float inputs:roughness = 0.3
            token outputs:surface
        }
        def Shader "Tex"
        {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @spec.png@
            float2 inputs:st.connect = </World/M/St.outputs:result>
            float3 outputs:rgb
        }
        def Shader "St"
        {
            uniform token info:id = "UsdPrimvarReader_float2"
            string inputs:varname = "st"
            float2 outputs:result
        }
    }
}
"""
TEXEL = (200, 100, 50)  # sRGB


def _f0(path, tmp_path) -> np.ndarray:
    """The normal-incidence reflectance the renderer shades with, at the card's centre."""
    out = tmp_path / "f0.npy"
    assert main(["render", str(path), "--out", str(out), "--size", "32", "--yaw", "0",
                 "--pitch", "0", "--tonemap", "none", "--msaa", "0", "--material-debug",
                 "specular", "--cache", str(tmp_path / "cache")]) == 0
    return np.load(out)[12:20, 12:20, :3].reshape(-1, 3).mean(axis=0)


@pytest.mark.parametrize("spec, expect", [
    ("color3f inputs:specularColor = (0.9, 0.6, 0.2)", (0.9, 0.6, 0.2)),
    ("color3f inputs:specularColor.connect = </World/M/Tex.outputs:rgb>",
     tuple(srgb_to_linear(np.array(TEXEL, np.uint8)))),
    ("", (0.0, 0.0, 0.0)),  # specularColor's fallback: black
])
def test_specular_workflow_reflects_specular_color(tmp_path, spec, expect):
    Image.new("RGB", (4, 4), TEXEL).save(tmp_path / "spec.png")
    path = tmp_path / "card.usda"
    path.write_text(CARD.replace("SPEC", spec))
    scene = load_scene(path)
    mat = scene.materials[scene.instances[0].material]
    assert mat.metallic == 0.0  # metallic is the metallic workflow's; unused here
    assert not any("useSpecularWorkflow" in w for w in scene.warnings), scene.warnings
    np.testing.assert_allclose(_f0(path, tmp_path), expect, atol=0.005)


CUBES = """#usda 1.0
(
    metersPerUnit = 1
)
def Cube "Plain"
{
}
def Cube "Coloured"
{
    color3f[] primvars:displayColor = [(0.8, 0.1, 0.1)]
    float[] primvars:displayOpacity = [0.25]
    double3 xformOp:translate = (3, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""


def test_gprim_without_material_is_hydra_grey_or_its_display_color(tmp_path):
    path = tmp_path / "cubes.usda"
    path.write_text(CUBES)
    scene = load_scene(path)
    material = {scene.meshes[i.mesh].name: scene.materials[i.material] for i in scene.instances}
    mesh = {m.name: m for m in scene.meshes}
    assert material["/Plain"].base_color == (0.5, 0.5, 0.5, 1.0)
    assert material["/Plain"].base_color_texture is None and mesh["/Plain"].colors is None
    colors = mesh["/Coloured"].colors
    assert colors is not None
    np.testing.assert_allclose(colors[:, :3], np.broadcast_to((0.8, 0.1, 0.1), (len(colors), 3)), atol=1e-6)
    np.testing.assert_allclose(colors[:, 3], 0.25, atol=1e-6)
    assert material["/Coloured"].alpha_mode == "BLEND"
