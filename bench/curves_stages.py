"""BasisCurves and Points to compare with Storm: `python -m bench.curves_stages DIR` writes
DIR/usd/*.usda, then

    ASSET_PREVIEW_STORM_PYTHON=... asset-preview bench usd --assets DIR --storm-complexity 1.0

renders each with ours and Storm (1.0 is usdview's default, Low; 1.3 its Very High). One stage
per rule: linear curves (nonperiodic, periodic, varying widths, per-vertex colour), cubic
bezier / bspline / catmullRom (nonperiodic and periodic, per-curve colour), curves without
widths (Storm's default), and Points with and without per-point widths. Each stage carries a
grey ground card so that both renderers frame the same bounds.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

from bench.stage_files import write_usda

HEADER = '#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n    defaultPrim = "W"\n)\n'
CARD = ('    def Mesh "Card"\n    {\n        int[] faceVertexCounts = [4]\n'
        '        int[] faceVertexIndices = [0, 1, 2, 3]\n'
        '        point3f[] points = [(-2.2, -2.2, -0.6), (2.2, -2.2, -0.6), (2.2, 2.2, -0.6), (-2.2, 2.2, -0.6)]\n'
        '        color3f[] primvars:displayColor = [(0.5, 0.5, 0.5)]\n    }\n')


def _pts(points) -> str:
    return ", ".join(f"({x:.4f}, {y:.4f}, {z:.4f})" for x, y, z in points)


def _wave(n: int, y: float, amp: float = 0.6) -> list[tuple[float, float, float]]:
    return [(-1.8 + 3.6 * i / (n - 1), y + amp * (1 if i % 2 else -1), 0.0) for i in range(n)]


def _ring(n: int, cx: float, cy: float, r: float) -> list[tuple[float, float, float]]:
    return [(cx + r * math.cos(2 * math.pi * i / n), cy + r * math.sin(2 * math.pi * i / n), 0.0)
            for i in range(n)]


def _curves(name: str, kind: str, curves: list[list], basis: str = "bezier", wrap: str = "nonperiodic",
            widths: str = "", color: str = "") -> str:
    counts = ", ".join(str(len(c)) for c in curves)
    pts = ", ".join(_pts(c) for c in curves)
    text = (f'    def BasisCurves "{name}"\n    {{\n        uniform token type = "{kind}"\n'
            f'        uniform token basis = "{basis}"\n        uniform token wrap = "{wrap}"\n'
            f'        int[] curveVertexCounts = [{counts}]\n        point3f[] points = [{pts}]\n')
    return text + widths + color + "    }\n"


def stages() -> dict[str, str]:
    out: dict[str, str] = {}
    red = '        color3f[] primvars:displayColor = [(0.9, 0.15, 0.1)]\n'
    two = '        color3f[] primvars:displayColor = [(0.9, 0.15, 0.1), (0.1, 0.3, 0.9)] (interpolation = "uniform")\n'
    wide = '        float[] widths = [0.15] (interpolation = "constant")\n'
    a, b = _wave(7, 0.9), _wave(7, -0.9)
    out["curves_linear"] = _curves("C", "linear", [a, b], widths=wide, color=two)
    ring = _ring(8, 0, 0, 1.4)
    out["curves_linear_periodic"] = _curves("C", "linear", [ring], wrap="periodic", widths=wide, color=red)
    n = len(a)
    out["curves_linear_varying"] = _curves(
        "C", "linear", [a], widths=f'        float[] widths = [{", ".join(f"{0.05 + 0.08 * i:.2f}" for i in range(n))}] (interpolation = "vertex")\n',
        color=f'        color3f[] primvars:displayColor = [{", ".join(f"({i / (n - 1):.3f}, 0.2, {1 - i / (n - 1):.3f})" for i in range(n))}] (interpolation = "vertex")\n')
    out["curves_bezier"] = _curves("C", "cubic", [a, b], "bezier", widths=wide, color=two)
    out["curves_bspline"] = _curves("C", "cubic", [a, b], "bspline", widths=wide, color=two)
    out["curves_catmullrom"] = _curves("C", "cubic", [a, b], "catmullRom", widths=wide, color=two)
    out["curves_bspline_periodic"] = _curves("C", "cubic", [ring], "bspline", "periodic", widths=wide, color=red)
    out["curves_catmullrom_periodic"] = _curves("C", "cubic", [ring], "catmullRom", "periodic", widths=wide, color=red)
    out["curves_bezier_periodic"] = _curves("C", "cubic", [_ring(9, 0, 0, 1.4)], "bezier", "periodic", widths=wide, color=red)
    out["curves_no_widths"] = _curves("C", "linear", [a, b], color=two)
    grid = [(-1.6 + 0.8 * i, -1.6 + 0.8 * j, 0.0) for j in range(5) for i in range(5)]
    out["points_widths"] = (
        f'    def Points "P"\n    {{\n        point3f[] points = [{_pts(grid)}]\n'
        f'        float[] widths = [{", ".join(f"{0.1 + 0.02 * k:.2f}" for k in range(len(grid)))}] (interpolation = "vertex")\n'
        f'        color3f[] primvars:displayColor = [(0.2, 0.7, 0.2)]\n    }}\n')
    out["points_no_widths"] = (
        f'    def Points "P"\n    {{\n        point3f[] points = [{_pts(grid)}]\n'
        f'        color3f[] primvars:displayColor = [(0.2, 0.7, 0.2)]\n    }}\n')
    return {k: HEADER + 'def Xform "W"\n{\n' + v + CARD + "}\n" for k, v in out.items()}


def write(folder: Path) -> list[Path]:
    return write_usda(folder, stages())


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("curves-stages")
    for p in write(target / "usd"):
        print(p)
