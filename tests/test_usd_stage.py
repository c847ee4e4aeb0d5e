"""USD as studios ship it: counts that agree with a direct pxr traversal (purposes, visibility,
instancing, GeomSubsets, variants, PointInstancers), UsdSkel posed at rest, UsdLux lights, a
dome light's environment and UsdGeomCameras usable by `render --camera`."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from core.errors import NotInAsset
from core.options import RenderOptions
from pipeline.bake import build_baked
from pipeline.ingest import load_scene
from renderer.view.framing import request_camera

USD_SUFFIXES = {".usd", ".usda", ".usdc", ".usdz"}


def pxr_triangles(path) -> int:
    """Triangles as usdview draws them, straight from pxr: visible, default/render purpose
    Meshes with instance proxies, PointInstancer prototypes once per (unmasked) instance."""
    stage = Usd.Stage.Open(str(path))
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)

    def mesh_triangles(prim) -> int:
        mesh = UsdGeom.Mesh(prim)
        counts = list(mesh.GetFaceVertexCountsAttr().Get() or [])
        holes = set(mesh.GetHoleIndicesAttr().Get() or [])
        return sum(max(c - 2, 0) for f, c in enumerate(counts) if f not in holes)

    def drawn(prim) -> bool:
        img = UsdGeom.Imageable(prim)
        return img.ComputeVisibility() != UsdGeom.Tokens.invisible and \
            img.ComputePurpose() in (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)

    def subtree(root) -> int:
        total = 0
        it = iter(Usd.PrimRange(root, predicate))
        for prim in it:
            if prim.IsA(UsdGeom.PointInstancer):
                it.PruneChildren()
                if drawn(prim):
                    pi = UsdGeom.PointInstancer(prim)
                    idx = np.asarray(pi.GetProtoIndicesAttr().Get() or [], int)
                    mask = np.asarray(pi.ComputeMaskAtTime(Usd.TimeCode.Default()) or
                                      [True] * len(idx), bool)
                    for j, target in enumerate(pi.GetPrototypesRel().GetForwardedTargets()):
                        total += int((mask & (idx == j)).sum()) * subtree(stage.GetPrimAtPath(target))
            elif prim.IsA(UsdGeom.Mesh) and drawn(prim):
                total += mesh_triangles(prim)
        return total

    return subtree(stage.GetPseudoRoot())


def test_every_usd_sample_matches_a_direct_pxr_traversal(assets):
    samples = sorted(p for p in (assets / "usd").rglob("*") if p.suffix in USD_SUFFIXES)
    assert len(samples) >= 8
    for path in samples:
        # full: every mesh (the Teapot's DrawModes stage replaces most with stand-ins)
        assert load_scene(path, draw_mode="full").triangle_count == pxr_triangles(path) > 0, path


QUAD = """
        int[] faceVertexCounts = [4, 4]
        int[] faceVertexIndices = [0, 1, 2, 3, 1, 4, 5, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)]
        uniform token subdivisionScheme = "none"
