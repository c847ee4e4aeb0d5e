"""USD surfaces drawn as usdview draws them (Hydra Storm, docs/usd.md "Back faces"): a
single-sided gprim is not culled (usdview's cullBackfaces is off by default) and its back
is shaded with the normal unflipped; a double-sided one turns the normal to the viewer;
`orientation = "leftHanded"` decides which side is the front. UsdPreviewSurface
displacement is not drawn, with a warning."""
from __future__ import annotations

import math

import numpy as np
import pytest

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
        int[] faceVertexIndices = INDICES
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        uniform token orientation = "ORIENTATION"
        uniform bool doubleSided = DOUBLE
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
            DISPLACEMENT
            token outputs:surface
        }
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 3
        bool inputs:normalize = 1
    }
}
"""
LIT = 0.5 / math.pi * 3.0  # albedo / pi x E, the card facing the light (and the camera)


def _stage(tmp_path, facing_camera: bool, double: bool, left: bool = False, displacement: str = ""):
    # counter-clockwise seen from +Z (the camera and the light's side) is the front when
    # right-handed; leftHanded makes the clockwise order the front
    ccw = facing_camera != left
    text = (CARD.replace("INDICES", "[0, 1, 2, 3]" if ccw else "[0, 3, 2, 1]")
            .replace("ORIENTATION", "leftHanded" if left else "rightHanded")
            .replace("DOUBLE", "1" if double else "0").replace("DISPLACEMENT", displacement))
    path = tmp_path / f"card_{int(facing_camera)}{int(double)}{int(left)}.usda"
    path.write_text(text)
    return path


def _shot(path, tmp_path):
    from cli.main import main
    out = tmp_path / f"{path.stem}.npy"
    assert main(["render", str(path), "--out", str(out), "--size", "32", "--yaw", "0",
                 "--pitch", "0", "--tonemap", "none", "--msaa", "0", "--background", "transparent",
                 "--cache", str(tmp_path / "cache")]) == 0
    return np.load(out).astype(np.float64)[12:20, 12:20]


@pytest.mark.parametrize("left", [False, True])
def test_back_faces_as_storm_draws_them(tmp_path, left):
    """Storm (bench usd on this stage: FLIP 0.019 -> 0.007 with this rule): the front lit;
    a single-sided back drawn, unlit by a light on the other side (its normal points
    away); a double-sided back lit as a front. Before, ours culled the single-sided back."""
    front = _shot(_stage(tmp_path, True, False, left), tmp_path)
    back = _shot(_stage(tmp_path, False, False, left), tmp_path)
    back_double = _shot(_stage(tmp_path, False, True, left), tmp_path)
    np.testing.assert_allclose(front[..., :3], LIT, rtol=0.02)
    assert back[..., 3].min() > 0.99  # drawn, not culled
    assert back[..., :3].max() < 0.02 * LIT  # and dark: the light is behind its normal
    np.testing.assert_allclose(back_double[..., :3], LIT, rtol=0.02)
    assert back_double[..., 3].min() > 0.99


def test_single_sided_material_flags(tmp_path):
    single = load_scene(_stage(tmp_path, True, False))
    double = load_scene(_stage(tmp_path, True, True))
    (m1,) = [m for m in single.materials if m.name.endswith("Grey")]
    (m2,) = [m for m in double.materials if m.name.endswith("Grey")]
    assert m1.show_back_faces and not m1.double_sided
    assert m2.double_sided


def test_displacement_is_not_drawn_and_says_so(tmp_path):
    scene = load_scene(_stage(tmp_path, True, False, displacement="float inputs:displacement = 0.3"))
    assert any("displacement" in w and "Grey" in w for w in scene.warnings)
    flat = load_scene(_stage(tmp_path, True, True, displacement="float inputs:displacement = 0"))
    assert not any("displacement" in w for w in flat.warnings)


# -- texture colour spaces (UsdUVTexture sourceColorSpace), as Storm resolves them

GREY_CARD = """#usda 1.0
def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] ( interpolation = "vertex" )
    rel material:binding = </M>
}
def Material "M"
{
    token outputs:surface.connect = </M/S.outputs:surface>
    def Shader "S"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </M/T.outputs:rgb>
        float inputs:roughness.connect = </M/T.outputs:r>
        token outputs:surface
    }
    def Shader "T"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./FILE@
        token inputs:sourceColorSpace = "SPACE"
        float3 outputs:rgb
        float outputs:r
    }
}
"""


def _gama(png: bytes, gamma: float) -> bytes:
    """`png` with a gAMA chunk after IHDR."""
    import struct
    import zlib
    body = b"gAMA" + struct.pack(">I", round(gamma * 100000))
    return png[:33] + struct.pack(">I", 4) + body + struct.pack(">I", zlib.crc32(body)) + png[33:]


def _png16(channels: int) -> bytes:
    """A 16-bit PNG of grey 128 x 257 with `channels` (Pillow writes 16-bit grey only)."""
    import struct
    import zlib
    px = np.full((8, 8, channels), 128 * 257, ">u2")
    raw = b"".join(b"\x00" + px[y].tobytes() for y in range(8))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    header = struct.pack(">IIBBBBB", 8, 8, 16, {1: 0, 2: 4, 3: 2, 4: 6}[channels], 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
            + chunk(b"IEND", b""))


def _grey_image(tmp_path, kind: str) -> str:
    """An 8 x 8 image of grey 128 (8-bit) or 128 x 257 (16-bit), written as `kind`."""
    import io

    from PIL import Image
    g = np.full((8, 8), 128, np.uint8)
    images = {"l.png": Image.fromarray(g, "L"), "la.png": Image.fromarray(np.stack([g, g], -1), "LA"),
              "rgb.png": Image.fromarray(np.stack([g] * 3, -1), "RGB"),
              "rgba.png": Image.fromarray(np.stack([g] * 3 + [g * 0 + 255], -1), "RGBA"),
              "16.png": Image.fromarray(np.full((8, 8), 128 * 257, np.uint16)),
              "l.jpg": Image.fromarray(g, "L"), "rgb.jpg": Image.fromarray(np.stack([g] * 3, -1), "RGB")}
    base = kind.split("+")[0]
    if base in ("rgb16.png", "rgba16.png"):
        data = _png16(3 if base == "rgb16.png" else 4)
    else:
        buf = io.BytesIO()
        images[base].save(buf, format="JPEG" if base.endswith(".jpg") else "PNG", quality=100)
        data = buf.getvalue()
    if kind.endswith("+g1"):
        data = _gama(data, 1.0)
    elif kind.endswith("+g045"):
        data = _gama(data, 0.45455)
    name = kind.replace("+", "_")
    (tmp_path / name).write_bytes(data)
    return name


# What Storm draws (bench/storm_worker.py on a stage of such cards, lit by a distant light:
# 184 where the texel is read as linear 0.502, 125 where it is sRGB-decoded to 0.216).
STORM_SRGB = [("l.png", "auto", False), ("l.png", "sRGB", True), ("l.png", "raw", False),
              ("la.png", "auto", False), ("rgb.png", "auto", True), ("rgb.png", "raw", False),
              ("16.png", "auto", False), ("16.png", "sRGB", True), ("rgb.png+g1", "auto", False),
              ("l.png+g045", "auto", True), ("rgba.png", "auto", True), ("l.jpg", "auto", False),
              ("rgb.jpg", "auto", True), ("rgb.png+g1", "sRGB", True), ("la.png", "sRGB", True),
              ("rgb16.png", "auto", True), ("rgba16.png", "auto", True), ("rgb16.png", "raw", False)]


@pytest.mark.parametrize("kind,space,srgb", STORM_SRGB)
def test_source_color_space_as_storm_reads_it(tmp_path, kind, space, srgb):
    """Base colour (an sRGB slot) and roughness (a data slot) from one texture: each reads
    the texel as Storm does, 0.216 when sRGB-decoded and 0.502 as it is, within the 8-bit
    re-encoding's half step."""
    from core.colour import srgb_to_linear
    name = _grey_image(tmp_path, kind)
    path = tmp_path / f"card_{name}_{space}.usda"
    path.write_text(GREY_CARD.replace("FILE", name).replace("SPACE", space))
    scene = load_scene(path)
    (mat,) = [m for m in scene.materials if m.name.endswith("M")]
    want = float(srgb_to_linear(np.uint8(128))) if srgb else 128 / 255
    base = scene.textures[mat.base_color_texture.texture].image
    read_as_base = float(srgb_to_linear(base[..., :3]).mean())  # the sRGB slot decodes
    assert read_as_base == pytest.approx(want, abs=0.004)
    rough = scene.textures[mat.metallic_roughness_texture.texture].image
    assert float(rough[..., 1].mean()) / 255 == pytest.approx(want, abs=0.004)  # read as is


