"""Subdivision surfaces to compare with Storm (OpenSubdiv): `python -m bench.subdiv_stages DIR`
writes DIR/usd/*.usda, then

    ASSET_PREVIEW_STORM_PYTHON=... asset-preview bench usd --assets DIR --storm-complexity 1.2

renders each with ours and Storm refined two levels (usdview's "High" complexity; ours refines a
cage this small two levels). One rule each: a smooth cube, infinitely sharp and semi-sharp
creases, sharp corners, a pyramid with a creased base and a sharp apex, a bumped open grid under
each interpolateBoundary, triangles under each triangleSubdivisionRule, a textured cube
(face-varying UVs, every face its own region), a textured cube unwrapped as a cross (seams
that end at darts and one-face regions) under cornersPlus1 and cornersPlus2, and a textured
bumped grid whose st is varying (bilinear) or vertex (smooth).
"""
from __future__ import annotations

import sys
from pathlib import Path

from bench.stage_files import write_usda

HEADER = '#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n    defaultPrim = "M"\n)\n'
CUBE_POINTS = "(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1), (-1, -1, -1), (1, -1, -1)"
CUBE_FACES = "0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4"
CUBE_EDGES = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 6), (1, 7), (2, 4), (3, 5)]
GREY = '    color3f[] primvars:displayColor = [(0.6, 0.6, 0.6)] (interpolation = "constant")\n'


def _mesh(counts: list[int], indices: str, points: str, extra: str = "", meta: str = "") -> str:
    return (f'def Mesh "M"{meta}\n{{\n    int[] faceVertexCounts = [{", ".join(map(str, counts))}]\n'
            f'    int[] faceVertexIndices = [{indices}]\n    point3f[] points = [{points}]\n'
            f'    uniform token subdivisionScheme = "catmullClark"\n{GREY}{extra}}}\n')


def _creases(edges, sharpness: float) -> str:
    return (f"    int[] creaseIndices = [{', '.join(f'{a}, {b}' for a, b in edges)}]\n"
            f"    int[] creaseLengths = [{', '.join(['2'] * len(edges))}]\n"
            f"    float[] creaseSharpnesses = [{', '.join([str(sharpness)] * len(edges))}]\n")


def _grid(boundary: str) -> str:
    n = 4
    pts = ", ".join(f"({x - 2}, {0.6 if (x, y) in ((1, 1), (2, 2)) else 0}, {y - 2})"
                    for y in range(n + 1) for x in range(n + 1))
    idx = ", ".join(str(v) for y in range(n) for x in range(n)
                    for v in (y * 5 + x, y * 5 + x + 5, y * 5 + x + 6, y * 5 + x + 1))
    return _mesh([4] * n * n, idx, pts, f'    uniform token interpolateBoundary = "{boundary}"\n'
                                        '    uniform bool doubleSided = true\n')


# The cube's faces (CUBE_FACES order: front, top, back, bottom, right, left) unwrapped as a
# cross over a 3 x 4 chart: bottom, front, top, back up the middle column, right and left
# beside the front. Per face, its corners' (column, row).
CROSS = [[(1, 1), (2, 1), (2, 2), (1, 2)], [(1, 2), (2, 2), (2, 3), (1, 3)],
         [(1, 3), (2, 3), (2, 4), (1, 4)], [(1, 0), (2, 0), (2, 1), (1, 1)],
         [(2, 1), (3, 1), (3, 2), (2, 2)], [(0, 1), (1, 1), (1, 2), (0, 2)]]
CHECKER_MATERIAL = """
def Scope "Looks"
{
    def Material "Checker"
    {
        token outputs:surface.connect = </Looks/Checker/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </Looks/Checker/T.outputs:rgb>
            float inputs:roughness = 0.6
            token outputs:surface
        }
        def Shader "T"
        {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @./checker.png@
            float2 inputs:st.connect = </Looks/Checker/R.outputs:result>
            float3 outputs:rgb
        }
        def Shader "R"
        {
            uniform token info:id = "UsdPrimvarReader_float2"
            string inputs:varname = "st"
            float2 outputs:result
        }
    }
}
"""
BOUND = ' (\n    prepend apiSchemas = ["MaterialBindingAPI"]\n)'


def _textured(counts, indices, points, st: str, extra: str = "") -> str:
    return HEADER + _mesh(counts, indices, points, st + extra + '    rel material:binding = </Looks/Checker>\n',
                          BOUND).replace(GREY, "") + CHECKER_MATERIAL


