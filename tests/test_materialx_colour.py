"""MaterialX colour management: colour constants and images declared in MaterialX's standard
colour spaces (on the input, or inherited from the node, nodegraph or document) reach the
material in lin_rec709, converted as MaterialX's default colour management system (cmlib)
converts them."""
from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image
from test_materialx import _render, one, stage, surface

from core.colour import srgb_encode
from pipeline.usd import colorspaces

# cmlib's acescg_to_lin_rec709 (NG_acescg_to_lin_rec709_color3), as column vectors
ACESCG_TO_REC709 = np.array([[1.705050992658, -0.621792120657, -0.083258872001],
                             [-0.130256417507, 1.140804736575, -0.010548319068],
                             [-0.024003356805, -0.128968976065, 1.15297233287]])


def _cmlib_matrix(space: str) -> np.ndarray:
    import MaterialX as mx
    folder = mx.getDefaultDataSearchPath().asString().split(mx.PATH_LIST_SEPARATOR)[0]
    text = open(f"{folder}/libraries/cmlib/cmlib_ng.mtlx").read()
    found = re.search(rf'NG_{space}_to_lin_rec709_color3".*?type="matrix33" value="([^"]+)"',
                      text, re.S)
    assert found, space
    return np.array([float(x) for x in found.group(1).split(",")]).reshape(3, 3).T  # row vectors


@pytest.mark.parametrize("space, gamut", [("acescg", "ap1"), ("lin_adobergb", "adobergb"),
                                          ("lin_displayp3", "displayp3")])
def test_gamut_matrices_from_primaries_match_materialx_cmlib(space, gamut):
    # derived from primaries + Bradford; cmlib prints its P3 matrix to 8 digits
    np.testing.assert_allclose(colorspaces.to_rec709(gamut), _cmlib_matrix(space), atol=2e-5)
    # white stays white in every gamut
    np.testing.assert_allclose(colorspaces.to_rec709(gamut).sum(1), 1.0, atol=1e-5)


def test_every_standard_space_named_by_the_spec_is_known():
    spec = ("srgb_texture lin_rec709 g22_rec709 g18_rec709 acescg lin_ap1 g22_ap1 g18_ap1 "
            "lin_srgb adobergb lin_adobergb srgb_displayp3 lin_displayp3 rec709_display")
    for name in spec.split():
        assert colorspaces.lookup(name) is not None, name
    assert colorspaces.lookup("acescc") is None


@pytest.mark.parametrize("space, value, expected", [
    ("lin_rec709", 0.5, 0.5),
    ("srgb_texture", 0.5, 0.21404114),
    ("g22_rec709", 0.5, 0.5 ** 2.2),
    ("g18_rec709", 0.5, 0.5 ** 1.8),
    ("rec709_display", 0.5, 0.5 ** 2.4),
    ("adobergb", 0.5, 0.5 ** (563 / 256)),  # grey: the matrix keeps it
    ("g22_rec709", -0.25, 0.0),  # cmlib clamps before the power
])
def test_transfer_functions_on_grey(space, value, expected):
    got = colorspaces.to_working(np.full(3, value), colorspaces.lookup(space))
    np.testing.assert_allclose(got, expected, atol=1e-7)


def test_acescg_constant_colour_is_converted_to_lin_rec709(tmp_path):
    doc = surface("standard_surface", """
        <input name="base" type="float" value="1"/>
        <input name="base_color" type="color3" value="0.5, 0.4, 0.3" colorspace="acescg"/>
        <input name="specular_color" type="color3" value="0.5, 0.4, 0.3"/>""")
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    assert scene.warnings == []
    # (0.5, 0.4, 0.3) through cmlib's matrix by hand: 1.70505*0.5 - 0.62179*0.4 - 0.08326*0.3 ...
    np.testing.assert_allclose(m.base_color[:3], (0.578830, 0.388025, 0.282303), atol=1e-5)
    np.testing.assert_allclose(m.base_color[:3], ACESCG_TO_REC709 @ (0.5, 0.4, 0.3), atol=1e-9)
    # no colorspace anywhere: the value as written
    np.testing.assert_allclose(m.specular_color, (0.5, 0.4, 0.3), atol=1e-9)