"""

STUDIO = f"""#usda 1.0
(
    metersPerUnit = 1
    defaultPrim = "Set"
)
def Xform "Set"
{{
    def Xform "Prop" (
        instanceable = true
        prepend references = </Library/Crate>
    )
    {{
    }}
    def Xform "Prop2" (
        instanceable = true
        prepend references = </Library/Crate>
    )
    {{
        double3 xformOp:translate = (5, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
    def Xform "Prop3" (
        instanceable = true
        prepend references = </Library/Crate>
    )
    {{
        double3 xformOp:translate = (10, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
    def Xform "Hidden"
    {{
        token visibility = "invisible"
        def Mesh "M"
        {{{QUAD}
        }}
    }}
    def Xform "Proxy"
    {{
        uniform token purpose = "proxy"
        def Mesh "M"
        {{{QUAD}
        }}
    }}
    def Xform "Render"
    {{
        uniform token purpose = "render"
        def Mesh "M"
        {{
            uniform token purpose = "proxy"{QUAD}
        }}
    }}
    def Mesh "Guide"
    {{
        uniform token purpose = "guide"{QUAD}
    }}
    def Mesh "Split"
    {{{QUAD}
        def GeomSubset "a"
        {{
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [0]
        }}
    }}
    def Mesh "TwoFamilies"
    {{{QUAD}
        def GeomSubset "left" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {{
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [0]
            rel material:binding = </Set/Looks/Red>
        }}
        def GeomSubset "right" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {{
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [1]
            rel material:binding = </Set/Looks/Red>
        }}
        def GeomSubset "partLeft" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {{
            uniform token elementType = "face"
            uniform token familyName = "parts"
            int[] indices = [0]
            rel material:binding = </Set/Looks/Red>
        }}
    }}
    def Scope "Looks"
    {{
        def Material "Red"
        {{
        }}
    }}
    def Xform "Variant" (
        variants = {{
            string lod = "low"
        }}
        prepend variantSets = "lod"
    )
    {{
        variantSet "lod" = {{
            "high" {{
                def Mesh "High"
                {{{QUAD}
                }}
                def Mesh "High2"
                {{{QUAD}
                }}
            }}
            "low" {{
                def Mesh "Low"
                {{{QUAD}
                }}
            }}
        }}
    }}
    def PointInstancer "Scatter"
    {{
        rel prototypes = [</Set/Scatter/Protos/Rock>]
        int[] protoIndices = [0, 0, 0, 0, 0]
        point3f[] positions = [(0, 5, 0), (1, 5, 0), (2, 5, 0), (3, 5, 0), (4, 5, 0)]
        int64[] invisibleIds = [4]
        def Scope "Protos"
        {{
            def Mesh "Rock"
            {{{QUAD}
            }}
        }}
    }}
}}
over "Library"
{{
    def Xform "Crate"
    {{
        def Mesh "Box"
        {{{QUAD}
        }}
    }}
}}
"""


def test_studio_stage_counts_and_instancing_agree_with_pxr(tmp_path):
    path = tmp_path / "studio.usda"
    path.write_text(STUDIO)
    scene = load_scene(path)
    # 4 triangles a mesh: crates 3 x 4, Split 4, TwoFamilies 4 (its "parts" subset is not a
    # second copy of face 0), the selected variant's Low 4, Scatter 4 unmasked x 4; not Hidden,
    # Proxy, Guide, nor Render/M (its own proxy purpose wins)
    assert scene.triangle_count == pxr_triangles(path) == 12 + 4 + 4 + 4 + 16
    assert any("partLeft" in w and "not materialBind" in w for w in scene.warnings)
    by_name: dict[str, list] = {}
    for inst in scene.instances:
        by_name.setdefault(scene.meshes[inst.mesh].name, []).append(inst)
    crate = [n for n in by_name if n.endswith("/Box")]
    assert len(crate) == 1 and len(by_name[crate[0]]) == 3  # one mesh, drawn three times
    rock = [n for n in by_name if n.endswith("/Rock")]
    assert len(rock) == 1 and len(by_name[rock[0]]) == 4
    baked = build_baked(scene)
    assert sorted(len(m.transforms) for m in baked.meshes)[-2:] == [3, 4]  # instanced draws


SKEL = """#usda 1.0
(
    metersPerUnit = 1
)
def SkelRoot "Arm"
{
    def Skeleton "Skel" ( prepend apiSchemas = ["SkelBindingAPI"] )
    {
        uniform token[] joints = ["root", "root/elbow"]
        uniform matrix4d[] bindTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)), ((1,0,0,0),(0,1,0,0),(0,0,1,0),(1,0,0,1))]
        uniform matrix4d[] restTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)), ((0,1,0,0),(-1,0,0,0),(0,0,1,0),(1,0,0,1))]
        double3 xformOp:translate = (0, 0, 2)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Mesh "Skin" ( prepend apiSchemas = ["SkelBindingAPI"] )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(1, 0, 0), (2, 0, 0), (2, 0.1, 0), (1, 0.1, 0)]
        int[] primvars:skel:jointIndices = [1, 1, 1, 1] (
            elementSize = 1
            interpolation = "vertex"
        )
        float[] primvars:skel:jointWeights = [1, 1, 1, 1] (
            elementSize = 1
            interpolation = "vertex"
        )
        rel skel:skeleton = </Arm/Skel>
        uniform token subdivisionScheme = "none"
        double3 xformOp:translate = (0, 5, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
"""


def test_skinned_mesh_is_posed_at_the_rest_transforms(tmp_path):
    """The elbow's rest pose turns 90 degrees from its bind pose: the forearm, bound along +X
    from x=1, points up +Y from the elbow. Skinned points are in the skeleton's space (its
    translate applies, the mesh's own does not)."""
    path = tmp_path / "arm.usda"
    path.write_text(SKEL)
    scene = load_scene(path)
    inst = scene.instances[0]
    p = scene.meshes[inst.mesh].positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
    lo, hi = p.min(0), p.max(0)
    np.testing.assert_allclose(lo, (0.9, 0, 2), atol=1e-5)
    np.testing.assert_allclose(hi, (1.0, 1.0, 2), atol=1e-5)


LIGHTS = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Z"
)
def Xform "World"
{
    def DistantLight "Sun"
    {
        float inputs:intensity = 3
        float inputs:exposure = 1
        color3f inputs:color = (1, 0.5, 0.25)
    }
    def SphereLight "Bulb" ( prepend apiSchemas = ["ShapingAPI"] )
    {
        float inputs:radius = 0.5
        float inputs:intensity = 4
        float inputs:shaping:cone:angle = 30
        float inputs:shaping:cone:softness = 0.5
        double3 xformOp:translate = (0, 0, 3)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def RectLight "Panel"
    {
        float inputs:width = 2
        float inputs:height = 0.5
    }
    def DomeLight "Sky"
    {
        asset inputs:texture:file = @sky.png@
    }
    def Camera "Shot"
    {
        float focalLength = 35
        float verticalAperture = 20.25
        float horizontalAperture = 36
        float2 clippingRange = (0.1, 1000)
        double3 xformOp:translate = (0, -10, 1)
        float3 xformOp:rotateXYZ = (90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
    def Cube "Box"
    {
        double size = 2
    }
}
"""


def test_lights_dome_and_camera(tmp_path):
    from PIL import Image
    Image.new("RGB", (8, 4), (10, 20, 200)).save(tmp_path / "sky.png")
    path = tmp_path / "lights.usda"
    path.write_text(LIGHTS)
    scene = load_scene(path)
    sun, bulb, panel = scene.lights
    # 3 x 2^1 radiance over a 0.53 degree disc: illuminance x pi sin^2(0.265 degrees)
    assert sun.type == "directional" and \
        sun.intensity == pytest.approx(6 * math.pi * math.sin(math.radians(0.265)) ** 2)
    assert sun.color == pytest.approx((1, 0.5, 0.25))
    np.testing.assert_allclose(-sun.matrix[:3, 2], (0, -1, 0), atol=1e-9)  # -Z of Z-up: down
    assert bulb.type == "spot" and bulb.intensity == pytest.approx(4 * math.pi * 0.25)
    assert (bulb.outer_cone, bulb.inner_cone) == pytest.approx((math.radians(30), math.radians(15)))
    np.testing.assert_allclose(bulb.matrix[:3, 3], (0, 3, 0), atol=1e-9)
    assert panel.type == "spot" and panel.intensity == pytest.approx(1.0)
    assert scene.environment == str((tmp_path / "sky.png").resolve())
    assert str((tmp_path / "sky.png").resolve()) in scene.files
    (cam,) = scene.cameras
    assert cam.name == "/World/Shot"
    assert math.degrees(cam.yfov) == pytest.approx(2 * math.degrees(math.atan(20.25 / 2 / 35)), rel=1e-4)
    np.testing.assert_allclose(cam.matrix[:3, 3], (0, 1, 10), atol=1e-6)
    np.testing.assert_allclose(-cam.matrix[:3, 2], (0, 0, -1), atol=1e-6)

    baked = build_baked(scene)
    for spec in ("/World/Shot", "0"):  # by prim path or by index, as glTF cameras
        c = request_camera(baked, RenderOptions(width=64, height=64, camera=spec))
        np.testing.assert_allclose(c.position, (0, 1, 10), atol=1e-6)
        d = c.target - c.position
        np.testing.assert_allclose(d / np.linalg.norm(d), (0, 0, -1), atol=1e-6)
        assert c.fov == pytest.approx(math.degrees(cam.yfov)) and c.near == pytest.approx(0.1)
    with pytest.raises(NotInAsset, match="'/World/Shot'"):
        request_camera(baked, RenderOptions(camera="/Nope"))


def test_render_through_the_usd_camera_and_dome(tmp_path, capsys):
    from PIL import Image

    from cli.main import main
    Image.new("RGB", (16, 8), (10, 20, 200)).save(tmp_path / "sky.png")
    path = tmp_path / "lights.usda"
    path.write_text(LIGHTS)
    def shot(*extra):
        out = tmp_path / "shot.npy"
        assert main(["render", str(path), "--camera", "/World/Shot", "--out", str(out), "--size",
                     "64", "--cache", str(tmp_path / "cache"), "--msaa", "0", "--tonemap", "none",
                     *extra]) == 0
        return np.load(out)

    covered = shot("--background", "transparent")[..., 3] > 0.5
    img = shot("--background", "env")  # the dome shown behind (the default backdrop is a gradient)
    # a 2-unit box 10 units away under a 32 degree fov: about 0.35 of the height, centred
    rows = np.nonzero(covered.any(1))[0]
    assert 0.25 < (rows.max() - rows.min() + 1) / 64 < 0.45
    cols = np.nonzero(covered.any(0))[0]
    assert abs((cols.min() + cols.max()) / 2 - 31.5) < 2
    sky = img[~covered][:, :3].mean(0)
    assert sky[2] > 3 * sky[0]  # the dome's blue, not the default environment


GREY_CARD = """#usda 1.0
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
        rel material:binding = </World/Grey>
    }
    def Material "Grey"
    {
        token outputs:surface.connect = </World/Grey/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.5, 0.5, 0.5)
            float inputs:roughness = 1
            float inputs:ior = 1
            token outputs:surface
        }
    }
    def DistantLight "Sun"
    {
LIGHT
    }
}
"""


def _card_shot(path, tmp_path, *extra):
    from cli.main import main
    out = tmp_path / "card.npy"
    assert main(["render", str(path), "--out", str(out), "--size", "32", "--yaw", "0",
                 "--pitch", "0", "--tonemap", "none", "--msaa", "0",
                 "--cache", str(tmp_path / "cache"), *extra]) == 0
    return np.load(out).astype(np.float64)[12:20, 12:20, :3]


@pytest.mark.parametrize("authored, illuminance", [
    ("", 50000 * math.pi * math.sin(math.radians(0.53 / 2)) ** 2),  # the schema's fallback
    ("float inputs:intensity = 1.5\nfloat inputs:exposure = 1\nbool inputs:normalize = 1", 3.0),
    ("float inputs:intensity = 40\nfloat inputs:angle = 20",
     40 * math.pi * math.sin(math.radians(10)) ** 2),
])
def test_grey_card_under_a_distant_light(tmp_path, authored, illuminance):
    """A Lambertian card facing a DistantLight is lit by it alone, as Storm lights it (no
    studio environment on top): albedo / pi x E."""
    path = tmp_path / "card.usda"
    path.write_text(GREY_CARD.replace("LIGHT", authored))
    np.testing.assert_allclose(_card_shot(path, tmp_path), 0.5 / math.pi * illuminance, rtol=0.02)
    # its lights off, the studio lights it; named, an environment lights it with the stage's lights
    studio = _card_shot(path, tmp_path, "--no-lights")
    assert studio.min() > 0.1
    both = _card_shot(path, tmp_path, "--env", "studio")
    np.testing.assert_allclose(both - studio, 0.5 / math.pi * illuminance, rtol=0.02)


def test_untextured_dome_is_a_uniform_environment(tmp_path):
    """A DomeLight without a texture is radiance colour x intensity x 2^exposure from every
    direction (UsdLux): a Lambertian card shows albedo x L; with a distant light beside it, both."""
    path = tmp_path / "dome.usda"
    dome = 'def DomeLight "Sky"\n    {\n        float inputs:intensity = 0.5\n        ' \
           'float inputs:exposure = 1\n        color3f inputs:color = (1, 0.5, 0.25)\n    }\n    '
    path.write_text(GREY_CARD.replace('def DistantLight "Sun"', dome + 'def DistantLight "Sun"')
                    .replace("LIGHT", "float inputs:intensity = 0.2\nbool inputs:normalize = 1"))
    expect = 0.5 * np.array([1.0, 0.5, 0.25]) + 0.5 / math.pi * 0.2
    np.testing.assert_allclose(_card_shot(path, tmp_path), np.broadcast_to(expect, (8, 8, 3)), rtol=0.02)


def test_textured_dome_intensity_exposure_and_colour_scale_its_texture(tmp_path):
    """A textured DomeLight's radiance is its texture x intensity x 2^exposure x colour
    (UsdLux): doubling the intensity doubles what a Lambertian card reflects, and the
    environment baked for it is the file's, scaled (pipeline/environment/scaled.py)."""
    from PIL import Image

    from core.colour import srgb_to_linear
    Image.new("RGB", (16, 8), (188, 188, 188)).save(tmp_path / "sky.png")
    texel = float(srgb_to_linear(np.array([188], np.uint8))[0])
    shots = {}
    for label, inputs, factor in (("one", "", (1.0, 1.0, 1.0)),
                                  ("two", "float inputs:intensity = 2", (2.0, 2.0, 2.0)),
                                  ("tinted", "float inputs:intensity = 0.5\nfloat inputs:exposure = 1\n"
                                             "color3f inputs:color = (1, 0.5, 0.25)", (1.0, 0.5, 0.25))):
        path = tmp_path / label / "card.usda"
        path.parent.mkdir()
        (path.parent / "sky.png").write_bytes((tmp_path / "sky.png").read_bytes())
        path.write_text(GREY_CARD.replace('def DistantLight "Sun"\n    {\nLIGHT\n    }',
                                          'def DomeLight "Sky"\n    {\n' + inputs +
                                          '\n        asset inputs:texture:file = @sky.png@\n    }'))
        shots[label] = _card_shot(path, tmp_path)
        np.testing.assert_allclose(shots[label], np.broadcast_to(0.5 * texel * np.array(factor),
                                                                 (8, 8, 3)), rtol=0.03)
    np.testing.assert_allclose(shots["two"] / shots["one"], 2.0, rtol=1e-3)
    from pipeline.environment import scaled
    assert scaled.parse(scaled.name((2, 2, 2), "/a/sky.png")) == ((2.0, 2.0, 2.0), "/a/sky.png")
    assert scaled.name((1, 1, 1), "/a/sky.png") == "/a/sky.png"


