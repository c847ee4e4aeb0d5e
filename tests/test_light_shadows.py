"""Punctual lights cast shadows in the raster (renderer/raster/light_shadows.py): a sphere over
a ground plane under a distant, a spot and a point light, read from a USD stage. The ground's
pixel at the analytically projected shadow centre against a lit one, both Lambert under a
uniform sky: lit = albedo x (sky + E cos / pi), shadowed = albedo x sky; the ray tracer's NEE
(renderer/methods/trace_lights.py) agrees. UsdLux inputs:shadow:enable false casts none and
inputs:shadow:color tints the shadowed light."""
from __future__ import annotations

import base64
import dataclasses
import json
import math

import numpy as np
import pytest

from core.options import RenderOptions
from pipeline.bake import bake_environment, build_baked
from pipeline.environment import uniform
from pipeline.ingest import load_scene
from renderer import render
from renderer.view.framing import asset_camera

ALBEDO = 0.8
SKY = 0.3          # uniform sky radiance
SUN = 3.0          # the distant light's illuminance (normalized: intensity)
CENTRE = np.array([0.0, 1.5, 0.0])  # the sphere's
RADIUS = 0.4
SIZE = 96
# The ground pixel at the shadow centre and a lit one against their expected values: raster vs
# the analytic value (its IBL is exact for a uniform sky; measured within 0.1%), raytrace vs
# the same (measured within 0.05% of the raster)
ANALYTIC_TOLERANCE = 0.02
RAYTRACE_TOLERANCE = 0.02

STAGE = """#usda 1.0
(
    defaultPrim = "World"
    upAxis = "Y"
    metersPerUnit = 1
)
def Xform "World"
{
    def Sphere "Ball" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        double radius = %(radius)s
        double3 xformOp:translate = (%(cx)s, %(cy)s, %(cz)s)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        rel material:binding = </World/Matte>
    }
    def Mesh "Ground" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-2.5, 0, 2.5), (2.5, 0, 2.5), (2.5, 0, -2.5), (-2.5, 0, -2.5)]
        normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] ( interpolation = "vertex" )
        rel material:binding = </World/Matte>
    }
    def Material "Matte"
    {
        token outputs:surface.connect = </World/Matte/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (%(albedo)s, %(albedo)s, %(albedo)s)
            float inputs:roughness = 1
            float inputs:ior = 1
            token outputs:surface
        }
    }
    LIGHT
}
"""

DISTANT = """def DistantLight "Sun"
    {
        float inputs:intensity = %s
        bool inputs:normalize = 1
        EXTRA
        float3 xformOp:rotateXYZ = (-60, 30, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }""" % SUN

SPOT = """def SphereLight "Spot" ( prepend apiSchemas = ["ShapingAPI"] )
    {
        float inputs:intensity = 20
        bool inputs:normalize = 1
        bool treatAsPoint = 1
        float inputs:shaping:cone:angle = 40
        double3 xformOp:translate = (1.2, 3.5, 0.8)
        float3 xformOp:rotateXYZ = (-75, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }"""

POINT = """def SphereLight "Bulb"
    {
        float inputs:intensity = 20
        bool inputs:normalize = 1
        bool treatAsPoint = 1
        double3 xformOp:translate = (0.6, 3.2, 0.4)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }"""


def _asset(tmp_path, light: str, extra: str = ""):
    text = STAGE % {"radius": RADIUS, "cx": CENTRE[0], "cy": CENTRE[1], "cz": CENTRE[2],
                    "albedo": ALBEDO}
    path = tmp_path / "stage.usda"
    path.write_text(text.replace("LIGHT", light.replace("EXTRA", extra)))
    return build_baked(load_scene(path), key=f"light-shadows-{hash(light + extra)}")


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    return bake_environment(uniform.name((SKY,) * 3), tmp_path_factory.mktemp("sky"), face_size=32)


OPTIONS = RenderOptions(width=SIZE, height=SIZE, tonemap="none", background="transparent",
                        shadow=0.0, yaw=20.0, pitch=50.0, method="opaque")