def test_auto_rule_reads_image_headers():
    from pipeline.usd.materials import auto_source_srgb
    assert not auto_source_srgb(b"\x76\x2f\x31\x01" + bytes(40))  # OpenEXR: float, linear


def test_exr_reads_linear_in_data_slots(tmp_path):
    """An OpenEXR is linear to Storm under auto: roughness from one reads the float value
    (our 8-bit decode holds it sRGB-encoded, so the data slot gets it decoded back)."""
    import OpenEXR
    rgb = np.full((2, 2, 3), 0.3, np.float32)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"RGB": rgb}) as f:
        f.write(str(tmp_path / "r.exr"))
    path = tmp_path / "exr.usda"
    path.write_text(GREY_CARD.replace("FILE", "r.exr").replace("SPACE", "auto"))
    scene = load_scene(path)
    (mat,) = [m for m in scene.materials if m.name.endswith("M")]
    rough = scene.textures[mat.metallic_roughness_texture.texture].image
    assert float(rough[..., 1].mean()) / 255 == pytest.approx(0.3, abs=0.005)


GLOSSY_CARD = """#usda 1.0
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
        rel material:binding = </World/Glossy>
    }
    def Material "Glossy"
    {
        token outputs:surface.connect = </World/Glossy/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = DIFFUSE
            float inputs:roughness = 0.4
            float inputs:opacity = OPACITY
            token outputs:surface
        }
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 3
        bool inputs:normalize = 1
    }
}
"""


