"""MaterialX: .mtlx documents referenced from USD and UsdShade networks with MaterialX node ids
become the scene's Material (values, textures, transforms, warnings) and render like the
equivalent UsdPreviewSurface."""
from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image
from test_render_physics import constant_env

from core.errors import AssetError
from core.options import RenderOptions
from core.scene import TextureRef
from pipeline.bake import bake_asset
from pipeline.ingest import load_scene
from pipeline.usd.materialx import gltf_transform
from renderer.raster.render import render

QUAD = """
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
        uniform token subdivisionScheme = "none"
"""


def stage(folder, mtlx: str | None, binding: str, materials: str = "", name="quad.usda"):
    """A quad bound to `binding`; `mtlx` (a document body) written beside it and referenced."""
    folder.mkdir(parents=True, exist_ok=True)
    ref = ""
    if mtlx is not None:
        (folder / "look.mtlx").write_text(f'<?xml version="1.0"?>\n<materialx version="1.38">\n'
                                          f'{mtlx}\n</materialx>\n')
        ref = 'def Scope "mtl" ( prepend references = @./look.mtlx@</MaterialX/Materials> ) {}'
    path = folder / name
    path.write_text(f"""#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{{
    {ref}
    {materials}
    def Mesh "quad" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {{
{QUAD}
        rel material:binding = <{binding}>
    }}
}}
""")
    return path


def surface(category: str, inputs: str, name="M") -> str:
    return (f'<{category} name="{name}_S" type="surfaceshader">{inputs}</{category}>\n'
            f'<surfacematerial name="{name}" type="material">'
            f'<input name="surfaceshader" type="surfaceshader" nodename="{name}_S"/></surfacematerial>')


def quadrants_png(path):
    """4 x 4: red | green over blue | white (row 0 at the top)."""
    img = np.zeros((4, 4, 3), np.uint8)
    img[:2, :2], img[:2, 2:], img[2:, :2], img[2:, 2:] = (255, 0, 0), (0, 255, 0), (0, 0, 255), 255
    Image.fromarray(img).save(path)
    return path


def one(path):
    scene = load_scene(path)
    assert len(scene.materials) == 1
    return scene, scene.materials[0]


def test_standard_surface_values(tmp_path):
    doc = surface("standard_surface", """
        <input name="base" type="float" value="0.5"/>
        <input name="base_color" type="color3" value="0.8, 0.4, 0.2"/>
        <input name="metalness" type="float" value="0.25"/>
        <input name="specular" type="float" value="0.7"/>
        <input name="specular_color" type="color3" value="1, 0.9, 0.8"/>
        <input name="specular_roughness" type="float" value="0.35"/>
        <input name="specular_IOR" type="float" value="1.45"/>
        <input name="coat" type="float" value="0.6"/>
        <input name="coat_roughness" type="float" value="0.15"/>
        <input name="sheen" type="float" value="0.5"/>
        <input name="sheen_color" type="color3" value="0.2, 0.4, 0.6"/>
        <input name="thin_film_thickness" type="float" value="350"/>
        <input name="thin_film_IOR" type="float" value="1.33"/>
        <input name="emission" type="float" value="2"/>
        <input name="emission_color" type="color3" value="1, 0.5, 0"/>
        <input name="opacity" type="color3" value="0.5, 0.5, 0.5"/>""")
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    np.testing.assert_allclose(m.base_color, (0.4, 0.2, 0.1, 0.5), atol=1e-6)
    assert m.alpha_mode == "BLEND"
    assert (m.metallic, m.roughness) == pytest.approx((0.25, 0.35))
    assert (m.specular, m.ior) == pytest.approx((0.7, 1.45))
    np.testing.assert_allclose(m.specular_color, (1, 0.9, 0.8), atol=1e-6)
    assert (m.clearcoat, m.clearcoat_roughness) == pytest.approx((0.6, 0.15))
    np.testing.assert_allclose(m.sheen_color, (0.1, 0.2, 0.3), atol=1e-6)
    assert m.iridescence == 1 and m.iridescence_thickness_range == pytest.approx((350, 350))
    assert m.iridescence_ior == pytest.approx(1.33)
    np.testing.assert_allclose(m.emissive, (1, 0.5, 0), atol=1e-6)
    assert m.emissive_strength == pytest.approx(2)
    assert m.name == "/World/mtl/M"
    assert not any(".mtlx" in w for w in scene.warnings), scene.warnings


