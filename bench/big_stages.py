"""Big studio-style stand-ins for the cold first image: `python -m bench.big_stages DIR` writes

- DIR/usd/big_chess/chess.usda: a chess-like set of about 1 M triangles, 32 lathed pieces
  (six shapes, quads, faceVarying normals and st as a DCC exports them), each piece a reference
  to its shape's .usdc layer (not instanceable, as a hand-placed set is), on a board of 64
  squares; MaterialX materials (`ND_standard_surface_surfaceshader` networks in USD, colour and
  roughness read from `ND_image_*` nodes) and one referenced .mtlx document for the board's frame;
- DIR/usd/big_kit/kit.usda: a vehicle kit, one root referencing 32 part layers (bodies, doors,
  seats, lamps ...; wheels and bolts `instanceable`, 4 and 24 times), a material-only layer the
  parts share, a `vehicle` variant set choosing which body, roof and bumper parts load (23 of
  the 32 compose) and a `rim` set on each wheel;
- DIR/usd/big_blocks/blocks.usdc: a block world of 10,143 cube meshes (6 quads each, faceVarying
  st into one texture atlas), 320 materials (UsdPreviewSurface, each reading the atlas through
  its own UsdTransform2d tile and a `scale` tint) and 8 further textures;

then `ASSET_PREVIEW_STORM_PYTHON=... asset-preview bench usd --assets DIR --stages big_` renders
each with ours and Storm, and `python -m bench.usd_cold STAGE ...` splits our cold time per phase.
The stages are deterministic (fixed seeds) so before/after runs read the same bytes.
"""
from __future__ import annotations

import math
import sys
import textwrap
from pathlib import Path

import numpy as np
from PIL import Image

HEADER = '#usda 1.0\n(\n    metersPerUnit = {mpu}\n    upAxis = "Y"\n    defaultPrim = "{prim}"\n)\n'