def _pixel(frame, asset, options, point) -> np.ndarray:
    """The mean linear RGB of the 3 x 3 pixels about where world `point` projects."""
    camera = asset_camera(asset, options)[0]
    clip = camera.projection_matrix() @ camera.view_matrix() @ np.append(point, 1.0)
    ndc = clip[:3] / clip[3]
    col = int((ndc[0] * 0.5 + 0.5) * options.width)
    row = int((0.5 - ndc[1] * 0.5) * options.height)
    assert 1 <= col < options.width - 1 and 1 <= row < options.height - 1, (point, col, row)
    return frame.linear[row - 1:row + 2, col - 1:col + 2, :3].reshape(-1, 3).mean(0)


def _ground_hit(origin: np.ndarray, toward_light: np.ndarray) -> np.ndarray:
    """Where the ray from the light through `origin` meets the ground y = 0."""
    return origin - toward_light * (origin[1] / toward_light[1])


def _sun(asset) -> np.ndarray:
    """Unit direction toward the distant light."""
    m = asset.lights[0].matrix
    return m[:3, 2] / np.linalg.norm(m[:3, 2])


def test_distant_light_shadow_centre_is_lit_by_the_sky_alone(tmp_path, sky):
    asset = _asset(tmp_path, DISTANT)
    to_light = _sun(asset)
    cos = float(to_light[1])
    shade = _ground_hit(CENTRE, to_light)
    lit = np.array([-shade[0], 0.0, -shade[2]])  # as far from the sphere's foot, across it
    lit_expected = ALBEDO * (SKY + SUN * cos / math.pi)
    shade_expected = ALBEDO * SKY
    frames = {"opaque": render(asset, sky, OPTIONS),
              "raytrace": render(asset, sky, dataclasses.replace(OPTIONS, method="raytrace"))}
    raster = frames["opaque"]
    assert raster.plan["light_shadows"].startswith("1 light(s), 1 view(s)")
    got_lit, got_shade = _pixel(raster, asset, OPTIONS, lit), _pixel(raster, asset, OPTIONS, shade)
    assert np.allclose(got_lit, lit_expected, rtol=ANALYTIC_TOLERANCE), (got_lit, lit_expected)
    assert np.allclose(got_shade, shade_expected, rtol=ANALYTIC_TOLERANCE), (got_shade, shade_expected)
    ratio = got_shade / got_lit
    assert np.allclose(ratio, shade_expected / lit_expected, rtol=2 * ANALYTIC_TOLERANCE)
    traced = frames["raytrace"]
    for point, value in ((lit, got_lit), (shade, got_shade)):
        assert np.allclose(_pixel(traced, asset, OPTIONS, point), value, rtol=RAYTRACE_TOLERANCE), point


def test_shadow_enable_false_and_the_option_cast_none(tmp_path, sky):
    on = _asset(tmp_path, DISTANT)
    off = _asset(tmp_path, DISTANT, "bool inputs:shadow:enable = 0")
    assert on.lights[0].shadow and not off.lights[0].shadow
    shade = _ground_hit(CENTRE, _sun(on))
    lit_expected = ALBEDO * (SKY + SUN * float(_sun(on)[1]) / math.pi)
    frame = render(off, sky, OPTIONS)
    assert frame.plan["light_shadows"] == "none"
    assert np.allclose(_pixel(frame, off, OPTIONS, shade), lit_expected, rtol=ANALYTIC_TOLERANCE)
    traced = render(off, sky, dataclasses.replace(OPTIONS, method="raytrace"))
    assert np.allclose(_pixel(traced, off, OPTIONS, shade), lit_expected, rtol=RAYTRACE_TOLERANCE)
    # RenderOptions.light_shadows off: the stage's shadowing light casts none either
    no = dataclasses.replace(OPTIONS, light_shadows=False)
    assert np.allclose(_pixel(render(on, sky, no), on, no, shade), lit_expected, rtol=ANALYTIC_TOLERANCE)


