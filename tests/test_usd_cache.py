"""The bake key follows every file a USD stage reads or looks for: a texture restored after a
bake, changed, or different beside a byte-identical copy of the stage is another entry."""
from __future__ import annotations

from PIL import Image

from pipeline.bake import bake_or_load_asset

STAGE = """#usda 1.0
(
    metersPerUnit = 1
)
def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] ( interpolation = "vertex" )
    rel material:binding = </Look>
}
def Material "Look"
{
    token outputs:surface.connect = </Look/S.outputs:surface>
    def Shader "S"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </Look/Tex.outputs:rgb>
        token outputs:surface
    }
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @tex.png@
        float3 outputs:rgb
    }
}
"""


def bake(path, cache):
    baked, _ = bake_or_load_asset(path, cache)
    textured = any(m.material.base_color_texture is not None for m in baked.meshes)
    return baked.key, textured


def test_restored_changed_and_copied_textures_rebake(tmp_path):
    cache = tmp_path / "cache"
    a = tmp_path / "a"
    a.mkdir()
    (a / "stage.usda").write_text(STAGE)
    key_missing, textured = bake(a / "stage.usda", cache)
    assert not textured
    assert bake(a / "stage.usda", cache) == (key_missing, False)  # unchanged: the same entry

    Image.new("RGB", (4, 4), (200, 0, 0)).save(a / "tex.png")  # restored
    key_red, textured = bake(a / "stage.usda", cache)
    assert textured and key_red != key_missing

    Image.new("RGB", (4, 4), (0, 0, 200)).save(a / "tex.png")  # changed
    key_blue, textured = bake(a / "stage.usda", cache)
    assert textured and key_blue not in (key_red, key_missing)

    b = tmp_path / "b"  # the same stage bytes elsewhere, beside another texture
    b.mkdir()
    (b / "stage.usda").write_text(STAGE)
    Image.new("RGB", (4, 4), (0, 200, 0)).save(b / "tex.png")
    key_b, textured = bake(b / "stage.usda", cache)
    assert textured and key_b not in (key_red, key_blue, key_missing)

    c = tmp_path / "c"  # ... and beside none: not the entries of a or b
    c.mkdir()
    (c / "stage.usda").write_text(STAGE)
    assert bake(c / "stage.usda", cache) == (key_missing, False)
    (b / "tex.png").unlink()
    assert bake(b / "stage.usda", cache) == (key_missing, False)