# -- geometry helpers ------------------------------------------------------------------------------
def lathe(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(points, faceVertexCounts, faceVertexIndices, faceVarying normals, faceVarying st) of the
    surface swept by `profile` (K x 2: radius, height) around Y in `segments` quads per ring."""
    k = len(profile)
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    r, y = profile[:, 0], profile[:, 1]
    pts = np.stack([r[:, None] * np.cos(a)[None], np.repeat(y[:, None], segments, 1),
                    r[:, None] * np.sin(a)[None]], -1).reshape(-1, 3)
    # profile tangent -> outward normal in the (r, y) plane, then rotated around
    dr, dy = np.gradient(r), np.gradient(y)
    ln = np.maximum(np.hypot(dr, dy), 1e-9)
    nr, ny = dy / ln, -dr / ln
    vnorm = np.stack([nr[:, None] * np.cos(a)[None], np.repeat(ny[:, None], segments, 1),
                      nr[:, None] * np.sin(a)[None]], -1).reshape(-1, 3)
    j, i = np.meshgrid(np.arange(k - 1), np.arange(segments), indexing="ij")
    i1 = (i + 1) % segments
    quads = np.stack([j * segments + i, (j + 1) * segments + i, (j + 1) * segments + i1,
                      j * segments + i1], -1).reshape(-1, 4)
    fvi = quads.ravel()
    normals = vnorm[fvi]
    # st: u around (the seam column repeats at u = 1, so st splits there), v along the profile
    u = np.stack([i, i, i + 1, i + 1], -1).reshape(-1) / segments
    v = np.stack([j, j + 1, j + 1, j], -1).reshape(-1) / (k - 1)
    st = np.stack([u, v], -1)
    return pts.astype(np.float32), np.full(len(quads), 4, np.int32), fvi.astype(np.int32), \
        normals.astype(np.float32), st.astype(np.float32)


def _piece_profile(kind: str, rings: int) -> np.ndarray:
    """(radius, height) of a piece's silhouette, bottom to top, closed at the axis on top."""
    t = np.linspace(0.0, 1.0, rings)
    base = 0.38 - 0.08 * np.clip(t / 0.12, 0, 1)
    waist = 0.3 - 0.18 * np.sin(np.clip((t - 0.12) / 0.6, 0, 1) * np.pi / 2)
    h = {"pawn": 0.9, "rook": 1.1, "knight": 1.2, "bishop": 1.35, "queen": 1.55, "king": 1.7}[kind]
    r = np.where(t < 0.12, base, waist)
    top = np.clip((t - 0.72) / 0.28, 0, 1)
    if kind == "pawn":
        r = np.where(t > 0.72, 0.2 * np.sqrt(np.maximum(1 - (2 * top - 1) ** 2, 0)) + 0.0, r)
    elif kind == "rook":
        r = np.where(t > 0.72, 0.22 + 0.03 * np.sign(np.sin(top * 9 * np.pi)), r)
    elif kind == "knight":
        r = np.where(t > 0.72, 0.2 * (1 - top) + 0.06 * np.sin(top * 5 * np.pi) ** 2, r)
    elif kind == "bishop":
        r = np.where(t > 0.72, 0.17 * np.sqrt(np.maximum(1 - top ** 1.5, 0)), r)
    else:  # queen, king: a crown
        r = np.where(t > 0.72, 0.2 + 0.04 * np.cos(top * 6 * np.pi) - 0.1 * top, r)
    r = r.astype(np.float64)
    r[-1] = 0.0  # closed at the axis
    return np.stack([r, t * h], -1)


def _set_mesh(layer, path: str, points, counts, fvi, normals=None, st=None, extent=True) -> None:
    from pxr import Sdf, Vt
    spec = Sdf.CreatePrimInLayer(layer, path)
    spec.specifier, spec.typeName = Sdf.SpecifierDef, "Mesh"

    def attr(name, tname, value, interp=None, variability=Sdf.VariabilityVarying):
        a = Sdf.AttributeSpec(spec, name, tname, variability)
        a.default = value
        if interp:
            a.SetInfo("interpolation", interp)
    attr("points", Sdf.ValueTypeNames.Point3fArray, Vt.Vec3fArray.FromNumpy(points))
    attr("faceVertexCounts", Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(counts))
    attr("faceVertexIndices", Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(fvi))
    attr("subdivisionScheme", Sdf.ValueTypeNames.Token, "none", variability=Sdf.VariabilityUniform)
    if normals is not None:
        attr("primvars:normals", Sdf.ValueTypeNames.Normal3fArray, Vt.Vec3fArray.FromNumpy(normals), "faceVarying")
    if st is not None:
        attr("primvars:st", Sdf.ValueTypeNames.TexCoord2fArray, Vt.Vec2fArray.FromNumpy(st), "faceVarying")
    if extent:
        lo, hi = points.min(0), points.max(0)
        attr("extent", Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray.FromNumpy(np.stack([lo, hi])))


def _noise_image(size: int, rgb, seed: int, grain: float = 0.25) -> Image.Image:
    """A wood-like grain of `rgb`, deterministic per seed."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    w = np.sin((x * 40 + 3 * np.sin(y * 7 + rng.uniform(0, 6))) * np.pi) * 0.5 + 0.5
    n = np.kron(rng.random((size // 8, size // 8)), np.ones((8, 8)))[:size, :size]
    v = (1 - grain) + grain * (0.6 * w + 0.4 * n)
    return Image.fromarray(np.round(np.clip(v[..., None] * np.asarray(rgb), 0, 1) * 255).astype(np.uint8), "RGB")


# -- 1. chess ---------------------------------------------------------------------------------------
PIECES = ("pawn", "rook", "knight", "bishop", "queen", "king")
BACK_ROW = ("rook", "knight", "bishop", "queen", "king", "bishop", "knight", "rook")


def _mtlx_material(name: str, color_tex: str | None, rough_tex: str | None, color, rough: float,
                   metal: float = 0.0, coat: float = 0.0) -> str:
    nodes, base, rgh = "", f"            color3f inputs:base_color = {tuple(color)}\n", \
        f"            float inputs:specular_roughness = {rough}\n"
    if color_tex:
        base = f"            color3f inputs:base_color.connect = </Chess/Looks/{name}/Color.outputs:out>\n"
        nodes += (f'        def Shader "Color"\n        {{\n            uniform token info:id = "ND_image_color3"\n'
                  f'            asset inputs:file = @{color_tex}@ ( colorSpace = "srgb_texture" )\n'
                  f'            color3f outputs:out\n        }}\n')
    if rough_tex:
        rgh = f"            float inputs:specular_roughness.connect = </Chess/Looks/{name}/Rough.outputs:out>\n"
        nodes += (f'        def Shader "Rough"\n        {{\n            uniform token info:id = "ND_image_float"\n'
                  f'            asset inputs:file = @{rough_tex}@ ( colorSpace = "raw" )\n'
                  f'            float outputs:out\n        }}\n')
    return (f'    def Material "{name}"\n    {{\n'
            f'        token outputs:mtlx:surface.connect = </Chess/Looks/{name}/Surface.outputs:out>\n'
            f'        def Shader "Surface"\n        {{\n'
            f'            uniform token info:id = "ND_standard_surface_surfaceshader"\n{base}{rgh}'
            f'            float inputs:metalness = {metal}\n            float inputs:coat = {coat}\n'
            f'            float inputs:specular = 0.5\n            token outputs:out\n        }}\n{nodes}    }}\n')


def _component_layer(path: Path, name: str):
    """A new centimetre, Y-up layer at `path` whose default prim is the component Xform /name."""
    from pxr import Sdf
    layer = Sdf.Layer.CreateNew(str(path))
    layer.defaultPrim = name
    layer.pseudoRoot.SetInfo("metersPerUnit", 0.01)
    layer.pseudoRoot.SetInfo("upAxis", "Y")
    root = Sdf.CreatePrimInLayer(layer, "/" + name)
    root.specifier, root.typeName = Sdf.SpecifierDef, "Xform"
    root.SetInfo("kind", "component")
    return layer, root


def write_chess(folder: Path, segments: int = 128, rings: int = 121) -> Path:
    """~1 M triangles: 32 pieces x (rings - 1) x segments quads, each quad two triangles."""
    d = folder / "usd" / "big_chess"
    (d / "pieces").mkdir(parents=True, exist_ok=True)
    (d / "tex").mkdir(exist_ok=True)
    for kind in PIECES:
        path = d / "pieces" / f"{kind}.usdc"
        layer, root = _component_layer(path, "Piece")
        pts, counts, fvi, normals, st = lathe(_piece_profile(kind, rings), segments)
        _set_mesh(layer, "/Piece/Geom", pts * 6.0, counts, fvi, normals, st)  # 6 cm squares
        layer.Save()
    _noise_image(1024, (0.93, 0.88, 0.78), 1).save(d / "tex" / "light_color.png")
    _noise_image(1024, (0.25, 0.16, 0.10), 2).save(d / "tex" / "dark_color.png")
    Image.fromarray((np.asarray(_noise_image(1024, (1, 1, 1), 3, 0.5))[..., 0] * 0.6).astype(np.uint8),
                    "L").save(d / "tex" / "rough.png")
    y, x = np.mgrid[0:2048, 0:2048] // 256
    checker = ((x + y) % 2).astype(bool)
    grain = np.asarray(_noise_image(2048, (1, 1, 1), 4, 0.3), np.float32) / 255
    squares = np.where(checker[..., None], grain * (0.9, 0.85, 0.75), grain * (0.18, 0.12, 0.08))
    Image.fromarray(np.round(squares * 255).astype(np.uint8), "RGB").save(d / "tex" / "board_color.png")
    (d / "frame.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.38">\n'
        '  <standard_surface name="SR_frame" type="surfaceshader">\n'
        '    <input name="base_color" type="color3" value="0.12, 0.08, 0.05" />\n'
        '    <input name="specular_roughness" type="float" value="0.35" />\n'
        '    <input name="coat" type="float" value="0.6" />\n'
        '  </standard_surface>\n'
        '  <surfacematerial name="Frame" type="material">\n'
        '    <input name="surfaceshader" type="surfaceshader" nodename="SR_frame" />\n'
        '  </surfacematerial>\n</materialx>\n')
    looks = (_mtlx_material("Light", "./tex/light_color.png", "./tex/rough.png", (0.9, 0.85, 0.75), 0.3, coat=0.3)
             + _mtlx_material("Dark", "./tex/dark_color.png", "./tex/rough.png", (0.2, 0.12, 0.08), 0.3, coat=0.3)
             + _mtlx_material("Board", "./tex/board_color.png", None, (0.5, 0.5, 0.5), 0.25, coat=0.5))
    body = []
    for side, z, row_pawn, look in (("W", 0, 1, "Light"), ("B", 7, 6, "Dark")):
        for col in range(8):
            for kind, row in ((BACK_ROW[col], z), ("pawn", row_pawn)):
                name = f"{side}_{kind}_{col}"
                body.append(
                    f'    def "{name}" (\n        prepend apiSchemas = ["MaterialBindingAPI"]\n'
                    f'        references = @./pieces/{kind}.usdc@\n    )\n    {{\n'
                    f'        double3 xformOp:translate = ({(col - 3.5) * 6}, 1, {(row - 3.5) * 6})\n'
                    f'        float xformOp:rotateY = {0 if side == "W" else 180}\n'
                    f'        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]\n'
                    f'        rel material:binding = </Chess/Looks/{look}>\n    }}\n')
    # the board: 64 squares of one mesh (st over the checker texture) and a frame
    n = 9
    gx, gz = np.meshgrid(np.linspace(-24, 24, n), np.linspace(-24, 24, n))
    bpts = np.stack([gx.ravel(), np.ones(n * n), gz.ravel()], -1)
    bst = np.stack([(gx.ravel() + 24) / 48, (gz.ravel() + 24) / 48], -1)
    q = [(j * n + i, (j + 1) * n + i, (j + 1) * n + i + 1, j * n + i + 1) for j in range(8) for i in range(8)]
    fmt = lambda a: ", ".join("(" + ", ".join(f"{v:.6g}" for v in row) + ")" for row in a)  # noqa: E731
    board = (f'    def Mesh "Board" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n    {{\n'
             f'        int[] faceVertexCounts = [{", ".join(["4"] * 64)}]\n'
             f'        int[] faceVertexIndices = [{", ".join(str(v) for f in q for v in f)}]\n'
             f'        point3f[] points = [{fmt(bpts)}]\n'
             f'        texCoord2f[] primvars:st = [{fmt(bst)}] ( interpolation = "vertex" )\n'
             f'        uniform token subdivisionScheme = "none"\n'
             f'        rel material:binding = </Chess/Looks/Board>\n    }}\n'
             f'    def Cube "Frame" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n    {{\n'
             f'        double size = 1\n        double3 xformOp:translate = (0, 0, 0)\n'
             f'        float3 xformOp:scale = (54, 1.9, 54)\n'
             f'        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]\n'
             f'        rel material:binding = </Chess/FrameLook/Materials/Frame>\n    }}\n')
    path = d / "chess.usda"
    path.write_text(HEADER.format(mpu=0.01, prim="Chess") + 'def Xform "Chess" ( kind = "assembly" )\n{\n'
                    + '    def Scope "Looks"\n    {\n' + textwrap.indent(looks, "    ")
                    + '    }\n    def Scope "FrameLook" ( references = @./frame.mtlx@</MaterialX> )\n    {\n    }\n'
                    + board + "".join(body) + "}\n")
    return path


# -- 2. kit -----------------------------------------------------------------------------------------
def _box(size, center=(0, 0, 0)) -> tuple:
    sx, sy, sz = np.asarray(size) / 2
    c = np.asarray(center)
    p = np.array([[-sx, -sy, -sz], [sx, -sy, -sz], [sx, sy, -sz], [-sx, sy, -sz],
                  [-sx, -sy, sz], [sx, -sy, sz], [sx, sy, sz], [-sx, sy, sz]]) + c
    f = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]])
    return p.astype(np.float32), np.full(6, 4, np.int32), f.ravel().astype(np.int32)


def _rounded(size, center, segments: int, seed: int) -> tuple:
    """A rounded, slightly dented box (a lathe squashed into `size`), a body panel's share of triangles."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, segments // 2 + 1)
    prof = np.stack([np.sin(t * np.pi) ** 0.35 * 0.5 + 1e-3, t - 0.5], -1)
    prof[0, 0] = prof[-1, 0] = 0.0
    pts, counts, fvi, normals, st = lathe(prof, segments)
    ang = np.arctan2(pts[:, 2], pts[:, 0])
    squash = 1.0 / np.maximum(np.abs(np.cos(ang)), np.abs(np.sin(ang))) ** 0.8  # towards a box
    pts[:, 0] *= squash
    pts[:, 2] *= squash
    pts *= 1 + 0.01 * rng.standard_normal(pts.shape).astype(np.float32)
    return (pts * np.asarray(size, np.float32) + np.asarray(center, np.float32)), counts, fvi, normals, st


KIT_LOOKS = {"Paint_Red": (0.7, 0.05, 0.04, 0.25, 0.0), "Paint_Blue": (0.05, 0.12, 0.6, 0.25, 0.0),
             "Paint_Green": (0.1, 0.45, 0.12, 0.3, 0.0), "Chrome": (0.9, 0.9, 0.92, 0.1, 1.0),
             "Rubber": (0.03, 0.03, 0.03, 0.8, 0.0), "Glass": (0.8, 0.9, 0.95, 0.05, 0.0),
             "Seat": (0.35, 0.2, 0.12, 0.7, 0.0), "Lamp": (1.0, 0.95, 0.8, 0.2, 0.0),
             "Decal": (1.0, 1.0, 1.0, 0.4, 0.0)}


def write_kit(folder: Path, body_segments: int = 96) -> Path:
    from pxr import Sdf
    d = folder / "usd" / "big_kit"
    (d / "parts").mkdir(parents=True, exist_ok=True)
    (d / "tex").mkdir(exist_ok=True)
    _noise_image(512, (1, 1, 1), 11, 0.4).save(d / "tex" / "decal.png")
    mats = []
    for name, (r, g, b, rough, metal) in KIT_LOOKS.items():
        tex = ""
        color = f"color3f inputs:diffuseColor = ({r}, {g}, {b})"
        if name == "Decal":
            color = f"color3f inputs:diffuseColor.connect = </Looks/{name}/Tex.outputs:rgb>"
            tex = (f'        def Shader "Tex"\n        {{\n            uniform token info:id = "UsdUVTexture"\n'
                   f'            asset inputs:file = @../tex/decal.png@\n'
                   f'            float2 inputs:st.connect = </Looks/{name}/St.outputs:result>\n'
                   f'            float3 outputs:rgb\n        }}\n'
                   f'        def Shader "St"\n        {{\n            uniform token info:id = "UsdPrimvarReader_float2"\n'
                   f'            string inputs:varname = "st"\n            float2 outputs:result\n        }}\n')
        opacity = "            float inputs:opacity = 0.3\n" if name == "Glass" else ""
        mats.append(f'    def Material "{name}"\n    {{\n'
                    f'        token outputs:surface.connect = </Looks/{name}/S.outputs:surface>\n'
                    f'        def Shader "S"\n        {{\n            uniform token info:id = "UsdPreviewSurface"\n'
                    f'            {color}\n            float inputs:roughness = {rough}\n'
                    f'            float inputs:metallic = {metal}\n{opacity}            token outputs:surface\n'
                    f'        }}\n{tex}    }}\n')
    (d / "parts" / "looks.usda").write_text(HEADER.format(mpu=0.01, prim="Looks") + 'def Scope "Looks"\n{\n'
                                            + "".join(mats) + "}\n")
    # parts: (name, builder, look); a part layer holds its mesh(es) and references the looks
    parts: dict[str, tuple] = {}
    for k, (paint, scale) in enumerate((("Paint_Red", 1.0), ("Paint_Blue", 1.1), ("Paint_Green", 0.92))):
        parts[f"body_{k}"] = (_rounded((420 * scale, 110, 180), (0, 90, 0), body_segments, k), paint)
        parts[f"roof_{k}"] = (_rounded((220 * scale, 60, 160), (-20, 170, 0), body_segments // 2, 10 + k), paint)
        parts[f"bumper_front_{k}"] = (_rounded((30, 30, 180), (215 * scale, 50, 0), 48, 20 + k), "Chrome")
        parts[f"bumper_rear_{k}"] = (_rounded((30, 30, 180), (-215 * scale, 50, 0), 48, 30 + k), "Chrome")
    for k in range(4):
        side = 1 if k % 2 else -1
        parts[f"door_{k}"] = (_rounded((100, 80, 6), ((60 if k < 2 else -50), 100, side * 92), 48, 40 + k), "Paint_Red")
        parts[f"seat_{k}"] = (_rounded((50, 60, 50), ((20 if k < 2 else -60), 110, side * 40), 48, 50 + k), "Seat")
    for k in range(2):
        parts[f"lamp_{k}"] = (_rounded((8, 20, 30), (212, 90, (1 - 2 * k) * 60), 32, 60 + k), "Lamp")
        parts[f"taillamp_{k}"] = (_rounded((8, 20, 30), (-212, 90, (1 - 2 * k) * 60), 32, 62 + k), "Lamp")
    parts["windshield"] = (_rounded((6, 50, 150), (90, 160, 0), 48, 70), "Glass")
    parts["rear_window"] = (_rounded((6, 45, 150), (-125, 160, 0), 48, 71), "Glass")
    parts["steering"] = (_rounded((6, 30, 30), (40, 140, 40), 48, 72), "Rubber")
    parts["decal"] = (_rounded((150, 40, 2), (0, 100, 93), 32, 73), "Decal")
    parts["chassis"] = (_box((400, 20, 160), (0, 40, 0))[:3] + (None, None), "Rubber")
    for k, look in enumerate(("Rubber", "Chrome")):  # two wheel styles, instanced
        prof_t = np.linspace(0, 1, 40)
        prof = np.stack([35 - 8 * np.abs(np.cos(prof_t * np.pi)) ** 3 + (0 if k == 0 else 3 * np.sin(prof_t * 20)),
                         (prof_t - 0.5) * 25], -1)
        prof[0, 0] = prof[-1, 0] = 0.0
        pts, counts, fvi, normals, st = lathe(prof, 96)
        pts = pts[:, [0, 2, 1]].copy()  # axle along Z
        normals = normals[:, [0, 2, 1]].copy()
        fvi = fvi.reshape(-1, 4)[:, ::-1].ravel().copy()  # the swap mirrors: keep faces outward
        normals = normals.reshape(-1, 4, 3)[:, ::-1].reshape(-1, 3).copy()
        st = st.reshape(-1, 4, 2)[:, ::-1].reshape(-1, 2).copy()
        parts[f"wheel_{k}"] = ((pts, counts, fvi, normals, st), look)
    bolt = _box((3, 3, 2))[:3] + (None, None)
    parts["bolt"] = (bolt, "Chrome")
    for name, ((pts, counts, fvi, normals, st), look) in parts.items():
        path = d / "parts" / f"{name}.usdc"
        layer, root = _component_layer(path, "Part")
        looks = Sdf.CreatePrimInLayer(layer, "/Part/Looks")
        looks.specifier = Sdf.SpecifierDef
        looks.referenceList.Prepend(Sdf.Reference("./looks.usda", "/Looks"))
        _set_mesh(layer, "/Part/Geom", np.asarray(pts, np.float32), counts, fvi, normals, st)
        geom = layer.GetPrimAtPath("/Part/Geom")
        geom.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["MaterialBindingAPI"]))
        rel = Sdf.RelationshipSpec(geom, "material:binding", False)
        rel.targetPathList.Prepend(Sdf.Path(f"/Part/Looks/{look}"))
        layer.Save()
    # the root: a variant set picks one of three bodies with its roof and bumpers
    variants = []
    for k in range(3):
        refs = "".join(f'                def "{p}" ( references = @./parts/{p}_{k}.usdc@ )\n                {{\n'
                       f'                }}\n' for p in ("body", "roof", "bumper_front", "bumper_rear"))
        variants.append(f'            "v{k}" {{\n{refs}            }}\n')
    fixed = [p for p in parts if not any(p.startswith(s) for s in ("body_", "roof_", "bumper_", "wheel_", "bolt"))]
    fixed_refs = "".join(f'        def "{p}" ( references = @./parts/{p}.usdc@ )\n        {{\n        }}\n' for p in fixed)
    wheels = []
    for w, (x, z) in enumerate(((140, 95), (140, -95), (-140, 95), (-140, -95))):
        bolts = "".join(
            f'            def "Bolt_{b}" ( instanceable = true\n                references = @./parts/bolt.usdc@ )\n'
            f'            {{\n                double3 xformOp:translate = ({18 * math.cos(b * math.pi / 3):.4g}, '
            f'{18 * math.sin(b * math.pi / 3):.4g}, {13 if z > 0 else -13})\n'
            f'                uniform token[] xformOpOrder = ["xformOp:translate"]\n            }}\n'
            for b in range(6))
        wheels.append(
            f'        def Xform "Wheel_{w}"\n        (\n            variants = {{ string rim = "sport" }}\n'
            f'            prepend variantSets = "rim"\n        )\n        {{\n'
            f'            double3 xformOp:translate = ({x}, 35, {z})\n'
            f'            uniform token[] xformOpOrder = ["xformOp:translate"]\n'
            f'            variantSet "rim" = {{\n'
            f'                "plain" {{\n                    def "Rim" ( instanceable = true\n'
            f'                        references = @./parts/wheel_0.usdc@ ) {{ }}\n                }}\n'
            f'                "sport" {{\n                    def "Rim" ( instanceable = true\n'
            f'                        references = @./parts/wheel_1.usdc@ ) {{ }}\n                }}\n'
            f'            }}\n{bolts}        }}\n')
    text = (HEADER.format(mpu=0.01, prim="Kit")
            + 'def Xform "Kit" (\n    kind = "assembly"\n    variants = { string vehicle = "v1" }\n'
              '    prepend variantSets = "vehicle"\n)\n{\n'
            + '    variantSet "vehicle" = {\n' + "".join(variants) + '    }\n'
            + '    def Xform "Fixed"\n    {\n' + fixed_refs + "".join(wheels) + '    }\n}\n')
    path = d / "kit.usda"
    path.write_text(text)
    return path


# -- 3. blocks ---------------------------------------------------------------------------------------
def _cube_faces() -> tuple[np.ndarray, np.ndarray]:
    """A unit cube's 8 corners and 6 outward quads."""
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], np.float32)
    f = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]], np.int32)
    return p, f