def test_open_pbr_with_images_place2d_and_folded_constants(tmp_path):
    quadrants_png(tmp_path / "q.png")
    Image.new("L", (4, 4), 128).save(tmp_path / "rough.png")
    doc = """
    <nodegraph name="NG">
      <texcoord name="uv" type="vector2"/>
      <place2d name="p" type="vector2">
        <input name="texcoord" type="vector2" nodename="uv"/>
        <input name="scale" type="vector2" value="0.5, 0.5"/>
        <input name="offset" type="vector2" value="0.25, 0"/>
      </place2d>
      <image name="color" type="color3">
        <input name="file" type="filename" value="q.png" colorspace="srgb_texture"/>
        <input name="texcoord" type="vector2" nodename="p"/>
      </image>
      <constant name="k" type="color3"><input name="value" type="color3" value="0.5, 1, 1"/></constant>
      <multiply name="tint" type="color3">
        <input name="in1" type="color3" nodename="color"/>
        <input name="in2" type="color3" nodename="k"/>
      </multiply>
      <tiledimage name="rough" type="float">
        <input name="file" type="filename" value="rough.png"/>
        <input name="uvtiling" type="vector2" value="2, 2"/>
      </tiledimage>
      <noise2d name="wobble" type="float"/>
      <output name="base_out" type="color3" nodename="tint"/>
      <output name="rough_out" type="float" nodename="rough"/>
      <output name="metal_out" type="float" nodename="wobble"/>
    </nodegraph>
    """ + surface("open_pbr_surface", """
        <input name="base_color" type="color3" nodegraph="NG" output="base_out"/>
        <input name="specular_roughness" type="float" nodegraph="NG" output="rough_out"/>
        <input name="base_metalness" type="float" nodegraph="NG" output="metal_out"/>
        <input name="coat_weight" type="float" value="1"/>
        <input name="fuzz_weight" type="float" value="1"/>
        <input name="fuzz_color" type="color3" value="0.3, 0.2, 0.1"/>
        <input name="thin_film_weight" type="float" value="1"/>
        <input name="thin_film_thickness" type="float" value="0.4"/>""")
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    np.testing.assert_allclose(m.base_color[:3], (0.5, 1, 1), atol=1e-6)  # texture x constant k
    assert m.base_color_texture is not None and m.metallic_roughness_texture is not None
    assert m.roughness == pytest.approx(1.0) and m.metallic == pytest.approx(0.0)  # noise: default
    assert any("'NG/wobble' (noise2d)" in w for w in scene.warnings), scene.warnings
    assert m.clearcoat == 1 and m.sheen_color == pytest.approx((0.3, 0.2, 0.1))
    assert m.iridescence_thickness_range == pytest.approx((400, 400))  # µm -> nm
    # place2d (MaterialX order: scale, rotate, then offset): st / scale - offset, the same
    # lookup in glTF UVs through TextureRef
    ref = m.base_color_texture
    rng = np.random.default_rng(1)
    st = rng.random((20, 2))
    want = st / 0.5 - [0.25, 0]
    uv = np.c_[st[:, 0], 1 - st[:, 1], np.ones(20)] @ ref.uv_matrix().T
    np.testing.assert_allclose(np.c_[uv[:, 0], 1 - uv[:, 1]], want, atol=1e-5)
    # tiledimage: st * 2
    mr = m.metallic_roughness_texture
    assert mr.scale == pytest.approx((2, 2))
    assert scene.textures[mr.texture].image[..., 1].max() == 128  # grey in the roughness channel


def test_gltf_pbr_with_normal_map_and_mask(tmp_path):
    Image.new("RGB", (4, 4), (128, 128, 255)).save(tmp_path / "n.png")
    doc = """
    <image name="nimg" type="vector3"><input name="file" type="filename" value="n.png"/></image>
    <normalmap name="nmap" type="vector3">
      <input name="in" type="vector3" nodename="nimg"/>
      <input name="scale" type="float" value="0.5"/>
    </normalmap>
    """ + surface("gltf_pbr", """
        <input name="base_color" type="color3" value="0.1, 0.6, 0.2"/>
        <input name="metallic" type="float" value="0"/>
        <input name="roughness" type="float" value="0.5"/>
        <input name="normal" type="vector3" nodename="nmap"/>
        <input name="alpha" type="float" value="0.3"/>
        <input name="alpha_mode" type="integer" value="1"/>
        <input name="alpha_cutoff" type="float" value="0.25"/>
        <input name="clearcoat" type="float" value="0.5"/>
        <input name="transmission" type="float" value="0.4"/>""")
    _, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    np.testing.assert_allclose(m.base_color, (0.1, 0.6, 0.2, 0.3), atol=1e-6)
    assert (m.metallic, m.roughness, m.clearcoat, m.transmission) == pytest.approx((0, 0.5, 0.5, 0.4))
    assert m.alpha_mode == "MASK" and m.alpha_cutoff == pytest.approx(0.25)
    assert m.normal_texture is not None and m.normal_scale == pytest.approx(0.5)