def test_shadow_color_tints_the_blocked_light(tmp_path, sky):
    tint = np.array([0.5, 0.25, 0.0])
    asset = _asset(tmp_path, DISTANT, "color3f inputs:shadow:color = (0.5, 0.25, 0)")
    assert asset.lights[0].shadow_color == (0.5, 0.25, 0.0)
    to_light = _sun(asset)
    shade = _ground_hit(CENTRE, to_light)
    expected = ALBEDO * (SKY + tint * SUN * float(to_light[1]) / math.pi)
    traced = dataclasses.replace(OPTIONS, method="raytrace")
    for options, tol in ((OPTIONS, ANALYTIC_TOLERANCE), (traced, RAYTRACE_TOLERANCE)):
        got = _pixel(render(asset, sky, options), asset, options, shade)
        assert np.allclose(got, expected, rtol=tol), (options.method, got, expected)


@pytest.mark.parametrize("light, views", [(SPOT, 1), (POINT, 6)], ids=["spot", "point"])
def test_spot_and_point_lights_cast_shadows(tmp_path, light, views):
    """Under the light alone (a dark sky) the ground at the shadow centre is black, beside it
    lit by I cos / d^2, as the ray tracer has it."""
    dark = bake_environment(uniform.DARK, tmp_path, face_size=32)
    asset = _asset(tmp_path, light)
    source = asset.lights[0].matrix[:3, 3]
    to_light = (source - CENTRE) / np.linalg.norm(source - CENTRE)
    shade = _ground_hit(CENTRE, to_light)
    lit = shade + np.array([0.0, 0.0, 0.0])
    lit[[0, 2]] = source[[0, 2]] + (source[[0, 2]] - shade[[0, 2]]) * 0.5  # the far side of the foot
    d = source - lit
    expected = ALBEDO / math.pi * asset.lights[0].intensity * d[1] / np.linalg.norm(d) ** 3
    frames = {"opaque": render(asset, dark, OPTIONS),
              "raytrace": render(asset, dark, dataclasses.replace(OPTIONS, method="raytrace"))}
    assert frames["opaque"].plan["light_shadows"] == f"1 light(s), {views} view(s) of 512 px"
    got_lit = _pixel(frames["opaque"], asset, OPTIONS, lit)
    assert np.allclose(got_lit, expected, rtol=ANALYTIC_TOLERANCE), (got_lit, expected)
    assert _pixel(frames["opaque"], asset, OPTIONS, shade).max() < 0.01 * expected
    assert _pixel(frames["raytrace"], asset, OPTIONS, shade).max() < 0.01 * expected
    assert np.allclose(_pixel(frames["raytrace"], asset, OPTIONS, lit), got_lit, rtol=RAYTRACE_TOLERANCE)


def _gltf_box_over_ground(path):
    """A 0.6 m box 1 m above a 4 m ground quad, both matte, under a KHR_lights_punctual
    directional light shining straight down."""
    quad = [(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]
    box = [(x, y, z) for x in (-0.3, 0.3) for y in (1.0, 1.6) for z in (-0.3, 0.3)]
    pos = np.array(quad + box, np.float32)
    faces = [(0, 1, 2), (0, 2, 3)]
    for a, b, c, d in ((0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)):
        faces += [(4 + a, 4 + b, 4 + c), (4 + a, 4 + c, 4 + d)]
    idx = np.array(faces, np.uint16).ravel()
    blob = pos.tobytes() + idx.tobytes()
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 3.0}]}},
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0},
                  {"rotation": [-math.sqrt(0.5), 0, 0, math.sqrt(0.5)],  # -Z turned to -Y
                   "extensions": {"KHR_lights_punctual": {"light": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [ALBEDO, ALBEDO, ALBEDO, 1],
                                                "metallicFactor": 0, "roughnessFactor": 1},
                       "doubleSided": True}],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                       "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
                      {"bufferView": 1, "componentType": 5123, "count": len(idx), "type": "SCALAR"}],
    }
    path.write_text(json.dumps(doc))
    return path


