"""USD ingest: sample assets against an independent pxr traversal, generated stages for each
feature, and hostile files that must be refused with the documented error."""
from __future__ import annotations

import math
import os
import shutil
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from pxr import Sdf, Usd, UsdGeom, UsdUtils

from core.colour import srgb_to_linear
from core.errors import AssetError, LimitExceeded, MalformedAsset, MissingFile, UnsafeReference
from pipeline.ingest import load_scene
from pipeline.limits import Limits

USD_SUFFIXES = {".usd", ".usda", ".usdc", ".usdz"}


def usd_samples(root: Path) -> list[Path]:
    return sorted(p for p in (root / "usd").rglob("*") if p.suffix in USD_SUFFIXES)


def rendered_triangles(path: Path) -> int:
    """Triangles as rendered, counted straight from pxr: every visible, render/default-purpose
    Mesh (instance proxies included), sum of faceVertexCounts - 2 over faces not holes."""
    stage = Usd.Stage.Open(str(path))
    total = 0
    for prim in Usd.PrimRange(stage.GetPseudoRoot(),
                              Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        img = UsdGeom.Imageable(prim)
        if img.ComputeVisibility() == UsdGeom.Tokens.invisible or \
                img.ComputePurpose() not in (UsdGeom.Tokens.default_, UsdGeom.Tokens.render):
            continue
        mesh = UsdGeom.Mesh(prim)
        counts = list(mesh.GetFaceVertexCountsAttr().Get() or [])
        holes = set(mesh.GetHoleIndicesAttr().Get() or [])
        total += sum(max(c - 2, 0) for f, c in enumerate(counts) if f not in holes)
    return total


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("#usda 1.0\n" + text)
    return path


def png(path: Path, rgba: tuple[int, int, int, int] = (255, 0, 0, 255), size=(4, 2)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGBA", size, rgba).save(path)
    return path


QUAD = """
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
"""


def material(name: str, inputs: str, extra: str = "") -> str:
    return f"""
def Material "{name}"
{{
    token outputs:surface.connect = </{name}/S.outputs:surface>
    def Shader "S"
    {{
        uniform token info:id = "UsdPreviewSurface"
        {inputs}
        token outputs:surface
    }}
    {extra}
}}
"""


def mesh(name: str, body: str = QUAD, binding: str | None = None, meta: str = "") -> str:
    bind = f'rel material:binding = </{binding}>' if binding else ""
    api = 'prepend apiSchemas = ["MaterialBindingAPI"]' if binding else ""
    return f"""
def Mesh "{name}" (
    {api}
    {meta}
)
{{
    uniform token subdivisionScheme = "none"
    {body}
    {bind}
}}
"""


# -- the sample assets --------------------------------------------------------------------------
def test_every_usd_sample_loads_with_pxr_triangle_count(assets):
    samples = usd_samples(assets)
    assert len(samples) >= 8
    for path in samples:
        scene = load_scene(path, draw_mode="full")  # every mesh, not draw-mode stand-ins
        assert scene.triangle_count == rendered_triangles(path) > 0, path
        assert np.all(np.isfinite(scene.bounds)), path
        assert all(Path(f).is_file() and Path(f).resolve().is_relative_to(path.parent.resolve())
                   for f in scene.files), (path, scene.files)


def test_teapot_payload_and_variants_resolve(assets):
    path = assets / "usd/Teapot/Teapot.usd"
    scene = load_scene(path)
    # modelVariant Utah (through the payload), shadingVariant CeramicLimeGreen
    assert scene.triangle_count == 2472
    assert [m.name for m in scene.meshes] == ["/Teapot/Geometry"]
    assert len(scene.materials) == 1 and len(scene.textures) == 0
    mat = scene.materials[0]
    assert mat.name == "/Teapot/Materials/Ceramic"
    assert mat.roughness == pytest.approx(0.125) and mat.ior == pytest.approx(1.327)
    assert mat.metallic == 0.0 and mat.material_class == "opaque"
    colors = scene.meshes[0].colors  # diffuseColor is read from displayColor
    np.testing.assert_allclose(colors[0], (0.325, 0.825, 0.0, 1.0), atol=1e-6)
    files = {Path(f).name for f in scene.files}
    assert {"Teapot.usd", "Teapot_Payload.usd", "Teapot_Materials.usd", "Teapot_Geometry.usd",
            "UtahTeapot.usd"} <= files
    # smooth normals for the subdivision cage, unit length
    n = scene.meshes[0].normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)


def test_fancy_variant_materials_and_textures(assets):
    # full: the teapots' own geometry and materials, not their draw-mode stand-ins
    scene = load_scene(assets / "usd/Teapot/DrawModes.usd", draw_mode="full")
    assert len(scene.textures) == 2  # diffuse + ARM, shared by every fancy copy
    assert len(scene.materials) == 2  # PorcelainFlowers and Ceramic (equal copies shared)
    fancy = next(m for m in scene.materials if m.name.endswith("PorcelainFlowers"))
    assert fancy.base_color_texture is not None
    # ARM = occlusion R, roughness G, metallic B: glTF's layout, used as it is
    assert fancy.metallic_roughness_texture.texture == fancy.occlusion_texture.texture
    assert fancy.metallic_roughness_texture.texture != fancy.base_color_texture.texture
    assert {Path(t.source).name for t in scene.textures} == {"tea_set_01_diff_2k.jpg",
                                                              "tea_set_01_arm_2k.jpg"}
    assert {"tea_set_01_diff_2k.jpg", "FancyTeapot.usd"} <= {Path(f).name for f in scene.files}


def test_teapot_packaged_as_usdz(assets, tmp_path):
    """A real package made by usd-core's own usdzip: layers and textures read from inside it."""
    work = tmp_path / "Teapot"
    shutil.copytree(assets / "usd/Teapot", work)
    root = write(work / "fancy.usda", '(\n metersPerUnit = 1\n defaultPrim = "F"\n)\n'
                 'def "F" (\n prepend references = @./Teapot.usd@</Teapot>\n'
                 ' variants = {\n string modelVariant = "Fancy"\n }\n) {}\n')
    pkg = tmp_path / "fancy.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root)), str(pkg))
    scene = load_scene(pkg)
    assert scene.triangle_count == rendered_triangles(pkg) == 12144
    assert len(scene.textures) == 2 and scene.textures[0].image.shape == (2048, 2048, 4)
    assert scene.files == [str(pkg.resolve())]


def test_texture_coordinate_test(assets):
    scene = load_scene(assets / "usd/TextureCoordinateTest/TextureCoordinateTest.usda")
    assert len(scene.meshes) == 5 and len(scene.materials) == 5 and len(scene.textures) == 1
    by_name = {m.name.rsplit("/", 1)[-1]: m for m in scene.materials}
    # UsdUVTexture scale (0, .16, .8, 1) becomes the base colour factor
    np.testing.assert_allclose(by_name["BottomLeftMat"].base_color, (0, 0.16, 0.8, 1), atol=1e-6)
    assert all(m.double_sided for m in scene.materials)
    # primvar "st0" is the one the material's reader names; v is flipped to glTF's convention
    stage = Usd.Stage.Open(str(assets / "usd/TextureCoordinateTest/TextureCoordinateTest.usda"))
    prim = stage.GetPrimAtPath("/Asset/Scenes/Scene/TopLeftObj/TopLeftMesh/submesh")
    st = np.array(UsdGeom.PrimvarsAPI(prim).GetPrimvar("st0").ComputeFlattened())
    mesh = next(m for m in scene.meshes if m.name == str(prim.GetPath()))
    assert mesh.uv0 is not None
    expected = {(round(s, 5), round(1 - t, 5)) for s, t in st}
    assert {(round(u, 5), round(v, 5)) for u, v in mesh.uv0} == expected


def test_materialx_reference_is_read(assets):
    """The .mtlx document is read with PyMaterialX (tests/test_materialx.py has the details)."""
    path = assets / "usd/TextureCoordinateTest/TextureCoordinateTestMaterialX.usda"
    scene = load_scene(path)
    assert scene.triangle_count == 10
    assert not any("cannot read" in w for w in scene.warnings)
    # one image, read through its linear (lin_rec709) copy: the document declares it linear
    used = {m.base_color_texture.texture for m in scene.materials if m.base_color_texture}
    assert len(used) == 1 and all(t.source.endswith("Template.png") for t in scene.textures)


def test_primvar_interpolations(assets):
    scene = load_scene(assets / "usd/primvar_interpolation.usda")
    meshes = {m.name.rsplit("/", 1)[-1]: m for m in scene.meshes}
    assert len(meshes) == 7
    assert len(meshes["vertex"].positions) == 6  # no split needed
    assert len(meshes["faceVarying"].positions) == 8  # shared edge split
    assert len(meshes["uniform"].positions) == 8
    uniform = meshes["uniform"]
    tri_colors = uniform.colors[uniform.indices[:, 0], :3]
    assert {tuple(np.round(c.astype(float), 3)) for c in tri_colors} == {(1, 0.3, 0.3),
                                                                         (0.3, 0.3, 1)}
    np.testing.assert_allclose(meshes["constant"].colors[:, :3], [[1, 0.3, 0.3]] * 6, atol=1e-6)
    # metersPerUnit 0.01: the 2-unit wide quads are 2 cm wide
    extent = scene.bounds[1] - scene.bounds[0]
    assert extent[0] == pytest.approx(0.04, abs=1e-6)


# -- generated stages, one feature each ---------------------------------------------------------
def test_up_axis_z_and_meters_per_unit(tmp_path):
    path = write(tmp_path / "z.usda", '(\n upAxis = "Z"\n metersPerUnit = 0.5\n)\n' + mesh("M", """
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (2, 0, 0), (0, 0, 4)]
"""))
    scene = load_scene(path)
    inst = scene.instances[0]
    p = scene.meshes[inst.mesh].positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
    # Z up becomes Y up (right-handed: +Y in Z-up is -Z here), in metres
    np.testing.assert_allclose(p, [[0, 0, 0], [1, 0, 0], [0, 2, 0]], atol=1e-6)
    np.testing.assert_allclose(scene.bounds, [[0, 0, 0], [1, 2, 0]], atol=1e-6)


@pytest.mark.parametrize("meters", ["0", "-1", "nan"])
def test_meters_per_unit_must_be_positive(tmp_path, meters):
    path = write(tmp_path / "m.usda", f'(\n metersPerUnit = {meters}\n)\n' + mesh("M"))
    with pytest.raises(MalformedAsset, match="metersPerUnit"):
        load_scene(path)


def test_ngons_left_handed_and_holes(tmp_path):
    poly = """
        int[] faceVertexCounts = [5, 6, 3]
        int[] faceVertexIndices = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 0, 1, 2]
        point3f[] points = [(0,0,0),(2,0,0),(3,1,0),(1,2,0),(-1,1,0),
                            (10,0,0),(11,0,0),(12,1,0),(11,2,0),(10,2,0),(9,1,0)]
        int[] holeIndices = [2]
"""
    right = write(tmp_path / "r.usda", '(\n metersPerUnit = 1\n)\n' + mesh("M", poly))
    left = write(tmp_path / "l.usda", '(\n metersPerUnit = 1\n)\n' + mesh(
        "M", poly + 'uniform token orientation = "leftHanded"'))
    a, b = load_scene(right), load_scene(left)
    assert a.triangle_count == b.triangle_count == 3 + 4  # pentagon + hexagon, hole dropped

    def z_of_normals(scene):
        m = scene.meshes[0]
        p = m.positions[m.indices]
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]
    assert np.all(z_of_normals(a) > 0) and np.all(z_of_normals(b) < 0)
    # the fan covers each polygon exactly (convex here): areas add up
    m = a.meshes[0]
    p = m.positions[m.indices]
    area = 0.5 * np.abs(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]).sum()
    assert area == pytest.approx(5.0 + 4.0)  # shoelace areas