def test_materialx_node_ids_authored_in_usd(tmp_path):
    quadrants_png(tmp_path / "q.png")
    materials = """
    def Material "M"
    {
        token outputs:mtlx:surface.connect = </World/M/S.outputs:out>
        def Shader "S"
        {
            uniform token info:id = "ND_standard_surface_surfaceshader"
            color3f inputs:base_color.connect = </World/M/NG.outputs:c>
            float inputs:metalness = 0.5
            float inputs:coat = 0.25
            token outputs:out
        }
        def NodeGraph "NG"
        {
            color3f outputs:c.connect = </World/M/NG/img.outputs:out>
            def Shader "img"
            {
                uniform token info:id = "ND_image_color3"
                asset inputs:file = @q.png@
                float2 inputs:texcoord.connect = </World/M/NG/uv.outputs:out>
                color3f outputs:out
            }
            def Shader "uv"
            {
                uniform token info:id = "ND_texcoord_vector2"
                float2 outputs:out
            }
        }
    }
    """
    scene, m = one(stage(tmp_path, None, "/World/M", materials))
    assert m.base_color_texture is not None and m.metallic == pytest.approx(0.5)
    assert m.clearcoat == pytest.approx(0.25)
    np.testing.assert_allclose(m.base_color[:3], (1, 1, 1), atol=1e-6)  # base 1 x texture
    assert scene.textures[m.base_color_texture.texture].source.endswith("q.png")


def test_missing_texture_and_unknown_material_are_warnings(tmp_path):
    doc = """
    <image name="img" type="color3">
      <input name="file" type="filename" value="gone.png"/>
      <input name="default" type="color3" value="0, 0.5, 0"/>
    </image>""" + surface("standard_surface", '<input name="base_color" type="color3" nodename="img"/>')
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    assert m.base_color_texture is None
    np.testing.assert_allclose(m.base_color[:3], (0, 0.5, 0), atol=1e-6)  # the image default
    assert any("gone.png" in w for w in scene.warnings)
    scene, m = one(stage(tmp_path / "b", doc, "/World/mtl/Nope"))
    assert any("no surfacematerial 'Nope'" in w for w in scene.warnings), scene.warnings


def test_mtlx_texture_outside_the_root_is_refused(tmp_path):
    quadrants_png(tmp_path / "q.png")
    doc = """<image name="img" type="color3"><input name="file" type="filename" value="../q.png"/>
    </image>""" + surface("standard_surface", '<input name="base_color" type="color3" nodename="img"/>')
    with pytest.raises(AssetError, match="leaves the root"):
        load_scene(stage(tmp_path / "lib", doc, "/World/mtl/M"))


def test_texture_coordinate_test_materialx_matches_preview_surface(assets, tmp_path):
    folder = assets / "usd/TextureCoordinateTest"
    mx = load_scene(folder / "TextureCoordinateTestMaterialX.usda")
    ps = load_scene(folder / "TextureCoordinateTest.usda")
    assert mx.triangle_count == ps.triangle_count == 10
    # usd-core cannot compose the .mtlx reference (no usdMtlx file format: "Cannot determine
    # file format"); the document is read here instead, and its lin_rec709 image honoured
    assert mx.warnings == [], mx.warnings
    by_mesh = lambda s: {m.name.rsplit("/", 1)[-1]: s.materials[i.material]  # noqa: E731
                         for i in s.instances for m in [s.meshes[i.mesh]]}
    a, b = by_mesh(mx), by_mesh(ps)
    assert a.keys() == b.keys()
    for name in a:
        assert (a[name].base_color_texture is None) == (b[name].base_color_texture is None), name
    # Drawn alike: each quad shows its corner of the template where the UsdPreviewSurface
    # version shows it (texcoord reads `st`; the preview surface's reader names `st0`). The
    # preview version tints each quad (UsdUVTexture scale), the .mtlx does not, so compare
    # the pattern: luminance correlates within each image quadrant.
    a, b = (_render(folder / f, tmp_path) for f in ("TextureCoordinateTestMaterialX.usda",
                                                    "TextureCoordinateTest.usda"))
    assert np.array_equal(a[..., 3] > 0.5, b[..., 3] > 0.5)
    for y in (slice(0, 32), slice(32, 64)):
        for x in (slice(0, 32), slice(32, 64)):
            la, lb = a[y, x, :3].sum(-1).ravel(), b[y, x, :3].sum(-1).ravel()
            assert np.corrcoef(la, lb)[0, 1] > 0.8