def test_colorspace_is_inherited_from_document_and_nodegraph(tmp_path):
    """The nearest enclosing colorspace applies: the document's (acescg) to the surface's own
    constant, the nodegraph's (g22_rec709) to a constant node inside it, an input's own
    (lin_rec709) over both."""
    body = """
    <nodegraph name="NG" colorspace="g22_rec709">
      <constant name="c" type="color3"><input name="value" type="color3" value="0.5, 0.5, 0.5"/>
      </constant>
      <output name="out" type="color3" nodename="c"/>
    </nodegraph>""" + surface("standard_surface", """
        <input name="base_color" type="color3" nodegraph="NG" output="out"/>
        <input name="specular_color" type="color3" value="0.5, 0.4, 0.3"/>
        <input name="coat_color" type="color3" value="0.9, 0.9, 0.9" colorspace="lin_rec709"/>
        <input name="emission" type="float" value="1"/>
        <input name="emission_color" type="color3" value="0.2, 0.1, 0.05"/>""")
    path = stage(tmp_path, "", "/World/mtl/M")
    (tmp_path / "look.mtlx").write_text(f'<?xml version="1.0"?>\n<materialx version="1.38" '
                                        f'colorspace="acescg">\n{body}\n</materialx>\n')
    scene, m = one(path)
    assert scene.warnings == []
    np.testing.assert_allclose(m.base_color[:3], 0.5 ** 2.2, atol=1e-6)
    np.testing.assert_allclose(m.specular_color, ACESCG_TO_REC709 @ (0.5, 0.4, 0.3), atol=1e-6)
    np.testing.assert_allclose(m.emissive, ACESCG_TO_REC709 @ (0.2, 0.1, 0.05), atol=1e-6)


def test_colour_space_metadata_on_usd_authored_materialx_inputs(tmp_path):
    materials = """
    def Material "M"
    {
        token outputs:mtlx:surface.connect = </World/M/S.outputs:out>
        def Shader "S"
        {
            uniform token info:id = "ND_standard_surface_surfaceshader"
            float inputs:base = 1
            color3f inputs:base_color = (0.5, 0.4, 0.3) (colorSpace = "acescg")
            color3f inputs:specular_color = (0.5, 0.4, 0.3)
            token outputs:out
        }
    }
    """
    scene, m = one(stage(tmp_path, None, "/World/M", materials))
    assert scene.warnings == []
    np.testing.assert_allclose(m.base_color[:3], ACESCG_TO_REC709 @ (0.5, 0.4, 0.3), atol=1e-6)
    np.testing.assert_allclose(m.specular_color, (0.5, 0.4, 0.3), atol=1e-6)


def test_unknown_colorspace_is_a_warning_and_read_as_lin_rec709(tmp_path):
    doc = surface("standard_surface", '<input name="base" type="float" value="1"/>'
                  '<input name="base_color" type="color3" value="0.5, 0.4, 0.3" '
                  'colorspace="acescc"/>')
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    np.testing.assert_allclose(m.base_color[:3], (0.5, 0.4, 0.3), atol=1e-9)
    assert any("'acescc'" in w and "lin_rec709" in w for w in scene.warnings), scene.warnings


ACES_TEXELS = (128, 102, 77)  # read raw: acescg (0.502, 0.400, 0.302)