def test_indexed_facevarying_st_and_uniform_normals(tmp_path):
    path = write(tmp_path / "st.usda", '(\n metersPerUnit = 1\n)\n' + mesh("M", QUAD + """
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "faceVarying"
        )
        int[] primvars:st:indices = [0, 1, 2, 3]
        normal3f[] normals = [(0, 0, 1)] (
            interpolation = "uniform"
        )
"""))
    m = load_scene(path).meshes[0]
    np.testing.assert_allclose(m.normals, [[0, 0, 1]] * len(m.positions), atol=1e-6)
    by_pos = {tuple(p[:2]): tuple(uv) for p, uv in zip(m.positions, m.uv0)}
    # USD st (0,0) is the image's bottom-left: glTF (0, 1)
    assert by_pos[(0.0, 0.0)] == (0.0, 1.0) and by_pos[(1.0, 1.0)] == (1.0, 0.0)


def test_geom_subsets_bind_their_own_materials(tmp_path):
    body = """
        int[] faceVertexCounts = [3, 3, 4]
        int[] faceVertexIndices = [0, 1, 2, 0, 2, 3, 4, 5, 6, 7]
        point3f[] points = [(0,0,0),(1,0,0),(1,1,0),(0,1,0),(2,0,0),(3,0,0),(3,1,0),(2,1,0)]
        uniform token subsetFamily:materialBind:familyType = "partition"
        def GeomSubset "red" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [0, 1]
            rel material:binding = </Red>
        }
"""
    text = '(\n metersPerUnit = 1\n)\n' \
        + material("Red", "color3f inputs:diffuseColor = (1, 0, 0)") \
        + material("Blue", "color3f inputs:diffuseColor = (0, 0, 1)") + mesh("M", body, "Blue")
    scene = load_scene(write(tmp_path / "subsets.usda", text))
    assert len(scene.meshes) == 2 and scene.triangle_count == 4
    colours = {scene.materials[i.material].base_color[:3]: scene.meshes[i.mesh].triangle_count
               for i in scene.instances}
    assert colours == {(1.0, 0.0, 0.0): 2, (0.0, 0.0, 1.0): 2}