def test_gltf_transform_round_trips_rotation_and_scale():
    t = math.radians(30)
    c, s = math.cos(t), math.sin(t)
    m_st = np.array([[2 * c, 3 * s, 0.1], [-2 * s, 3 * c, 0.2], [0, 0, 1]])
    offset, rotation, scale = gltf_transform(m_st)
    ref = TextureRef(0, 0, offset, rotation, scale)
    st = np.random.default_rng(0).random((10, 2))
    want = np.c_[st, np.ones(10)] @ m_st.T
    got = np.c_[st[:, 0], 1 - st[:, 1], np.ones(10)] @ ref.uv_matrix().T
    np.testing.assert_allclose(np.c_[got[:, 0], 1 - got[:, 1]], want[:, :2], atol=1e-6)


# -- renders --------------------------------------------------------------------------------------
def _render(path, tmp_path):
    asset = bake_asset(path, tmp_path / "cache")
    opts = RenderOptions(width=64, height=64, yaw=0, pitch=0, tonemap="none",
                         background="transparent", msaa=0, shadow=0)  # alpha: the object only
    return render(asset, constant_env(1.0), opts).linear


PREVIEW = """
    def Material "P"
    {{
        token outputs:surface.connect = </World/P/S.outputs:surface>
        def Shader "S"
        {{
            uniform token info:id = "UsdPreviewSurface"
            {inputs}
            token outputs:surface
        }}
        {extra}
    }}
"""


@pytest.mark.parametrize("category, inputs", [
    ("standard_surface", '<input name="base_color" type="color3" value="0.7, 0.1, 0.05"/>'
                         '<input name="specular_roughness" type="float" value="0.6"/>'),
    ("open_pbr_surface", '<input name="base_color" type="color3" value="0.7, 0.1, 0.05"/>'
                         '<input name="specular_roughness" type="float" value="0.6"/>'),
    ("gltf_pbr", '<input name="base_color" type="color3" value="0.7, 0.1, 0.05"/>'
                 '<input name="metallic" type="float" value="0"/>'
                 '<input name="roughness" type="float" value="0.6"/>'),
])
def test_render_mean_colour_matches_preview_surface(tmp_path, category, inputs):
    mx = _render(stage(tmp_path / "mx", surface(category, inputs), "/World/mtl/M"), tmp_path)
    preview = PREVIEW.format(inputs='color3f inputs:diffuseColor = (0.7, 0.1, 0.05)\n'
                                    'float inputs:roughness = 0.6', extra="")
    ps = _render(stage(tmp_path / "ps", None, "/World/P", preview), tmp_path)
    covered = mx[..., 3] > 0.5
    assert covered.mean() > 0.3 and np.array_equal(covered, ps[..., 3] > 0.5)
    mean_mx, mean_ps = mx[covered, :3].mean(0), ps[covered, :3].mean(0)
    assert mean_mx[0] > 2 * mean_mx[1]  # red
    np.testing.assert_allclose(mean_mx, mean_ps, atol=0.01)