def test_gltf_directional_light_shadows(tmp_path):
    """glTF lights always cast shadows: under a straight-down sun the ground below the box is
    dark, beside it lit, as the ray tracer has it."""
    dark = bake_environment(uniform.DARK, tmp_path, face_size=32)
    asset = build_baked(load_scene(_gltf_box_over_ground(tmp_path / "box.gltf")), key="light-shadows-gltf")
    assert len(asset.lights) == 1 and asset.lights[0].shadow
    below, beside = np.array([0.1, 0.0, 0.1]), np.array([1.2, 0.0, 1.2])
    frames = {"opaque": render(asset, dark, OPTIONS),
              "raytrace": render(asset, dark, dataclasses.replace(OPTIONS, method="raytrace"))}
    lit = _pixel(frames["opaque"], asset, OPTIONS, beside)
    assert lit.min() > 0.5 * ALBEDO * 3.0 / math.pi  # about albedo E / pi, with a little specular
    assert _pixel(frames["opaque"], asset, OPTIONS, below).max() < 0.01 * lit.min()
    assert _pixel(frames["raytrace"], asset, OPTIONS, below).max() < 0.01 * lit.min()
    assert np.allclose(_pixel(frames["raytrace"], asset, OPTIONS, beside), lit, rtol=RAYTRACE_TOLERANCE)