def test_instancing_visibility_purpose_active(tmp_path):
    write(tmp_path / "part.usda", '(\n defaultPrim = "P"\n)\ndef Xform "P"\n{\n'
          + mesh("M") + "}\n")
    text = '(\n metersPerUnit = 1\n)\n'
    for i in range(3):
        text += f"""
def Xform "I{i}" (
    instanceable = true
    prepend references = @./part.usda@
)
{{
    double3 xformOp:translate = ({i * 2}, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""
    text += mesh("Hidden", meta="").replace("{", '{\n    token visibility = "invisible"', 1)
    text += mesh("Guide").replace("{", '{\n    uniform token purpose = "guide"', 1)
    text += mesh("Off", meta="active = false")
    scene = load_scene(write(tmp_path / "inst.usda", text))
    assert len(scene.meshes) == 1 and len(scene.instances) == 3  # one prototype, three places
    xs = sorted(i.matrix[0, 3] for i in scene.instances)
    assert xs == [0.0, 2.0, 4.0]
    assert scene.triangle_count == 6


def test_implicit_shapes_are_tessellated(tmp_path):
    text = '(\n metersPerUnit = 1\n)\n' + """
def Sphere "S" {
    double radius = 2
    color3f[] primvars:displayColor = [(1, 0, 0)]
}
def Cube "C" {
    double size = 1
}
def Cylinder "Y" {
    double height = 4
    uniform token axis = "X"
}
def Cone "K" {
    double radius = 0.5
    double height = 1
}
def Capsule "P" {
    uniform token axis = "Y"
}
def Plane "L" {
}
def TetMesh "Tet" {
}
"""
    scene = load_scene(write(tmp_path / "shapes.usda", text))
    by = {m.name: m for m in scene.meshes}
    assert set(by) == {"/S", "/C", "/Y", "/K", "/P", "/L"}
    ext = {n: (m.positions.min(axis=0), m.positions.max(axis=0)) for n, m in by.items()}
    np.testing.assert_allclose(ext["/S"][1], [2, 2, 2], atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(by["/S"].positions, axis=1), 2, atol=1e-4)
    np.testing.assert_allclose(by["/S"].colors[:, :3], [[1, 0, 0]] * len(by["/S"].positions))
    np.testing.assert_allclose(ext["/C"][1], [0.5, 0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(ext["/Y"][1], [2, 1, 1], atol=1e-6)  # height along X
    np.testing.assert_allclose([ext["/K"][0][2], ext["/K"][1][2]], [-0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(ext["/P"][1][1], 1.0, atol=1e-6)  # 0.5 + 2 * 0.5 / 2 along Y
    for m in by.values():  # outward winding: positive signed volume for closed shapes
        p = m.positions.astype(float)[m.indices]
        vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
        assert vol > 0 or m.name == "/L", m.name
    assert any("TetMesh" in w and "/Tet" in w for w in scene.warnings)


def test_point_instancer_places_prototypes(tmp_path):
    text = '(\n metersPerUnit = 1\n)\n' + """