def write_blocks(folder: Path, side: int = 64, layers: int = 4, materials: int = 320) -> Path:
    """side x side columns of 1 to `layers` cubes (10,143 by default), each its own Mesh prim bound to
    one of `materials` materials; st into a 16 x 16 atlas of 32 px tiles."""
    from pxr import Sdf, Vt
    d = folder / "usd" / "big_blocks"
    (d / "tex").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    tiles = 16
    atlas = np.zeros((tiles * 32, tiles * 32, 3), np.uint8)
    for ty in range(tiles):
        for tx in range(tiles):
            base = rng.uniform(0.2, 0.9, 3)
            noise = rng.uniform(0.75, 1.0, (32, 32, 1))
            atlas[ty * 32:(ty + 1) * 32, tx * 32:(tx + 1) * 32] = np.round(np.clip(base * noise, 0, 1) * 255)
    Image.fromarray(atlas, "RGB").save(d / "tex" / "atlas.png")
    extra = []
    for k in range(8):
        _noise_image(256, rng.uniform(0.3, 1.0, 3), 100 + k).save(d / "tex" / f"detail_{k}.png")
        extra.append(f"./tex/detail_{k}.png")
    layer = Sdf.Layer.CreateNew(str(d / "blocks.usdc"))
    layer.defaultPrim = "World"
    layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)
    layer.pseudoRoot.SetInfo("upAxis", "Y")
    with Sdf.ChangeBlock():
        world = Sdf.CreatePrimInLayer(layer, "/World")
        world.specifier, world.typeName = Sdf.SpecifierDef, "Xform"
        looks = Sdf.CreatePrimInLayer(layer, "/World/Looks")
        looks.specifier, looks.typeName = Sdf.SpecifierDef, "Scope"

        def shader(path: str, ident: str) -> Sdf.PrimSpec:
            s = Sdf.CreatePrimInLayer(layer, path)
            s.specifier, s.typeName = Sdf.SpecifierDef, "Shader"
            a = Sdf.AttributeSpec(s, "info:id", Sdf.ValueTypeNames.Token, Sdf.VariabilityUniform)
            a.default = ident
            return s

        def attr(spec, name, tname, value=None, connect=None):
            a = Sdf.AttributeSpec(spec, name, tname)
            if value is not None:
                a.default = value
            if connect is not None:
                a.connectionPathList.Prepend(Sdf.Path(connect))
            return a
        V = Sdf.ValueTypeNames  # noqa: N806
        for m in range(materials):
            mp = f"/World/Looks/M{m:03d}"
            mat = Sdf.CreatePrimInLayer(layer, mp)
            mat.specifier, mat.typeName = Sdf.SpecifierDef, "Material"
            attr(mat, "outputs:surface", V.Token, connect=f"{mp}/S.outputs:surface")
            s = shader(f"{mp}/S", "UsdPreviewSurface")
            attr(s, "inputs:diffuseColor", V.Color3f, connect=f"{mp}/Tex.outputs:rgb")
            attr(s, "inputs:roughness", V.Float, float(0.3 + 0.6 * (m % 7) / 6))
            attr(s, "outputs:surface", V.Token)
            r = shader(f"{mp}/St", "UsdPrimvarReader_float2")
            attr(r, "inputs:varname", V.String, "st")
            attr(r, "outputs:result", V.Float2)
            t2 = shader(f"{mp}/Tile", "UsdTransform2d")
            attr(t2, "inputs:in", V.Float2, connect=f"{mp}/St.outputs:result")
            attr(t2, "inputs:scale", V.Float2, (1 / tiles, 1 / tiles))
            attr(t2, "inputs:translation", V.Float2, ((m % tiles) / tiles, ((m // tiles) % tiles) / tiles))
            attr(t2, "outputs:result", V.Float2)
            tex = shader(f"{mp}/Tex", "UsdUVTexture")
            attr(tex, "inputs:file", V.Asset, Sdf.AssetPath(extra[m % 8] if m % 40 == 39 else "./tex/atlas.png"))
            attr(tex, "inputs:st", V.Float2, connect=f"{mp}/Tile.outputs:result")
            tint = rng.uniform(0.7, 1.0, 3)
            attr(tex, "inputs:scale", V.Float4, (float(tint[0]), float(tint[1]), float(tint[2]), 1.0))
            attr(tex, "inputs:wrapS", V.Token, "repeat")
            attr(tex, "inputs:wrapT", V.Token, "repeat")
            attr(tex, "outputs:rgb", V.Float3)
        corners, quads = _cube_faces()
        fvi = Vt.IntArray.FromNumpy(quads.ravel())
        counts = Vt.IntArray.FromNumpy(np.full(6, 4, np.int32))
        st = Vt.Vec2fArray.FromNumpy(np.tile(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), (6, 1)))
        extent = np.array([[0, 0, 0], [1, 1, 1]], np.float32)  # the points' bounds, moved with them
        h = rng.integers(1, layers + 1, (side, side))
        k = 0
        for x in range(side):
            row = Sdf.CreatePrimInLayer(layer, f"/World/Row_{x:03d}")
            row.specifier, row.typeName = Sdf.SpecifierDef, "Xform"
            for z in range(side):
                for y in range(layers):
                    if y >= h[x, z] and y > 0:
                        continue
                    path = f"/World/Row_{x:03d}/B_{z:03d}_{y}"
                    spec = Sdf.CreatePrimInLayer(layer, path)
                    spec.specifier, spec.typeName = Sdf.SpecifierDef, "Mesh"
                    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["MaterialBindingAPI"]))
                    # each cube's own points (as an exporter writes a block world: no instancing)
                    offset = np.array([x - side / 2, y, z - side / 2], np.float32)
                    attr(spec, "points", V.Point3fArray, Vt.Vec3fArray.FromNumpy(corners + offset))
                    attr(spec, "faceVertexCounts", V.IntArray, counts)
                    attr(spec, "faceVertexIndices", V.IntArray, fvi)
                    a = attr(spec, "primvars:st", V.TexCoord2fArray, st)
                    a.SetInfo("interpolation", "faceVarying")
                    a = Sdf.AttributeSpec(spec, "subdivisionScheme", V.Token, Sdf.VariabilityUniform)
                    a.default = "none"
                    attr(spec, "extent", V.Float3Array, Vt.Vec3fArray.FromNumpy(extent + offset))
                    rel = Sdf.RelationshipSpec(spec, "material:binding", False)
                    rel.targetPathList.Prepend(Sdf.Path(f"/World/Looks/M{(k * 7919) % materials:03d}"))
                    k += 1
    layer.Save()
    return d / "blocks.usdc"


def write(folder: Path) -> list[Path]:
    return [write_chess(folder), write_kit(folder), write_blocks(folder)]


if __name__ == "__main__":
    for p in write(Path(sys.argv[1])):
        print(p)
