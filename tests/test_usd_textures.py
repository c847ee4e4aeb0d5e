"""UsdUVTexture as UsdShade resolves it: an unconnected `st` reads its value (fallback (0, 0))
at every point, a primvar reader's `varname` may come through a material interface input,
and TGA, EXR and 16-bit PNG files are read."""
from __future__ import annotations

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from core.colour import srgb_to_linear
from pipeline.ingest import load_scene

STAGE = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    texCoord2f[] primvars:uvmap = [(0, 0), (1, 0), (1, 1), (0, 1)] ( interpolation = "vertex" )
    rel material:binding = </Look>
}
def Material "Look"
{
    string inputs:frame:stPrimvarName = "uvmap"
    token outputs:surface.connect = </Look/S.outputs:surface>
    def Shader "S"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </Look/Tex.outputs:rgb>
        token outputs:surface
    }
    def Shader "Reader"
    {
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname.connect = </Look.inputs:frame:stPrimvarName>
        float2 outputs:result
    }
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @FILE@
        ST
        float3 outputs:rgb
    }
}
"""


def write(tmp_path, file: str, st: str = "float2 inputs:st.connect = </Look/Reader.outputs:result>"):
    path = tmp_path / "card.usda"
    path.write_text(STAGE.replace("FILE", file).replace("ST", st))
    return load_scene(path)


def texture_of(scene):
    (mat,) = scene.materials
    assert mat.base_color_texture is not None, scene.warnings
    return mat.base_color_texture, scene.textures[mat.base_color_texture.texture].image


def test_varname_through_an_interface_input(tmp_path):
    Image.new("RGB", (4, 4), (200, 10, 10)).save(tmp_path / "red.png")
    scene = write(tmp_path, "red.png")
    (mesh,) = scene.meshes
    assert not any("no UVs" in w for w in scene.warnings), scene.warnings
    # uvmap's st (v up) as glTF uv (v down)
    assert sorted(map(tuple, mesh.uv0.tolist())) == [(0, 0), (0, 1), (1, 0), (1, 1)]


@pytest.mark.parametrize("st, expected", [("", (0.0, 0.0)), ("float2 inputs:st = (0.75, 0.25)", (0.75, 0.25))])
def test_unconnected_st_reads_its_value_everywhere(tmp_path, st, expected):
    Image.new("RGB", (4, 4), (200, 10, 10)).save(tmp_path / "red.png")
    scene = write(tmp_path, "red.png", st)
    texture_of(scene)
    (mesh,) = scene.meshes
    assert not any("no UVs" in w for w in scene.warnings), scene.warnings
    np.testing.assert_allclose(mesh.uv0, np.tile([[expected[0], 1 - expected[1]]], (4, 1)))


def test_tga_exr_and_16_bit_png(tmp_path):
    Image.new("RGB", (4, 2), (10, 200, 30)).save(tmp_path / "green.tga")
    _, img = texture_of(write(tmp_path, "green.tga"))
    assert img.shape == (2, 4, 4) and tuple(img[0, 0]) == (10, 200, 30, 255)

    rgb = np.zeros((2, 4, 3), np.float32)
    rgb[..., 2] = 0.2140  # linear 0.214 -> sRGB 0.5
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"RGB": rgb}) as f:
        f.write(str(tmp_path / "blue.exr"))
    _, img = texture_of(write(tmp_path, "blue.exr"))
    assert img.shape == (2, 4, 4) and abs(int(img[1, 3, 2]) - 128) <= 1 and img[0, 0, 0] == 0

    grey16 = np.full((2, 4), 40000, np.uint16)  # 16-bit grey: 40000 / 65535 = 0.61
    Image.fromarray(grey16).save(tmp_path / "grey16.png")
    _, img = texture_of(write(tmp_path, "grey16.png"))
    # linear under auto (Storm's rule), so the base colour slot, which decodes sRGB, reads 0.61
    assert abs(float(srgb_to_linear(img[0, 0, 0])) - 40000 / 65535) < 0.005, img[0, 0]


def test_broken_exr_names_the_file(tmp_path):
    (tmp_path / "bad.exr").write_bytes(b"\x76\x2f\x31\x01" + b"\0" * 40)
    scene = write(tmp_path, "bad.exr")
    assert scene.materials[0].base_color_texture is None
    assert any("bad.exr" in w and "EXR" in w for w in scene.warnings), scene.warnings