def _quat_from_to(a, b) -> list[float]:
    """The unit quaternion (x, y, z, w) turning unit vector a to unit vector b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    angle = math.atan2(s, float(a @ b))
    axis = axis / s if s > 1e-12 else np.array([1.0, 0.0, 0.0])
    return [*(axis * math.sin(angle / 2)).tolist(), math.cos(angle / 2)]


def _png_rgba(pixels: np.ndarray) -> bytes:
    import io

    from PIL import Image
    out = io.BytesIO()
    Image.fromarray(pixels.astype(np.uint8), "RGBA").save(out, format="PNG")
    return out.getvalue()


SUN_TILT = math.radians(60.0)  # from the vertical, shining toward -x


def _gltf_mask_card(path, alpha_mode="MASK"):
    """A 2 x 1 m card 1 m above a ground quad, matte, its base-colour alpha 0 on the half
    x < 0 (a 4-texel texture: 0, 0, 255, 255 across u = (x + 1) / 2), alphaMode `alpha_mode`
    at cutoff 0.5, under a sun tilted SUN_TILT toward -x: the card's shadow falls beside it,
    x in [-1 - tan, 1 - tan]."""
    quad = [(-3.5, 0, 2), (2, 0, 2), (2, 0, -2), (-3.5, 0, -2)]
    card = [(-1, 1, 0.5), (1, 1, 0.5), (1, 1, -0.5), (-1, 1, -0.5)]
    pos = np.array(quad + card, np.float32)
    uv = np.array([(0, 0)] * 4 + [(0, 0), (1, 0), (1, 1), (0, 1)], np.float32)
    idx = np.array([(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)], np.uint16).ravel()
    texels = np.zeros((1, 4, 4))
    texels[..., :3] = 255 * ALBEDO
    texels[0, 2:, 3] = 255
    image = _png_rgba(texels)
    blob = pos.tobytes() + uv.tobytes() + idx.tobytes()
    travel = [-math.sin(SUN_TILT), -math.cos(SUN_TILT), 0.0]
    matte = {"pbrMetallicRoughness": {"baseColorFactor": [ALBEDO, ALBEDO, ALBEDO, 1],
                                      "metallicFactor": 0, "roughnessFactor": 1}, "doubleSided": True}
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 3.0}]}},
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [{"mesh": 0}, {"mesh": 1},
                  {"rotation": _quat_from_to([0, 0, -1], travel),
                   "extensions": {"KHR_lights_punctual": {"light": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2,
                                    "material": 0}]},
                   {"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 3,
                                    "material": 1}]}],
        "materials": [matte, {**matte, "alphaMode": alpha_mode, "alphaCutoff": 0.5,
                              "pbrMetallicRoughness": {**matte["pbrMetallicRoughness"],
                                                       "baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}],
        "images": [{"uri": "data:image/png;base64," + base64.b64encode(image).decode()}],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": uv.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes + uv.nbytes, "byteLength": 12},
                        {"buffer": 0, "byteOffset": pos.nbytes + uv.nbytes + 12, "byteLength": 12}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                       "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
                      {"bufferView": 1, "componentType": 5126, "count": len(uv), "type": "VEC2"},
                      {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
                      {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    }
    path.write_text(json.dumps(doc))
    return path


def test_alpha_mask_cut_outs_cut_the_shadow(tmp_path):
    """The light passes a mask's cut-out: the ground where the card's alpha-0 half shadows
    it is lit as if the card were not there (albedo E cos / pi), where the opaque half does
    it is dark, and the ray tracer agrees at both."""
    dark = bake_environment(uniform.DARK, tmp_path, face_size=32)
    asset = build_baked(load_scene(_gltf_mask_card(tmp_path / "card.gltf")), key="light-shadows-mask")
    shift = math.tan(SUN_TILT)
    through = np.array([-0.6 - shift, 0.0, 0.0])  # under card x = -0.6 (u 0.2: alpha 0)
    behind = np.array([0.6 - shift, 0.0, 0.0])    # under card x = 0.6 (u 0.8: alpha 1)
    expected = ALBEDO * 3.0 * math.cos(SUN_TILT) / math.pi
    frames = {"opaque": render(asset, dark, OPTIONS),
              "raytrace": render(asset, dark, dataclasses.replace(OPTIONS, method="raytrace"))}
    got = _pixel(frames["opaque"], asset, OPTIONS, through)
    assert np.allclose(got, expected, rtol=0.05), (got, expected)  # lit (a little specular)
    assert _pixel(frames["opaque"], asset, OPTIONS, behind).max() < 0.01 * expected
    assert _pixel(frames["raytrace"], asset, OPTIONS, behind).max() < 0.01 * expected
    assert np.allclose(_pixel(frames["raytrace"], asset, OPTIONS, through), got, rtol=RAYTRACE_TOLERANCE)


def _gltf_see_through_cards(path, glass_tint=(1.0, 0.5, 0.25), blend_alpha=0.5):
    """Two 2 x 0.8 m cards 1 m above the ground under the tilted sun: at z = -0.8 a clear
    glass (KHR_materials_transmission 1, base colour `glass_tint`), at z = +0.8 an alpha-blended
    matte one of alpha `blend_alpha`."""
    doc = json.loads(_gltf_mask_card(path).read_text())
    quad = [(-3.5, 0, 2.5), (2, 0, 2.5), (2, 0, -2.5), (-3.5, 0, -2.5)]
    cards = [[(-1, 1, z + 0.4), (1, 1, z + 0.4), (1, 1, z - 0.4), (-1, 1, z - 0.4)] for z in (-0.8, 0.8)]
    pos = np.array(quad + cards[0] + cards[1], np.float32)
    idx = np.array([(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7), (8, 9, 10), (8, 10, 11)], np.uint16).ravel()
    blob = pos.tobytes() + idx.tobytes()
    matte = doc["materials"][0]
    doc["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_transmission"]
    doc["materials"] = [matte,
                        {"pbrMetallicRoughness": {"baseColorFactor": [*glass_tint, 1], "metallicFactor": 0,
                                                  "roughnessFactor": 0},
                         "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0}},
                         "doubleSided": True},
                        {**matte, "alphaMode": "BLEND",
                         "pbrMetallicRoughness": {**matte["pbrMetallicRoughness"],
                                                  "baseColorFactor": [ALBEDO, ALBEDO, ALBEDO, blend_alpha]}}]
    doc["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1 + k, "material": k}]}
                     for k in range(3)]
    doc["nodes"] = [{"mesh": 0}, {"mesh": 1}, {"mesh": 2}, doc["nodes"][2]]
    doc["scenes"] = [{"nodes": [0, 1, 2, 3]}]
    for key in ("textures", "samplers", "images"):
        doc.pop(key)
    doc["buffers"] = [{"byteLength": len(blob),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}]
    doc["bufferViews"] = [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes}] + [
        {"buffer": 0, "byteOffset": pos.nbytes + 12 * k, "byteLength": 12} for k in range(3)]
    doc["accessors"] = [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                         "min": pos.min(0).tolist(), "max": pos.max(0).tolist()}] + [
        {"bufferView": 1 + k, "componentType": 5123, "count": 6, "type": "SCALAR"} for k in range(3)]
    path.write_text(json.dumps(doc))
    return path


def test_see_through_casters_tint_the_shadow_as_the_ray_tracer(tmp_path):
    """A transmissive caster lets through transmission x base colour, a blended one 1 - alpha
    (renderer.methods.trace_lights): the ground in their shadows is lit x (1, 0.5, 0.25) and
    x 0.5, in the raster and in the ray tracer (whose blended layer stops a shadow ray with
    probability alpha, so within sampling noise)."""
    dark = bake_environment(uniform.DARK, tmp_path, face_size=32)
    asset = build_baked(load_scene(_gltf_see_through_cards(tmp_path / "cards.gltf")), key="light-shadows-tint")
    shift = math.tan(SUN_TILT)
    lit = ALBEDO * 3.0 * math.cos(SUN_TILT) / math.pi
    under_glass = np.array([-shift, 0.0, -0.8])
    under_blend = np.array([-shift, 0.0, 0.8])
    frames = {"opaque": render(asset, dark, OPTIONS),
              "raytrace": render(asset, dark, dataclasses.replace(OPTIONS, method="raytrace", samples=64))}
    raster = frames["opaque"]
    assert raster.plan["light_shadows"].startswith("1 light(s)")
    glass = _pixel(raster, asset, OPTIONS, under_glass)
    blend = _pixel(raster, asset, OPTIONS, under_blend)
    assert np.allclose(glass, lit * np.array([1.0, 0.5, 0.25]), rtol=0.05), glass
    assert np.allclose(blend, lit * 0.5, rtol=0.05), blend
    traced = frames["raytrace"]
    assert np.allclose(_pixel(traced, asset, OPTIONS, under_glass), glass, rtol=RAYTRACE_TOLERANCE)
    assert np.allclose(_pixel(traced, asset, OPTIONS, under_blend), blend, rtol=0.1)  # noise


GLASS_ENTRY = (200, 80, 150)   # sRGB texel on the sphere's half toward the sun
GLASS_EXIT = (90, 210, 150)    # and on the half away from it


def _srgb_linear(c) -> np.ndarray:
    c = np.asarray(c, np.float64) / 255
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _gltf_glass_ball(path, colours=(GLASS_ENTRY, GLASS_EXIT), thin=False, centre=(0.0, 1.0, 0.0),
                     radius=0.45):
    """A closed UV sphere of clear glass (transmission 1, base colour factor white) over the
    ground quad under the tilted sun, its base-colour texture (2 texels, nearest) `colours[0]`
    on the hemisphere facing the sun and `colours[1]` on the other; volume glass
    (KHR_materials_volume, thickness 1) unless `thin` (transmission alone: thin-walled)."""
    doc = json.loads(_gltf_mask_card(path).read_text())
    toward = np.array([math.sin(SUN_TILT), math.cos(SUN_TILT), 0.0])
    lat, lon = np.meshgrid(np.linspace(0, math.pi, 33), np.linspace(0, 2 * math.pi, 65), indexing="ij")
    normal = np.stack([np.sin(lat) * np.cos(lon), np.cos(lat), np.sin(lat) * np.sin(lon)], -1).reshape(-1, 3)
    ball = np.asarray(centre) + radius * normal
    quad = np.array([(-3.5, 0, 2), (2, 0, 2), (2, 0, -2), (-3.5, 0, -2)], np.float64)
    pos = np.concatenate([quad, ball]).astype(np.float32)
    nrm = np.concatenate([np.tile([0.0, 1.0, 0.0], (4, 1)), normal]).astype(np.float32)
    uv = np.zeros((len(pos), 2), np.float32)
    uv[4:, 0] = np.where(normal @ toward > 0, 0.25, 0.75)
    uv[4:, 1] = 0.5
    tris = []
    for i in range(32):
        for j in range(64):
            a, b = 4 + i * 65 + j, 4 + (i + 1) * 65 + j
            tris += [(a, a + 1, b + 1), (a, b + 1, b)]  # outward winding (CCW from outside)
    ground = np.array([(0, 1, 2), (0, 2, 3)], np.uint32).ravel()
    sphere = np.array(tris, np.uint32).ravel()
    texels = np.full((1, 2, 4), 255.0)
    texels[0, 0, :3], texels[0, 1, :3] = colours
    image = _png_rgba(texels)
    blob = pos.tobytes() + nrm.tobytes() + uv.tobytes() + ground.tobytes() + sphere.tobytes()
    offsets = np.cumsum([0, pos.nbytes, nrm.nbytes, uv.nbytes, ground.nbytes, sphere.nbytes])
    glass = {"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0,
                                      "roughnessFactor": 0, "baseColorTexture": {"index": 0}},
             "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0},
                            **({} if thin else {"KHR_materials_volume": {"thicknessFactor": 1.0}})}}
    doc["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_volume"]
    doc["materials"] = [doc["materials"][0], glass]
    attrs = {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}
    doc["meshes"] = [{"primitives": [{"attributes": attrs, "indices": 3 + k, "material": k}]} for k in range(2)]
    doc["samplers"] = [{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}]
    doc["images"] = [{"uri": "data:image/png;base64," + base64.b64encode(image).decode()}]
    doc["buffers"] = [{"byteLength": len(blob),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}]
    doc["bufferViews"] = [{"buffer": 0, "byteOffset": int(offsets[k]), "byteLength": int(offsets[k + 1] - offsets[k])}
                          for k in range(5)]
    doc["accessors"] = [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                         "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
                        {"bufferView": 1, "componentType": 5126, "count": len(pos), "type": "VEC3"},
                        {"bufferView": 2, "componentType": 5126, "count": len(pos), "type": "VEC2"},
                        {"bufferView": 3, "componentType": 5125, "count": len(ground), "type": "SCALAR"},
                        {"bufferView": 4, "componentType": 5125, "count": len(sphere), "type": "SCALAR"}]
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("thin", [False, True], ids=["volume", "thin-walled"])
def test_textured_glass_ball_tints_its_shadow_per_crossing(tmp_path, thin):
    """A shadow ray through a closed glass ball crosses it twice, in at one texel and out at
    another, as a camera ray does (docs/material-extensions.md): volume glass lets through
    sqrt(c_in) x sqrt(c_out), a thin-walled ball two sheets, c_in x c_out. The ground at the
    centre of the ball's shadow is lit x that in the raster's tint atlas and in the ray
    tracer's shadow rays."""
    dark = bake_environment(uniform.DARK, tmp_path, face_size=32)
    asset = build_baked(load_scene(_gltf_glass_ball(tmp_path / "ball.gltf", thin=thin)),
                        key=f"light-shadows-glass-ball-{thin}")
    lit = ALBEDO * 3.0 * math.cos(SUN_TILT) / math.pi
    toward = np.array([math.sin(SUN_TILT), math.cos(SUN_TILT), 0.0])
    centre = _ground_hit(np.array([0.0, 1.0, 0.0]), toward)
    c_in, c_out = _srgb_linear(GLASS_ENTRY), _srgb_linear(GLASS_EXIT)
    through = c_in * c_out if thin else np.sqrt(c_in * c_out)
    raster = _pixel(render(asset, dark, OPTIONS), asset, OPTIONS, centre)
    assert np.allclose(raster, lit * through, rtol=0.05), (raster, lit * through)
    traced = render(asset, dark, dataclasses.replace(OPTIONS, method="raytrace", samples=16))
    assert np.allclose(_pixel(traced, asset, OPTIONS, centre), raster, rtol=RAYTRACE_TOLERANCE)