def Xform "World" {
    double3 xformOp:translate = (0, 0, 10)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def PointInstancer "PI" {
        point3f[] positions = [(0, 0, 0), (5, 0, 0), (10, 0, 0), (15, 0, 0)]
        float3[] scales = [(1, 1, 1), (2, 2, 2), (1, 1, 1), (1, 1, 1)]
        int[] protoIndices = [0, 1, 0, 1]
        int64[] invisibleIds = [3]
        rel prototypes = [</World/PI/Protos/A>, </World/PI/Protos/B>]
        def Scope "Protos" {
            def Cube "A" {
                double size = 1
                double3 xformOp:translate = (0, 1, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
            def Xform "B" {
                def Sphere "Ball" {
                    double radius = 0.5
                }
            }
        }
    }
}
"""
    scene = load_scene(write(tmp_path / "pi.usda", text))
    assert len(scene.meshes) == 2  # each prototype built once
    placed = sorted((scene.meshes[i.mesh].name, tuple(np.round(i.matrix[:3, 3], 6)),
                     round(float(i.matrix[0, 0]), 6)) for i in scene.instances)
    assert placed == [("/World/PI/Protos/A", (0, 1, 10), 1.0),
                      ("/World/PI/Protos/A", (10, 1, 10), 1.0),
                      ("/World/PI/Protos/B/Ball", (5, 0, 10), 2.0)]  # id 3 is invisible
    assert scene.triangle_count == 2 * 12 + 1280


@pytest.mark.parametrize("inputs, cls, transmission, alpha", [
    ("float inputs:opacity = 0\n float inputs:ior = 1.5", "transmissive", 1.0, 1.0),
    ("float inputs:opacity = 0.25\n float inputs:ior = 1.33", "transmissive", 0.75, 1.0),
    ("float inputs:opacity = 0.5", "blend", 0.0, 0.5),
    ("float inputs:opacity = 0.5\n float inputs:ior = 1.0", "blend", 0.0, 0.5),
    ("float inputs:opacity = 0.3\n float inputs:opacityThreshold = 0.5", "mask", 0.0, 0.3),
    ("float inputs:ior = 1.5", "opaque", 0.0, 1.0),
])
def test_opacity_and_ior_mapping(tmp_path, inputs, cls, transmission, alpha):
    text = '(\n metersPerUnit = 1\n)\n' + material("G", inputs) + mesh("M", binding="G")
    mat = load_scene(write(tmp_path / "glass.usda", text)).materials[0]
    assert mat.material_class == cls
    assert mat.transmission == pytest.approx(transmission)
    assert mat.base_color[3] == pytest.approx(alpha)


def test_factors_outside_0_1_are_clamped(tmp_path):
    """As glTF's factors are: opacity -1 with an ior must not become transmission 2."""
    inputs = ("float inputs:opacity = -1\n float inputs:ior = 1.5\n float inputs:roughness = 3"
              "\n float inputs:metallic = -2")
    text = '(\n metersPerUnit = 1\n)\n' + material("G", inputs) + mesh("M", binding="G")
    mat = load_scene(write(tmp_path / "range.usda", text)).materials[0]
    assert (mat.transmission, mat.roughness, mat.metallic) == (1.0, 1.0, 0.0)


def _textured(tmp_path: Path, tex_uri: str, st_reader: str = "st", extra_nodes: str = "",
              st_source: str = "</G/R.outputs:result>") -> str:
    nodes = f"""
    def Shader "T"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{tex_uri}@
        float2 inputs:st.connect = {st_source}
        token inputs:wrapS = "clamp"
        token inputs:wrapT = "mirror"
        float4 inputs:scale = (0.5, 0.5, 0.5, 1)
        float3 outputs:rgb
        float outputs:g
    }}
    def Shader "R"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "{st_reader}"
        float2 outputs:result
    }}
    {extra_nodes}
"""
    return '(\n metersPerUnit = 1\n)\n' + material(
        "G", "color3f inputs:diffuseColor.connect = </G/T.outputs:rgb>\n"
             "        float inputs:roughness.connect = </G/T.outputs:g>", nodes) \
        + mesh("M", QUAD + f"""
        texCoord2f[] primvars:{st_reader} = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
""", binding="G")


def test_uv_texture_in_usdz_with_wrap_scale_and_channels(tmp_path):
    png(tmp_path / "src/tex/a.png", (200, 100, 50, 255))
    layer = write(tmp_path / "src/root.usda", _textured(tmp_path, "tex/a.png", st_reader="uvmap"))
    pkg = tmp_path / "asset.usdz"
    with zipfile.ZipFile(pkg, "w", zipfile.ZIP_STORED) as z:
        z.write(layer, "root.usda")
        z.write(tmp_path / "src/tex/a.png", "tex/a.png")
    scene = load_scene(pkg)
    mat = scene.materials[0]
    assert mat.base_color[:3] == (0.5, 0.5, 0.5)
    base = scene.textures[mat.base_color_texture.texture]
    assert base.image.shape == (2, 4, 4) and tuple(base.image[0, 0]) == (200, 100, 50, 255)
    assert (base.sampler.wrap_s, base.sampler.wrap_t) == (33071, 33648)  # clamp, mirror
    # roughness read from G lands in G of the metallic-roughness texture, factor = scale.g
    assert mat.roughness == pytest.approx(0.5)
    mr = scene.textures[mat.metallic_roughness_texture.texture]
    # an 8-bit RGBA PNG at sourceColorSpace auto is sRGB to Storm whichever input reads it
    assert mr.image[0, 0, 1] == round(float(srgb_to_linear(np.uint8(100))) * 255)
    assert scene.meshes[0].uv0 is not None  # read from "uvmap", the reader's primvar
    assert scene.files == [str(pkg.resolve())]  # the package stands for what it holds


def test_texture_file_and_primvar_name_through_material_interface(tmp_path):
    png(tmp_path / "maps/a.png", (0, 255, 0, 255))
    text = '(\n metersPerUnit = 1\n)\n' + material("G", """
        color3f inputs:diffuseColor.connect = </G/T.outputs:rgb>""", """
    asset inputs:tex = @./maps/a.png@
    string inputs:frame:stPrimvarName = "uv"
    def Shader "T"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file.connect = </G.inputs:tex>
        float2 inputs:st.connect = </G/R.outputs:result>
        float3 outputs:rgb
    }
    def Shader "R"
    {
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname.connect = </G.inputs:frame:stPrimvarName>
        float2 outputs:result
    }
""") + mesh("M", QUAD + """
        texCoord2f[] primvars:uv = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
""", binding="G")
    scene = load_scene(write(tmp_path / "iface.usda", text))
    assert len(scene.textures) == 1 and scene.meshes[0].uv0 is not None
    assert tuple(scene.textures[0].image[0, 0]) == (0, 255, 0, 255)


def test_channel_repack_for_separate_maps(tmp_path):
    png(tmp_path / "rough.png", (10, 0, 0, 255))
    png(tmp_path / "metal.png", (240, 0, 0, 255))
    nodes = """
    def Shader "Ro"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./rough.png@
        token inputs:sourceColorSpace = "raw"
        float outputs:r
    }
    def Shader "Me"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./metal.png@
        token inputs:sourceColorSpace = "raw"
        float outputs:r
    }
"""
    text = '(\n metersPerUnit = 1\n)\n' + material(
        "G", "float inputs:roughness.connect = </G/Ro.outputs:r>\n"
             "        float inputs:metallic.connect = </G/Me.outputs:r>", nodes) \
        + mesh("M", binding="G")
    scene = load_scene(write(tmp_path / "mr.usda", text))
    mat = scene.materials[0]
    packed = scene.textures[mat.metallic_roughness_texture.texture].image
    assert tuple(packed[0, 0, 1:3]) == (10, 240)  # G roughness, B metallic
    assert mat.roughness == mat.metallic == 1.0


def test_transform2d_matches_usd_formula(tmp_path):
    png(tmp_path / "a.png")
    extra = """
    def Shader "X"
    {
        uniform token info:id = "UsdTransform2d"
        float2 inputs:in.connect = </G/R.outputs:result>
        float inputs:rotation = 30
        float2 inputs:scale = (2, 3)
        float2 inputs:translation = (0.25, -0.5)
        float2 outputs:result
    }
"""
    text = _textured(tmp_path, "./a.png", extra_nodes=extra, st_source="</G/X.outputs:result>")
    ref = load_scene(write(tmp_path / "x.usda", text)).materials[0].base_color_texture
    rng = np.random.default_rng(1)
    for s, t in rng.random((5, 2)):
        th = math.radians(30)
        ss, tt = 2 * s, 3 * t  # USD: scale, rotate, translate, in st (v up)
        us = (math.cos(th) * ss - math.sin(th) * tt + 0.25,
              math.sin(th) * ss + math.cos(th) * tt - 0.5)
        u, v, _ = ref.uv_matrix() @ np.array([s, 1 - t, 1.0])  # glTF uv of the same point
        assert (u, 1 - v) == pytest.approx(us, abs=1e-5)


def test_symlink_inside_the_folder_is_followed(tmp_path):
    write(tmp_path / "real/part.usda",
          '(\n defaultPrim = "P"\n)\ndef Xform "P" {\n' + mesh("M") + "}\n")
    os.symlink(tmp_path / "real/part.usda", tmp_path / "link.usda")
    os.symlink(tmp_path / "real", tmp_path / "dir")
    path = write(tmp_path / "a.usda", '(\n metersPerUnit = 1\n)\n'
                 'def "A" (\n prepend references = @./link.usda@\n) {}\n'
                 'def "B" (\n prepend references = @dir/../dir/part.usda@\n) {}\n')
    assert load_scene(path).triangle_count == 4


def test_missing_sublayer_texture_reference_or_payload_is_a_warning(tmp_path):
    write(tmp_path / "geo.usda", mesh("M", binding="Mat") + material(
        "Mat", "color3f inputs:diffuseColor.connect = </Mat/T.outputs:rgb>", """
    def Shader "T"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @gone.png@
        float4 inputs:fallback = (0, 1, 0, 1)
        float3 outputs:rgb
    }"""))
    path = write(tmp_path / "a.usda", '(\n subLayers = [@./gone.usda@, @./geo.usda@]\n)\n')
    scene = load_scene(path)
    assert scene.triangle_count == 2
    assert sum("gone.usda" in w for w in scene.warnings) == 1, scene.warnings
    assert any("gone.png" in w for w in scene.warnings)
    assert scene.materials[0].base_color[:3] == (0, 1, 0)  # UsdUVTexture's fallback
    (tmp_path / "bad.usda").write_bytes(b"#usda 1.0\n def {{{ nonsense")
    scene = load_scene(write(tmp_path / "b.usda", '(\n subLayers = [@./bad.usda@, '
                                                           '@./geo.usda@]\n)\n'))
    assert scene.triangle_count == 2 and any("bad.usda" in w for w in scene.warnings)
    for arc in ("references", "payload"):
        path = write(tmp_path / f"{arc}.usda", f'def "A" (\n prepend {arc} = @./gone.usda@\n) {{}}\n'
                     + mesh("M"))
        scene = load_scene(path)  # as usdview: the rest is drawn, the file named
        assert scene.triangle_count == 2
        assert any("gone.usda" in w and "</A>" in w for w in scene.warnings), scene.warnings
    with pytest.raises(MissingFile, match="no such file"):
        load_scene(tmp_path / "nothing.usda")


# -- hostile files --------------------------------------------------------------------------------
def _hostile_cases(tmp_path: Path) -> dict[str, tuple[Path, type]]:
    out = tmp_path.parent / f"{tmp_path.name}_outside"
    write(out / "outside.usda", mesh("M"))
    png(out / "t.png")
    asset = tmp_path / "asset"
    cases = {}
    cases["reference ../"] = (write(asset / "ref.usda", 'def "X" (\n prepend references = '
                                    f'@../../{out.name}/outside.usda@\n) {{}}\n'), UnsafeReference)
    cases["absolute"] = (write(asset / "abs.usda", f'(\n subLayers = [@{out}/outside.usda@]\n)\n'),
                         UnsafeReference)
    cases["http sublayer"] = (write(asset / "http.usda", '(\n subLayers = '
                                    '[@http://example.com/x.usda@]\n)\n'), UnsafeReference)
    cases["payload escape"] = (write(asset / "pay.usda", 'def "X" (\n prepend payload = '
                                     f'@../../{out.name}/outside.usda@\n) {{}}\n'), UnsafeReference)
    cases["texture escape"] = (write(asset / "tex.usda", _textured(
        asset, f"../../{out.name}/t.png")), UnsafeReference)
    link = asset / "linked.usda"
    link.parent.mkdir(parents=True, exist_ok=True)
    os.symlink(out / "outside.usda", link)
    cases["symlink out"] = (write(asset / "sym.usda", '(\n subLayers = [@./linked.usda@]\n)\n'),
                            UnsafeReference)
    cases["huge faceVertexCounts"] = (write(asset / "huge.usda", mesh("M", """
        int[] faceVertexCounts = [2000000000, 3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0)]
""")), LimitExceeded)
    cases["counts vs indices"] = (write(asset / "count.usda", mesh("M", """
        int[] faceVertexCounts = [4, 3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0)]
""")), MalformedAsset)
    cases["index past points"] = (write(asset / "index.usda", mesh("M", """
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 7]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0)]
""")), MalformedAsset)
    garbage = asset / "garbage.usda"
    garbage.write_text("#usda 1.0\ndef Mesh \"M\" { int[] faceVertexCounts = [3,\n")
    cases["truncated layer"] = (garbage, MalformedAsset)
    binary = asset / "bytes.usdc"
    binary.write_bytes(b"PXR-USDC" + bytes(range(256)) * 4)
    cases["corrupt crate"] = (binary, MalformedAsset)
    pkg = asset / "escape.usdz"
    inner = write(tmp_path / "inner.usda", '(\n subLayers = [@../outside.usda@]\n)\n')
    with zipfile.ZipFile(pkg, "w", zipfile.ZIP_STORED) as z:
        z.write(inner, "root.usda")
    cases["usdz escape"] = (pkg, UnsafeReference)
    deflated = asset / "deflated.usdz"
    with zipfile.ZipFile(deflated, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("root.usda", "#usda 1.0\n" + mesh("M") * 50)
    cases["compressed usdz"] = (deflated, MalformedAsset)
    return cases


def test_hostile_files_are_refused_fast(tmp_path):
    for name, (path, error) in _hostile_cases(tmp_path).items():
        start = time.monotonic()
        with pytest.raises(error) as info:
            load_scene(path)
        assert time.monotonic() - start < 10, name  # refused, not hung
        assert isinstance(info.value, AssetError)
        assert info.value.path and info.value.reason, name


def test_usdz_nested_layer_references_are_relative_to_that_layer(tmp_path):
    """`../geo.usda` in the package's sub/a.usda names geo.usda at the package root: inside
    the package (it was refused as leaving it); one more `..` does leave it."""
    geo = mesh("M", """
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
""")
    for up, error in (("..", None), ("../..", UnsafeReference)):
        pkg = tmp_path / f"nested{len(up)}.usdz"
        with zipfile.ZipFile(pkg, "w", zipfile.ZIP_STORED) as z:
            z.writestr("root.usda", "#usda 1.0\n(\n metersPerUnit = 1\n subLayers = [@sub/a.usda@]\n)\n")
            z.writestr("sub/a.usda", f"#usda 1.0\n(\n subLayers = [@{up}/geo.usda@]\n)\n")
            z.writestr("geo.usda", "#usda 1.0\n" + geo)
        if error is None:
            assert load_scene(pkg).triangle_count == 1
        else:
            with pytest.raises(error, match="leaves the package"):
                load_scene(pkg)


def test_usdz_entry_and_size_limits(tmp_path):
    pkg = tmp_path / "many.usdz"
    with zipfile.ZipFile(pkg, "w", zipfile.ZIP_STORED) as z:
        z.writestr("root.usda", "#usda 1.0\n" + mesh("M"))
        for i in range(20):
            z.writestr(f"pad{i}.txt", b"x" * 1000)
    with pytest.raises(LimitExceeded, match="files"):
        load_scene(pkg, Limits(max_archive_files=10))
    with pytest.raises(LimitExceeded, match="unpacks"):
        load_scene(pkg, Limits(max_unpacked_bytes=5000))
    assert load_scene(pkg).triangle_count == 2


def test_undecodable_texture_is_a_warning(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    scene = load_scene(write(tmp_path / "t.usda", _textured(tmp_path, "./bad.png")))
    mat = scene.materials[0]
    assert mat.base_color_texture is None
    assert mat.base_color == (0.0, 0.0, 0.0, 1.0)  # UsdUVTexture's default fallback
    assert any("bad.png" in w for w in scene.warnings)