def test_render_of_an_image_node_matches_preview_surface_texture(tmp_path):
    """Orientation: a MaterialX image shows its quadrants where UsdUVTexture shows them."""
    for sub in ("mx", "ps"):
        (tmp_path / sub).mkdir()
        quadrants_png(tmp_path / sub / "q.png")
    doc = ('<image name="img" type="color3"><input name="file" type="filename" value="q.png"/>'
           '<input name="texcoord" type="vector2" nodename="uv"/></image>'
           '<texcoord name="uv" type="vector2"/>'
           + surface("standard_surface", '<input name="base_color" type="color3" nodename="img"/>'))
    mx = _render(stage(tmp_path / "mx", doc, "/World/mtl/M"), tmp_path)
    preview = PREVIEW.format(inputs='color3f inputs:diffuseColor.connect = </World/P/T.outputs:rgb>\n'
                                    'float inputs:roughness = 0.2', extra="""
        def Shader "T"
        {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @q.png@
            float2 inputs:st.connect = </World/P/R.outputs:result>
            float3 outputs:rgb
        }
        def Shader "R"
        {
            uniform token info:id = "UsdPrimvarReader_float2"
            string inputs:varname = "st"
            float2 outputs:result
        }""")
    ps = _render(stage(tmp_path / "ps", None, "/World/P", preview), tmp_path)
    q = 16
    for y, x in ((q, q), (q, 3 * q), (3 * q, q), (3 * q, 3 * q)):
        a, b = mx[y, x, :3], ps[y, x, :3]
        assert np.argmax(a) == np.argmax(b) and np.allclose(a, b, atol=0.05), (y, x, a, b)
    assert np.argmax(mx[q, q, :3]) == 0  # red at the top left, as the image


def test_several_documents_each_material_found(tmp_path):
    """Two .mtlx documents referenced on one prim: each material is looked up in the document
    that defines it, whatever the reference order."""
    for name, doc in (("plastic", surface("standard_surface", '<input name="base_color" '
                                          'type="color3" value="0.1, 0.2, 0.9"/>', "blue")),
                      ("metal", surface("standard_surface", '<input name="base_color" '
                                        'type="color3" value="1, 0.8, 0.3"/><input '
                                        'name="metalness" type="float" value="1"/>', "gold"))):
        (tmp_path / f"{name}.mtlx").write_text(f'<?xml version="1.0"?>\n<materialx '
                                               f'version="1.38">\n{doc}\n</materialx>\n')
    refs = ('def Scope "mtl" ( prepend references = [@./plastic.mtlx@</MaterialX/Materials>, '
            '@./metal.mtlx@</MaterialX/Materials>] ) {}')
    for binding, colour, metallic in (("/World/mtl/gold", (1, 0.8, 0.3), 1.0),
                                      ("/World/mtl/blue", (0.1, 0.2, 0.9), 0.0)):
        path = tmp_path / "quad.usda"
        stage(tmp_path, None, binding, materials=refs)
        scene, m = one(path)
        assert not any("fallback" in w for w in scene.warnings), scene.warnings
        np.testing.assert_allclose(m.base_color[:3], colour, atol=1e-6)
        assert m.metallic == pytest.approx(metallic)


# -- MaterialX's UsdPreviewSurface node (ND_UsdPreviewSurface_surfaceshader) ------------------

def test_usd_preview_surface_node_with_nodegraph_outputs(tmp_path):
    """usd-wg MaterialXTest's `UsdPreviewSurface` node: its inputs, fed by a nodegraph's
    outputs (an image, a folded multiply), read as the UsdShade UsdPreviewSurface is."""
    quadrants_png(tmp_path / "q.png")
    doc = """
    <nodegraph name="NG">
      <image name="img" type="color3"><input name="file" type="filename" value="q.png"/></image>
      <constant name="r" type="float"><input name="value" type="float" value="0.2"/></constant>
      <multiply name="r2" type="float"><input name="in1" type="float" nodename="r"/>
        <input name="in2" type="float" value="2"/></multiply>
      <output name="base_out" type="color3" nodename="img"/>
      <output name="rough_out" type="float" nodename="r2"/>
    </nodegraph>
    """ + surface("UsdPreviewSurface", """
      <input name="diffuseColor" type="color3" nodegraph="NG" output="base_out"/>
      <input name="roughness" type="float" nodegraph="NG" output="rough_out"/>
      <input name="metallic" type="float" value="0.75"/>
      <input name="emissiveColor" type="color3" value="0.1, 0.2, 0.3"/>
      <input name="clearcoat" type="float" value="0.5"/>
    """)
    scene, m = one(stage(tmp_path, doc, "/World/mtl/M"))
    assert not [w for w in scene.warnings if "fallback" in w or "not read" in w], scene.warnings
    assert m.base_color_texture is not None
    assert scene.textures[m.base_color_texture.texture].source.endswith("q.png")
    assert m.roughness == pytest.approx(0.4) and m.metallic == pytest.approx(0.75)
    np.testing.assert_allclose(m.emissive, (0.1, 0.2, 0.3), atol=1e-6)
    assert m.clearcoat == pytest.approx(0.5) and m.clearcoat_roughness == pytest.approx(0.01)
    assert m.alpha_mode == "OPAQUE" and m.transmission == 0