def _glossy(tmp_path, diffuse: float, opacity: float):
    path = tmp_path / f"glossy_{diffuse}_{opacity}.usda"
    path.write_text(GLOSSY_CARD.replace("DIFFUSE", f"({diffuse}, {diffuse}, {diffuse})")
                    .replace("OPACITY", str(opacity)))
    return path


def test_preview_surface_opacity_fades_diffuse_only(tmp_path):
    """Storm blends a translucent UsdPreviewSurface premultiplied: diffuse x opacity +
    specular, over 1 - opacity of what is behind (bench usd on AlphaBlendSortTest and on a
    0.25-opacity probe, docs/usd.md "Translucency"); glTF's BLEND fades the whole colour. The
    sun behind the camera puts its highlight all over the card; the linear frame holds
    premultiplied colour, so the translucent card must read 0.25 x diffuse + specular."""
    (mat,) = [m for m in load_scene(_glossy(tmp_path, 0.5, 0.25)).materials
              if m.name.endswith("Glossy")]
    assert mat.alpha_mode == "BLEND" and mat.opacity_premultiplied
    opaque = _shot(_glossy(tmp_path, 0.5, 1.0), tmp_path)
    specular = _shot(_glossy(tmp_path, 0.0, 1.0), tmp_path)  # a black card: its highlight alone
    sheet = _shot(_glossy(tmp_path, 0.5, 0.25), tmp_path)
    diffuse = opaque[..., :3] - specular[..., :3]
    assert specular[..., :3].min() > 0.2 * diffuse.max()  # a highlight worth telling apart
    np.testing.assert_allclose(sheet[..., :3], 0.25 * diffuse + specular[..., :3], rtol=0.03)
    np.testing.assert_allclose(sheet[..., 3], 0.25, atol=0.01)


