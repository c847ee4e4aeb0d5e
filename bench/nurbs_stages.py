"""NurbsPatch, NurbsCurves and HermiteCurves to compare with Storm: `python -m bench.nurbs_stages
DIR` writes DIR/usd/*.usda, then

    ASSET_PREVIEW_STORM_PYTHON=... asset-preview bench usd --assets DIR [--storm-complexity C]

renders each with ours and Storm. One stage per case: a bicubic patch over a 5 x 4 control
hull that bulges out of its plane, the same with a trim loop (a circle cut out), a bilinear
(order 2) patch, cubic NurbsCurves with widths, NurbsCurves without widths, and HermiteCurves
(points and tangents). Each carries a grey ground card so that both renderers frame the same
bounds even where one draws nothing of the prim.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

from bench.curves_stages import CARD, HEADER
from bench.stage_files import write_usda


def _pts(points) -> str:
    return ", ".join(f"({x:.4f}, {y:.4f}, {z:.4f})" for x, y, z in points)


# a patch's stages are lit from the side, so that its facets (or their absence) show; no
# shadows, which Storm's frame (usdview's default) does not draw and ours would
LIGHT = ('    def DistantLight "Sun"\n    {\n        float inputs:intensity = 3\n'
         '        bool inputs:normalize = 1\n        bool inputs:shadow:enable = 0\n'
         '        float3 xformOp:rotateXYZ = (-30, 50, 0)\n'
         '        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]\n    }\n')


def _hull(nu: int, nv: int) -> list[tuple[float, float, float]]:
    """nu x nv control points over [-1.6, 1.6]^2 (u fastest), bulging in z."""
    out = []
    for j in range(nv):
        for i in range(nu):
            x, y = -1.6 + 3.2 * i / (nu - 1), -1.6 + 3.2 * j / (nv - 1)
            z = 1.2 * math.sin(math.pi * i / (nu - 1)) * math.sin(math.pi * j / (nv - 1)) - 0.3
            out.append((x, y, z))
    return out


def _knots(n: int, order: int) -> list[float]:
    """Clamped uniform knots of n control points (n + order values)."""
    inner = n - order
    return [0.0] * order + [(k + 1) / (inner + 1) for k in range(inner)] + [1.0] * order


def _fmt(values) -> str:
    return ", ".join(f"{v:g}" for v in values)


def _patch(order: int, trim: bool = False) -> str:
    nu, nv = 5, 4
    text = (f'    def NurbsPatch "Patch"\n    {{\n'
            f'        int uVertexCount = {nu}\n        int vVertexCount = {nv}\n'
            f'        int uOrder = {order}\n        int vOrder = {order}\n'
            f'        double[] uKnots = [{_fmt(_knots(nu, order))}]\n'
            f'        double[] vKnots = [{_fmt(_knots(nv, order))}]\n'
            f'        double2 uRange = (0, 1)\n        double2 vRange = (0, 1)\n'
            f'        point3f[] points = [{_pts(_hull(nu, nv))}]\n'
            f'        color3f[] primvars:displayColor = [(0.2, 0.5, 0.9)]\n')
    if trim:  # one loop: a linear (order 2) closed curve of 9 points, a circle in (u, v)
        n = 9
        ring = [(0.5 + 0.25 * math.cos(2 * math.pi * k / (n - 1)),
                 0.5 + 0.25 * math.sin(2 * math.pi * k / (n - 1)), 1.0) for k in range(n)]
        text += ('        int[] trimCurve:counts = [1]\n        int[] trimCurve:orders = [2]\n'
                 f'        int[] trimCurve:vertexCounts = [{n}]\n'
                 f'        double[] trimCurve:knots = [{_fmt(_knots(n, 2))}]\n'
                 '        double2[] trimCurve:ranges = [(0, 1)]\n'
                 f'        double3[] trimCurve:points = [{_pts(ring)}]\n')
    return text + "    }\n" + LIGHT


def _nurbs_curves(widths: bool) -> str:
    a = [(-1.8 + 3.6 * i / 6, 0.9 + 0.6 * (1 if i % 2 else -1), 0.0) for i in range(7)]
    b = [(-1.8 + 3.6 * i / 4, -0.9 + 0.6 * (1 if i % 2 else -1), 0.0) for i in range(5)]
    text = ('    def NurbsCurves "C"\n    {\n        int[] curveVertexCounts = [7, 5]\n'
            '        int[] order = [4, 3]\n'
            f'        double[] knots = [{_fmt(_knots(7, 4) + _knots(5, 3))}]\n'
            '        double2[] ranges = [(0, 1), (0, 1)]\n'
            f'        point3f[] points = [{_pts(a + b)}]\n'
            '        color3f[] primvars:displayColor = [(0.9, 0.15, 0.1), (0.1, 0.3, 0.9)] '
            '(interpolation = "uniform")\n')
    if widths:
        text += '        float[] widths = [0.15] (interpolation = "constant")\n'
    return text + "    }\n"


def _hermite() -> str:
    pts = [(-1.6, 0.8, 0.0), (0.0, 1.2, 0.0), (1.6, 0.8, 0.0), (-1.6, -0.9, 0.0), (1.6, -0.9, 0.0)]
    tan = [(3.0, 3.0, 0.0), (3.0, -3.0, 0.0), (3.0, 3.0, 0.0), (0.0, 4.0, 0.0), (0.0, -4.0, 0.0)]
    return ('    def HermiteCurves "C"\n    {\n        int[] curveVertexCounts = [3, 2]\n'
            f'        point3f[] points = [{_pts(pts)}]\n'
            f'        vector3f[] tangents = [{_pts(tan)}]\n'
            '        float[] widths = [0.15] (interpolation = "constant")\n'
            '        color3f[] primvars:displayColor = [(0.9, 0.6, 0.1)]\n    }\n')


def stages() -> dict[str, str]:
    out = {
        "nurbs_patch": _patch(4),
        "nurbs_patch_trimmed": _patch(4, trim=True),
        "nurbs_patch_bilinear": _patch(2),
        "nurbs_curves": _nurbs_curves(True),
        "nurbs_curves_no_widths": _nurbs_curves(False),
        "hermite_curves": _hermite(),
    }
    return {k: HEADER + 'def Xform "W"\n{\n' + v + CARD + "}\n" for k, v in out.items()}


def write(folder: Path) -> list[Path]:
    return write_usda(folder, stages())


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("nurbs-stages")
    for p in write(target / "usd"):
        print(p)