def test_usd_preview_surface_node_defaults_opacity_and_specular(tmp_path):
    """Unauthored inputs take the node definition's defaults (diffuse 0.18, roughness 0.5,
    metallic 0); opacity as the UsdShade reader reads it; the specular workflow."""
    doc = "\n".join([
        surface("UsdPreviewSurface", "", name="Plain"),
        surface("UsdPreviewSurface", '<input name="opacity" type="float" value="0.2"/>'
                                     '<input name="ior" type="float" value="1.45"/>', name="Glass"),
        surface("UsdPreviewSurface", '<input name="opacity" type="float" value="0.3"/>', name="Fade"),
        surface("UsdPreviewSurface", '<input name="opacity" type="float" value="0.8"/>'
                                     '<input name="opacityThreshold" type="float" value="0.5"/>',
                name="Cut"),
        surface("UsdPreviewSurface", '<input name="useSpecularWorkflow" type="integer" value="1"/>'
                                     '<input name="specularColor" type="color3" value="0.04, 0.2, 0.04"/>'
                                     '<input name="metallic" type="float" value="1"/>', name="Spec"),
    ])
    got = {}
    for name in ("Plain", "Glass", "Fade", "Cut", "Spec"):
        _, got[name] = one(stage(tmp_path / name, doc, f"/World/mtl/{name}"))
    plain = got["Plain"]
    np.testing.assert_allclose(plain.base_color, (0.18, 0.18, 0.18, 1.0), atol=1e-6)
    assert plain.roughness == pytest.approx(0.5) and plain.metallic == 0 and plain.ior == 1.5
    assert got["Glass"].transmission == pytest.approx(0.8) and got["Glass"].alpha_mode == "OPAQUE"
    assert got["Glass"].ior == pytest.approx(1.45)
    assert got["Fade"].alpha_mode == "BLEND" and got["Fade"].base_color[3] == pytest.approx(0.3)
    assert got["Cut"].alpha_mode == "MASK" and got["Cut"].alpha_cutoff == pytest.approx(0.5)
    spec = got["Spec"]
    assert spec.metallic == 0 and spec.specular == 1
    np.testing.assert_allclose(np.array(spec.specular_color) * 0.04, (0.04, 0.2, 0.04), atol=1e-6)


def test_usd_preview_surface_node_id_authored_in_usd_renders_as_preview_surface(tmp_path):
    """info:id ND_UsdPreviewSurface_surfaceshader on outputs:mtlx:surface renders as the
    UsdShade UsdPreviewSurface with the same inputs (usd-wg MaterialXTest drew grey here)."""
    materials = """
    def Material "M"
    {
        token outputs:mtlx:surface.connect = </World/M/S.outputs:out>
        def Shader "S"
        {
            uniform token info:id = "ND_UsdPreviewSurface_surfaceshader"
            color3f inputs:diffuseColor = (0.1047, 0.2419, 0.818)
            float inputs:roughness = 0.3247
            token outputs:out
        }
    }
    """
    mx = _render(stage(tmp_path / "mx", None, "/World/M", materials), tmp_path)
    preview = PREVIEW.format(inputs='color3f inputs:diffuseColor = (0.1047, 0.2419, 0.818)\n'
                                    'float inputs:roughness = 0.3247', extra="")
    ps = _render(stage(tmp_path / "ps", None, "/World/P", preview), tmp_path)
    covered = mx[..., 3] > 0.5
    assert covered.mean() > 0.3 and np.array_equal(covered, ps[..., 3] > 0.5)
    mean_mx, mean_ps = mx[covered, :3].mean(0), ps[covered, :3].mean(0)
    assert mean_mx[2] > 2 * mean_mx[0]  # blue plastic, not the fallback grey
    np.testing.assert_allclose(mean_mx, mean_ps, atol=0.01)