def stages() -> dict[str, str]:
    cube = {"cube_smooth": "", "cube_creased_inf": _creases(CUBE_EDGES, 10),
            "cube_creased_1.5": _creases(CUBE_EDGES, 1.5),
            "cube_corners": "    int[] cornerIndices = [0, 1, 2, 3, 4, 5, 6, 7]\n"
                            f"    float[] cornerSharpnesses = [{', '.join(['10'] * 8)}]\n"}
    out = {name: HEADER + _mesh([4] * 6, CUBE_FACES, CUBE_POINTS, extra) for name, extra in cube.items()}
    pyramid_pts = "(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1), (0, 1.5, 0)"
    out["pyramid_sharp"] = HEADER + _mesh(
        [4, 3, 3, 3, 3], "0, 1, 2, 3, 1, 0, 4, 2, 1, 4, 3, 2, 4, 0, 3, 4", pyramid_pts,
        _creases([(0, 1), (1, 2), (2, 3), (3, 0), (0, 4), (1, 4), (2, 4), (3, 4)], 10)
        + "    int[] cornerIndices = [4]\n    float[] cornerSharpnesses = [10]\n")
    for rule in ("catmullClark", "smooth"):
        out[f"pyramid_tri_{rule}"] = HEADER + _mesh(
            [4, 3, 3, 3, 3], "0, 1, 2, 3, 1, 0, 4, 2, 1, 4, 3, 2, 4, 0, 3, 4", pyramid_pts,
            f'    uniform token triangleSubdivisionRule = "{rule}"\n')
    for boundary in ("edgeAndCorner", "edgeOnly", "none"):
        out[f"grid_{boundary}"] = HEADER + _grid(boundary)
    st = ", ".join(f"({(i % 4 in (1, 2)) * 1.0}, {(i % 4 > 1) * 1.0})" for i in range(24))
    out["cube_textured"] = HEADER + _mesh(
        [4] * 6, CUBE_FACES, CUBE_POINTS,
        f'    texCoord2f[] primvars:st = [{st}] (interpolation = "faceVarying")\n'
        '    rel material:binding = </Looks/Checker>\n',
        ' (\n    prepend apiSchemas = ["MaterialBindingAPI"]\n)').replace(GREY, "") + """
def Scope "Looks"
{
    def Material "Checker"
    {
        token outputs:surface.connect = </Looks/Checker/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </Looks/Checker/T.outputs:rgb>
            float inputs:roughness = 0.6
            token outputs:surface
        }
        def Shader "T"
        {
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @./checker.png@
            float2 inputs:st.connect = </Looks/Checker/R.outputs:result>
            float3 outputs:rgb
        }
        def Shader "R"
        {
            uniform token info:id = "UsdPrimvarReader_float2"
            string inputs:varname = "st"
            float2 outputs:result
        }
    }
}
"""
    cross = ", ".join(f"({c / 3}, {r / 4})" for face in CROSS for c, r in face)
    for rule in ("cornersPlus1", "cornersPlus2"):
        out[f"cube_cross_{rule}"] = _textured(
            [4] * 6, CUBE_FACES, CUBE_POINTS,
            f'    texCoord2f[] primvars:st = [{cross}] (interpolation = "faceVarying")\n',
            f'    uniform token faceVaryingLinearInterpolation = "{rule}"\n')
    n = 4
    pts = ", ".join(f"({x - 2}, {0.4 if (x, y) in ((1, 1), (2, 2)) else 0}, {y - 2})"
                    for y in range(n + 1) for x in range(n + 1))
    idx = ", ".join(str(v) for y in range(n) for x in range(n)
                    for v in (y * 5 + x, y * 5 + x + 5, y * 5 + x + 6, y * 5 + x + 1))
    warp = ", ".join(f"({x / 4 + (0.15 if (x, y) in ((1, 1), (2, 3)) else 0)}, {y / 4})"
                     for y in range(n + 1) for x in range(n + 1))
    for interp in ("varying", "vertex"):
        out[f"grid_st_{interp}"] = _textured(
            [4] * n * n, idx, pts,
            f'    texCoord2f[] primvars:st = [{warp}] (interpolation = "{interp}")\n',
            '    uniform bool doubleSided = true\n')
    return out


def write(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    import numpy as np
    from PIL import Image
    cells = (np.indices((256, 256)) // 32).sum(axis=0) % 2
    Image.fromarray(np.where(cells[..., None], [230, 200, 60], [40, 60, 160]).astype(np.uint8)).save(
        folder / "checker.png")
    return write_usda(folder, stages())


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("subdiv-stages")
    for p in write(target / "usd"):
        print(p)