def _aces_image_stage(folder, space="acescg"):
    folder.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (4, 4), ACES_TEXELS).save(folder / "c.png")
    Image.new("L", (4, 4), 128).save(folder / "r.png")
    doc = (f'<image name="img" type="color3"><input name="file" type="filename" value="c.png" '
           f'colorspace="{space}"/></image>'
           '<image name="r" type="float"><input name="file" type="filename" value="r.png" '
           'colorspace="g22_rec709"/></image>'
           + surface("standard_surface", '<input name="base" type="float" value="1"/>'
                                         '<input name="base_color" type="color3" nodename="img"/>'
                                         '<input name="specular_roughness" type="float" '
                                         'nodename="r"/>'))
    return stage(folder, doc, "/World/mtl/M")


def test_texture_declared_acescg_is_converted_texel_by_texel(tmp_path):
    scene, m = one(_aces_image_stage(tmp_path))
    assert scene.warnings == []
    base = scene.textures[m.base_color_texture.texture]
    expected = ACESCG_TO_REC709 @ (np.array(ACES_TEXELS) / 255.0)
    # the base colour slot decodes sRGB: the converted colour stored sRGB-encoded, 8 bits
    stored = np.round(srgb_encode(expected) * 255)
    assert base.image[0, 0, :3].tolist() == stored.tolist()
    assert base.image[0, 0, 3] == 255
    # a float image has no gamut: g22 undone, read raw by the roughness slot
    rough = scene.textures[m.metallic_roughness_texture.texture].image
    assert rough[0, 0, 1] == round((128 / 255) ** 2.2 * 255)


def test_render_of_an_acescg_texture_matches_its_lin_rec709_constant(tmp_path):
    """Linear render, constant white environment: the textured quad and a quad whose
    constant base colour is the converted texel agree to 0.01 (8-bit storage)."""
    textured = _render(_aces_image_stage(tmp_path / "t"), tmp_path)
    rgb = ACESCG_TO_REC709 @ (np.array(ACES_TEXELS) / 255.0)
    doc = surface("standard_surface", '<input name="base" type="float" value="1"/>'
                  f'<input name="base_color" type="color3" value="{rgb[0]}, {rgb[1]}, {rgb[2]}"/>'
                  f'<input name="specular_roughness" type="float" value="{(128 / 255) ** 2.2}"/>')
    constant = _render(stage(tmp_path / "c", doc, "/World/mtl/M"), tmp_path)
    covered = textured[..., 3] > 0.5
    assert covered.mean() > 0.3 and np.array_equal(covered, constant[..., 3] > 0.5)
    np.testing.assert_allclose(textured[covered, :3].mean(0), constant[covered, :3].mean(0),
                               atol=0.01)
    # and it is not the unconverted read: red moves by more than the threshold
    assert abs(rgb[0] - ACES_TEXELS[0] / 255.0) > 0.05


@pytest.mark.parametrize("space", ["lin_rec709", "acescg"])
def test_openexr_image_declared_linear_is_not_encoded_twice(tmp_path, space):
    """Our 8-bit decode holds an OpenEXR's linear values sRGB-encoded: the base colour slot
    reads them as they are (lin_rec709) or after the gamut's conversion (acescg), never
    sRGB-encoded a second time."""
    import OpenEXR
    value = np.array([0.5, 0.4, 0.3], np.float32)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"RGB": np.broadcast_to(value, (2, 2, 3)).copy()}) as f:
        f.write(str(tmp_path / "c.exr"))
    doc = (f'<image name="img" type="color3"><input name="file" type="filename" value="c.exr" '
           f'colorspace="{space}"/></image>'
           + surface("standard_surface", '<input name="base_color" type="color3" nodename="img"/>'))
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    assert scene.warnings == []
    rgb = value if space == "lin_rec709" else ACESCG_TO_REC709 @ value
    texel = scene.textures[m.base_color_texture.texture].image[0, 0, :3]
    # 8-bit sRGB storage of the linear value: within one step of its encoding
    np.testing.assert_allclose(texel, srgb_encode(rgb) * 255, atol=1.0)