def test_coat_colour_tints_the_base_under_it(tmp_path):
    """standard_surface / OpenPBR: coat_color tints what lies under the coat, mixed in by the
    coat's weight (usd-wg's tiled brass: a white metal under a brass-coloured coat, usdview's
    screenshot gold). Constant: base x mix(1, coat_color, weight); from an image: that image
    becomes the base colour texture of an untextured base."""
    doc = surface("standard_surface", """
        <input name="base_color" type="color3" value="1, 1, 1"/>
        <input name="metalness" type="float" value="1"/>
        <input name="coat" type="float" value="0.5"/>
        <input name="coat_color" type="color3" value="0.8, 0.6, 0.2"/>""")
    _, mat = one(stage(tmp_path / "a", doc, "/World/mtl/M"))
    np.testing.assert_allclose(mat.base_color[:3], (0.9, 0.8, 0.6), atol=1e-6)
    (tmp_path / "b").mkdir()
    quadrants_png(tmp_path / "b" / "coat.png")
    doc = ('<nodegraph name="NG"><image name="img" type="color3">'
           '<input name="file" type="filename" value="coat.png"/></image>'
           '<output name="out" type="color3" nodename="img"/></nodegraph>') + surface("open_pbr_surface", """
        <input name="base_color" type="color3" value="1, 1, 1"/>
        <input name="base_metalness" type="float" value="1"/>
        <input name="coat_weight" type="float" value="1"/>
        <input name="coat_color" type="color3" nodegraph="NG" output="out"/>""")
    scene, mat = one(stage(tmp_path / "b", doc, "/World/mtl/M"))
    assert mat.base_color_texture is not None
    assert scene.textures[mat.base_color_texture.texture].source.endswith("coat.png")
    np.testing.assert_allclose(mat.base_color[:3], (1, 1, 1))
    # no coat: the coat colour says nothing
    doc = surface("standard_surface", """
        <input name="base_color" type="color3" value="0.5, 0.5, 0.5"/>
        <input name="coat_color" type="color3" value="1, 0, 0"/>""")
    _, mat = one(stage(tmp_path / "c", doc, "/World/mtl/M"))
    np.testing.assert_allclose(mat.base_color[:3], (0.5, 0.5, 0.5), atol=1e-6)


def test_declared_colorspaces_are_honoured_without_warnings(tmp_path):
    """usdview's Storm loads MaterialX images raw and converts each from its declared
    colorspace (an input's, else the document's), so a colour image in a lin_rec709
    document holds linear values, and an srgb_texture roughness image is linearised. Each
    texture is re-encoded for the slot that reads it, with no warning; the render matches
    a UsdPreviewSurface reading the same file with sourceColorSpace "raw"."""
    for sub in ("mx", "ps"):
        (tmp_path / sub).mkdir()
        Image.new("RGB", (4, 4), (128, 128, 128)).save(tmp_path / sub / "grey.png")
    body = ('<image name="img" type="color3"><input name="file" type="filename" value="grey.png"/>'
            '</image><image name="r" type="float"><input name="file" type="filename" '
            'value="grey.png" colorspace="srgb_texture"/></image>'
            + surface("standard_surface", '<input name="base_color" type="color3" nodename="img"/>'
                                          '<input name="specular_roughness" type="float" '
                                          'nodename="r"/>'))
    path = stage(tmp_path / "mx", "", "/World/mtl/M")
    (tmp_path / "mx" / "look.mtlx").write_text(  # the document's colorspace, inherited
        f'<?xml version="1.0"?>\n<materialx version="1.38" colorspace="lin_rec709">\n{body}\n'
        '</materialx>\n')
    scene, m = one(path)
    assert scene.warnings == [], scene.warnings
    base = scene.textures[m.base_color_texture.texture].image
    rough = scene.textures[m.metallic_roughness_texture.texture].image
    # the base colour slot decodes sRGB: linear 128/255 stored sRGB-encoded (188), which
    # decodes back within half an 8-bit step; the roughness slot reads srgb(128) = 0.216 raw
    assert base[0, 0, :3].tolist() == [188, 188, 188]
    assert rough[0, 0, 1] == 55
    mx = _render(path, tmp_path)
    preview = PREVIEW.format(inputs='color3f inputs:diffuseColor.connect = </World/P/T.outputs:rgb>\n'
                                    'float inputs:roughness = 0.2158605', extra="""
        def Shader "T"
        {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @grey.png@
            token inputs:sourceColorSpace = "raw"
            float3 outputs:rgb
        }""")
    ps = _render(stage(tmp_path / "ps", None, "/World/P", preview), tmp_path)
    covered = mx[..., 3] > 0.5
    assert covered.mean() > 0.3 and np.array_equal(covered, ps[..., 3] > 0.5)
    np.testing.assert_allclose(mx[covered, :3].mean(0), ps[covered, :3].mean(0), atol=0.01)