CARD_OVER_CHECKER = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{
    def Mesh "Checker"
    {
        int[] faceVertexCounts = [4, 4, 4, 4]
        int[] faceVertexIndices = [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6, 4, 5, 8, 7]
        point3f[] points = [(-2, -2, -1), (0, -2, -1), (2, -2, -1), (-2, 0, -1), (0, 0, -1),
                            (2, 0, -1), (-2, 2, -1), (0, 2, -1), (2, 2, -1)]
        color3f[] primvars:displayColor = [(0.9, 0.9, 0.9), (0.05, 0.05, 0.05),
                                           (0.05, 0.05, 0.05), (0.9, 0.9, 0.9)] (interpolation = "uniform")
        uniform bool doubleSided = 1
    }
    def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1.2, -1.2, 0), (1.2, -1.2, 0), (1.2, 1.2, 0), (-1.2, 1.2, 0)]
        rel material:binding = </World/Glossy>
    }
    def Material "Glossy"
    {
        token outputs:surface.connect = </World/Glossy/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.8, 0.3, 0.2)
            float inputs:roughness = 0.4
            float inputs:opacity = 0.3
            token outputs:surface
        }
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 3
        bool inputs:normalize = 1
    }
}
"""


def _frame(path, tmp_path, *extra: str, tag: str = ""):
    from cli.main import main
    out = tmp_path / f"{path.stem}_{'_'.join(extra) or 'raster'}{tag}.npy"
    assert main(["render", str(path), "--out", str(out), "--size", "40", "--yaw", "0",
                 "--pitch", "0", "--tonemap", "none", "--background", "transparent",
                 "--cache", str(tmp_path / "cache"), *extra]) == 0
    return np.load(out).astype(np.float64)


@pytest.mark.parametrize("integrator", ["tree", "path"])
def test_raytrace_blends_preview_surface_as_the_raster(tmp_path, integrator):
    """The ray tracer blends a translucent UsdPreviewSurface premultiplied as the raster and
    Storm do: opacity x diffuse + its whole specular over 1 - opacity of what is behind (here
    a checker, the sun behind the camera lighting both). Before, it passed rays stochastically
    with probability 1 - opacity and shaded the rest whole, fading the specular too: the card's
    centre read 0.61 / 0.47 / 0.45 (tree) where the raster reads 0.85 / 0.71 / 0.68. The
    tracer's environment light differs a little from the raster's split sum (and the path
    tracer has noise): the card's centre and the whole frame, means per channel (linear),
    within 3%."""
    path = tmp_path / "card_over_checker.usda"
    path.write_text(CARD_OVER_CHECKER)
    raster = _frame(path, tmp_path, "--msaa", "0")
    extra = ["--method", "raytrace", "--integrator", integrator]
    if integrator == "path":
        extra += ["--samples", "32", "--noise", "0"]
    traced = _frame(path, tmp_path, *extra)
    centre = (slice(15, 25), slice(15, 25))
    want, got = raster[centre][..., :3].mean((0, 1)), traced[centre][..., :3].mean((0, 1))
    np.testing.assert_allclose(got, want, rtol=0.03)
    np.testing.assert_allclose(traced[..., :3].mean((0, 1)), raster[..., :3].mean((0, 1)), rtol=0.03)


def test_raytrace_premultiplied_card_covers_by_its_opacity(tmp_path):
    """Over nothing, the card's pixels cover by its opacity (alpha 0.25, as the raster's and
    Storm's), and its colour is 0.25 x diffuse + specular (the raster's test above): the
    straight-on ray behind it finds no background."""
    sheet = _frame(_glossy(tmp_path, 0.5, 0.25), tmp_path, "--method", "raytrace")
    raster = _frame(_glossy(tmp_path, 0.5, 0.25), tmp_path, "--msaa", "0")
    centre = (slice(15, 25), slice(15, 25))
    np.testing.assert_allclose(sheet[centre][..., 3], 0.25, atol=0.01)
    np.testing.assert_allclose(sheet[centre][..., :3].mean((0, 1)),
                               raster[centre][..., :3].mean((0, 1)), rtol=0.03)


@pytest.mark.parametrize("integrator", ["tree", "path"])
def test_premultiplied_split_compiled_matches_numpy_twin(tmp_path, monkeypatch, integrator):
    """The split of a premultiplied blend (opacity into the diffuse share, the ray that goes
    on straight behind) is the same with the compiled shading and its numpy twin."""
    from renderer.methods import path_trace, raytrace
    path = tmp_path / "card_over_checker.usda"
    path.write_text(CARD_OVER_CHECKER)
    extra = ["--method", "raytrace", "--integrator", integrator, "--size", "24"]
    if integrator == "path":
        extra += ["--samples", "4", "--noise", "0"]
    fast = _frame(path, tmp_path, *extra)
    monkeypatch.setattr(raytrace if integrator == "tree" else path_trace, "KERNEL", False)
    slow = _frame(path, tmp_path, *extra, tag="_numpy")
    assert fast[..., :3].max() > 0.05
    np.testing.assert_allclose(fast, slow, atol=1e-5)


MTLX_CARD = """#usda 1.0
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
        rel material:binding = </World/M>
    }
    def Material "M"
    {
        token outputs:mtlx:surface.connect = </World/M/S.outputs:out>
        def Shader "S"
        {
            uniform token info:id = "ND_ID"
            INPUTS
            token outputs:out
        }
    }
}
"""


@pytest.mark.parametrize("node,inputs,premultiplied", [
    ("UsdPreviewSurface_surfaceshader", "float inputs:opacity = 0.3", True),
    ("standard_surface_surfaceshader", "color3f inputs:opacity = (0.3, 0.3, 0.3)", False),
])
def test_materialx_opacity_blends_by_its_definition(tmp_path, node, inputs, premultiplied):
    """MaterialX's library (bxdf/usd_preview_surface.mtlx, as bpy's usdMtlx ships it) puts
    ND_UsdPreviewSurface's whole specular over mix(transmission, diffuse, opacity): the
    premultiplied rule; standard_surface's opacity is the surface's presence: the whole
    shading fades (glTF's blend)."""
    path = tmp_path / f"{node}.usda"
    path.write_text(MTLX_CARD.replace("ID", node).replace("INPUTS", inputs))
    (mat,) = [m for m in load_scene(path).materials if m.name.endswith("M")]
    assert mat.alpha_mode == "BLEND" and mat.opacity_premultiplied == premultiplied


def test_preview_surface_presence_mode_fades_the_whole_colour(tmp_path):
    """opacityMode "presence" fades the whole shading in Storm's previewSurface (c *= opacity);
    "transparent", the default, fades the diffuse alone."""
    text = GLOSSY_CARD.replace("DIFFUSE", "(0.5, 0.5, 0.5)").replace("OPACITY", "0.25")
    presence = tmp_path / "presence.usda"
    presence.write_text(text.replace("float inputs:roughness = 0.4",
                                     'float inputs:roughness = 0.4\n            uniform token inputs:opacityMode = "presence"'))
    (mat,) = [m for m in load_scene(presence).materials if m.name.endswith("Glossy")]
    assert mat.alpha_mode == "BLEND" and not mat.opacity_premultiplied
    (mat,) = [m for m in load_scene(_glossy(tmp_path, 0.5, 0.25)).materials if m.name.endswith("Glossy")]
    assert mat.opacity_premultiplied
