"""UDIM-textured stages to compare with Storm: `python -m bench.udim_stages DIR` writes
DIR/usd/udim_*.usda and their tiles, then

    ASSET_PREVIEW_STORM_PYTHON=... asset-preview bench usd --assets DIR --stages udim

renders each with ours and Storm (`--time` after DIR also prints the ingest and bake cost of
the UDIM cylinder beside its one-image control). The card (tests/test_usd_udim.py's stage: flat tiles 1001,
1002, 1011, tile 1012 missing), the card through a UsdTransform2d (rotated 90 degrees and
moved, patterned tiles: orientation shows), one quad whose st spans four tiles (its two
triangles cut along the tile borders at bake), and a cylinder whose st runs 0..4 around it over
four patterned tiles of different sizes (the seams between tiles share vertices), also as
a Catmull-Clark cage (refined at bake, then remapped); the control: that cylinder with one
image holding the four tiles side by side (its st 0..1 around), no UDIM, which measures what
of the cylinder's FLIP is not UDIM's.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from PIL import Image

HEADER = '#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n    defaultPrim = "M"\n)\n'
FLAT = {1001: (220, 30, 30), 1002: (30, 200, 30), 1011: (30, 30, 220), 1012: (230, 200, 20)}
CARD_POINTS = ("(-1, -1, 0), (0, -1, 0), (1, -1, 0), (-1, 0, 0), (0, 0, 0), (1, 0, 0), (-1, 1, 0), "
               "(0, 1, 0), (1, 1, 0)")
CARD_ST = "(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1), (0, 2), (1, 2), (2, 2)"
CARD_FACES = "0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6, 4, 5, 8, 7"


def _material(pattern: str, transform: str = "") -> str:
    st = "</M/Look/Move.outputs:result>" if transform else "</M/Look/Reader.outputs:result>"
    move = (f'        def Shader "Move"\n        {{\n            uniform token info:id = "UsdTransform2d"\n'
            f'            float2 inputs:in.connect = </M/Look/Reader.outputs:result>\n{transform}'
            f'            float2 outputs:result\n        }}\n') if transform else ""
    return f"""    def Material "Look"
    {{
        token outputs:surface.connect = </M/Look/S.outputs:surface>
        def Shader "S"
        {{
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </M/Look/Tex.outputs:rgb>
            float inputs:roughness = 0.6
            token outputs:surface
        }}
        def Shader "Reader"
        {{
            uniform token info:id = "UsdPrimvarReader_float2"
            string inputs:varname = "st"
            float2 outputs:result
        }}
{move}        def Shader "Tex"
        {{
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @./{pattern}@
            float2 inputs:st.connect = {st}
            float3 outputs:rgb
        }}
    }}