def test_area_lights_in_metres(tmp_path):
    """A RectLight's and a SphereLight's size is in stage units x metersPerUnit x scale."""
    path = tmp_path / "cm.usda"
    path.write_text("""#usda 1.0
(
    metersPerUnit = 0.01
)
def Cube "Box"
{
}
def RectLight "Panel"
{
    float inputs:width = 200
    float inputs:height = 50
    float inputs:intensity = 3
}
def SphereLight "Bulb"
{
    float inputs:radius = 10
    double3 xformOp:scale = (2, 2, 2)
    uniform token[] xformOpOrder = ["xformOp:scale"]
}
def SphereLight "Normalized"
{
    float inputs:radius = 10
    float inputs:intensity = 7
    bool inputs:normalize = 1
}
""")
    panel, bulb, normalized = load_scene(path).lights
    assert panel.intensity == pytest.approx(3 * 2.0 * 0.5)
    assert bulb.intensity == pytest.approx(math.pi * 0.2 ** 2)
    assert normalized.intensity == pytest.approx(7)


def test_stage_lights_replace_the_studio_over_http(server, tmp_path):
    """The service lights a stage with its own lights as the CLI does (the default
    environment is not added); a named environment lights it beside them."""
    from test_service import decode, upload
    r = upload(server, "card.usda", GREY_CARD.replace("LIGHT", "float inputs:intensity = 2\n"
                                                      "bool inputs:normalize = 1").encode())
    rec = server.wait_status(r.json()["id"])
    assert rec["status"] == "ready", rec
    q = {"size": 32, "yaw": 0, "pitch": 0, "tonemap": "none", "msaa": 0}
    own = server.client.get(f"/assets/{rec['id']}/thumbnail", params=q)
    studio = server.client.get(f"/assets/{rec['id']}/thumbnail", params={**q, "env": "studio"})
    assert own.status_code == studio.status_code == 200
    centre = lambda r: decode(r.content)[12:20, 12:20, :3].mean() / 255  # noqa: E731
    expect = (0.5 / math.pi * 2) ** (1 / 2.4) * 1.055 - 0.055  # sRGB of albedo / pi x E
    assert abs(centre(own) - expect) < 0.02
    assert centre(studio) > centre(own) + 0.1