USD_IMAGE = """
    def Material "M"
    {
        asset inputs:tex = @c.png@ INTERFACE
        token outputs:mtlx:surface.connect = </World/M/S.outputs:out>
        def Shader "S"
        {
            uniform token info:id = "ND_standard_surface_surfaceshader"
            float inputs:base = 1
            color3f inputs:base_color.connect = </World/M/img.outputs:out>
            color3f inputs:specular_color = (0.5, 0.4, 0.3) (colorSpace = "lin_ap1_scene")
            token outputs:out
        }
        def Shader "img"
        {
            uniform token info:id = "ND_image_color3"
            FILE
            color3f outputs:out
        }
    }
"""


@pytest.mark.parametrize("where", ["input", "interface"])
def test_usd_authored_image_colour_space_from_its_file_or_the_interface_input(tmp_path, where):
    """usdMtlx writes an image's colorspace as the file attribute's colorSpace metadata; the
    attribute giving the value (a material's interface input) may carry it instead. USD's
    own name for a space (Gf.ColorSpaceNames: lin_ap1_scene) reads as MaterialX's acescg."""
    Image.new("RGB", (4, 4), ACES_TEXELS).save(tmp_path / "c.png")
    if where == "input":
        text = USD_IMAGE.replace(" INTERFACE", "").replace(
            "FILE", 'asset inputs:file = @c.png@ (colorSpace = "acescg")')
    else:
        text = USD_IMAGE.replace("INTERFACE", '(colorSpace = "acescg")').replace(
            "FILE", "asset inputs:file.connect = </World/M.inputs:tex>")
    scene, m = one(stage(tmp_path, None, "/World/M", text))
    assert scene.warnings == []
    rgb = ACESCG_TO_REC709 @ (np.array(ACES_TEXELS) / 255.0)
    texel = scene.textures[m.base_color_texture.texture].image[0, 0, :3]
    assert texel.tolist() == np.round(srgb_encode(rgb) * 255).tolist()
    np.testing.assert_allclose(m.specular_color, ACESCG_TO_REC709 @ (0.5, 0.4, 0.3), atol=1e-6)


def test_image_file_from_a_nodegraph_interface_input_takes_its_colorspace(tmp_path):
    """A nodegraph's filename input declared acescg, read by an image inside through
    interfacename: the image is converted from acescg (the document says lin_rec709)."""
    Image.new("RGB", (4, 4), ACES_TEXELS).save(tmp_path / "c.png")
    body = """
    <nodegraph name="NG">
      <input name="tex" type="filename" value="c.png" colorspace="acescg"/>
      <image name="img" type="color3"><input name="file" type="filename" interfacename="tex"/>
      </image>
      <output name="out" type="color3" nodename="img"/>
    </nodegraph>""" + surface("standard_surface", '<input name="base" type="float" value="1"/>'
                                                  '<input name="base_color" type="color3" '
                                                  'nodegraph="NG" output="out"/>')
    path = stage(tmp_path, "", "/World/mtl/M")
    (tmp_path / "look.mtlx").write_text(f'<?xml version="1.0"?>\n<materialx version="1.38" '
                                        f'colorspace="lin_rec709">\n{body}\n</materialx>\n')
    scene, m = one(path)
    assert scene.warnings == []
    rgb = ACESCG_TO_REC709 @ (np.array(ACES_TEXELS) / 255.0)
    texel = scene.textures[m.base_color_texture.texture].image[0, 0, :3]
    assert texel.tolist() == np.round(srgb_encode(rgb) * 255).tolist()


def test_rec2020_from_usd_names_matches_the_published_matrix():
    """lin_rec2020_scene (a USD name, no cmlib transform): ITU-R BT.2087's Rec.2020 -> Rec.709
    matrix, to its 4 printed digits."""
    bt2087 = np.array([[1.6605, -0.5876, -0.0728],
                       [-0.1246, 1.1329, -0.0083],
                       [-0.0182, -0.1006, 1.1187]])
    space = colorspaces.lookup("lin_rec2020_scene")
    np.testing.assert_allclose(colorspaces.to_working(np.eye(3), space).T, bt2087, atol=1e-4)