"""


def _mesh(counts, faces: str, points: str, st: str, scheme: str = "none") -> str:
    return (f'    def Mesh "Surface" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n    {{\n'
            f'        int[] faceVertexCounts = [{", ".join(map(str, counts))}]\n'
            f'        int[] faceVertexIndices = [{faces}]\n        point3f[] points = [{points}]\n'
            f'        texCoord2f[] primvars:st = [{st}] ( interpolation = "vertex" )\n'
            f'        uniform token subdivisionScheme = "{scheme}"\n'
            f'        rel material:binding = </M/Look>\n    }}\n')


def patterned(tile: int, size: int) -> Image.Image:
    """A tile that shows where it is and which way is up: a checker in the tile's hue, darker
    towards its top, and a white bar along its left edge."""
    hue = {1001: (0.9, 0.2, 0.2), 1002: (0.2, 0.8, 0.2), 1003: (0.25, 0.3, 0.95),
           1004: (0.95, 0.8, 0.15), 1011: (0.2, 0.8, 0.85), 1012: (0.85, 0.3, 0.85)}[tile]
    y, x = np.mgrid[0:size, 0:size] / size
    checker = ((np.floor(x * 8) + np.floor(y * 8)) % 2) * 0.5 + 0.5
    shade = (0.35 + 0.65 * y)[..., None] * checker[..., None] * np.asarray(hue)
    shade[:, : max(1, size // 16)] = 1.0
    return Image.fromarray(np.round(shade.clip(0, 1) * 255).astype(np.uint8), "RGB")


def _cylinder(segments: int = 32, rings: int = 8, around: float = 4.0) -> tuple[list[int], str, str, str]:
    """A cylinder around Y, st (0..`around` around, 0..1 up): four tiles side by side."""
    pts, st = [], []
    for j in range(rings + 1):
        for i in range(segments + 1):  # the last column repeats the first (st 4 vs 0)
            a = 2 * math.pi * i / segments
            pts.append(f"({math.sin(a):.6g}, {2 * j / rings - 1:.6g}, {math.cos(a):.6g})")
            st.append(f"({around * i / segments:.6g}, {j / rings:.6g})")
    faces = []
    w = segments + 1
    for j in range(rings):
        for i in range(segments):
            faces += [j * w + i, j * w + i + 1, (j + 1) * w + i + 1, (j + 1) * w + i]
    return [4] * (rings * segments), ", ".join(map(str, faces)), ", ".join(pts), ", ".join(st)


def write(folder: Path) -> list[Path]:
    usd = folder / "usd"
    (usd / "tiles").mkdir(parents=True, exist_ok=True)
    for t in (1001, 1002, 1011):
        Image.new("RGB", (64, 64), FLAT[t]).save(usd / "tiles" / f"flat.{t}.png")
    for t in (1001, 1002, 1011, 1012):
        patterned(t, 128).save(usd / "tiles" / f"card.{t}.png")
    for t, size in ((1001, 256), (1002, 128), (1003, 256), (1004, 64)):
        patterned(t, size).save(usd / "tiles" / f"cyl.{t}.png")
    strip = Image.new("RGB", (4 * 256, 256))
    for k, t in enumerate((1001, 1002, 1003, 1004)):
        strip.paste(Image.open(usd / "tiles" / f"cyl.{t}.png").resize((256, 256), Image.Resampling.BILINEAR),
                    (256 * k, 0))
    strip.save(usd / "tiles" / "cyl_strip.png")
    counts = [4, 4, 4, 4]
    stages = {
        "udim_card": _mesh(counts, CARD_FACES, CARD_POINTS, CARD_ST) + _material("tiles/flat.<UDIM>.png"),
        "udim_card_rotated": _mesh(counts, CARD_FACES, CARD_POINTS, CARD_ST) + _material(
            "tiles/card.<UDIM>.png", "            float inputs:rotation = 90\n"
                                     "            float2 inputs:translation = (2, 0)\n"),
        "udim_quad_across": _mesh([4], "0, 1, 2, 3", "(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)",
                                  "(0, 0), (2, 0), (2, 2), (0, 2)") + _material("tiles/card.<UDIM>.png"),
        "udim_cylinder": _mesh(*_cylinder()) + _material("tiles/cyl.<UDIM>.png"),
        "udim_cylinder_subdiv": _mesh(*_cylinder(), scheme="catmullClark") + _material("tiles/cyl.<UDIM>.png"),
        "udim_control_cylinder_one_image": _mesh(*_cylinder(around=1.0)) + _material("tiles/cyl_strip.png"),
    }
    out = []
    for name, body in stages.items():
        path = usd / f"{name}.usda"
        path.write_text(HEADER + f'def Xform "M"\n{{\n{body}}}\n')
        out.append(path)
    return out


def time_cylinders(folder: Path, runs: int = 7) -> str:
    """Median ingest (load_scene) and bake (build_baked and the texture mips) of the UDIM
    cylinder and its one-image control, run alternately in this process."""
    import statistics
    import time

    from pipeline.bake import build_baked
    from pipeline.ingest import load_scene

    paths = [folder / "usd" / "udim_cylinder.usda", folder / "usd" / "udim_control_cylinder_one_image.usda"]
    ingest: dict[Path, list[float]] = {p: [] for p in paths}
    bake: dict[Path, list[float]] = {p: [] for p in paths}
    for _ in range(runs):
        for p in paths:
            t = time.perf_counter()
            scene = load_scene(p)
            ingest[p].append(time.perf_counter() - t)
            t = time.perf_counter()
            for tex in build_baked(scene, "bench", {"occlusion": False}).textures:
                tex.mips(True)
            bake[p].append(time.perf_counter() - t)
    a, b = (statistics.median(ingest[p]) for p in paths)
    c, d = (statistics.median(bake[p]) for p in paths)
    return (f"ingest median: UDIM {1000 * a:.1f} ms, one image {1000 * b:.1f} ms ({a / b:.2f}x); "
            f"bake + mips median: UDIM {1000 * c:.1f} ms, one image {1000 * d:.1f} ms ({c / d:.2f}x)")


if __name__ == "__main__":
    for p in write(Path(sys.argv[1])):
        print(p)
    if "--time" in sys.argv[2:]:
        print(time_cylinders(Path(sys.argv[1])))
