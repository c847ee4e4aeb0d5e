"""Lights with extent over a box on a ground plane, to compare penumbrae with Storm and between
our integrators: `python -m bench.penumbra_stages DIR` writes DIR/usd/Penumbra/*.usda, then

    ASSET_PREVIEW_STORM_PYTHON=... asset-preview bench usd --assets DIR

renders each with ours and Storm. One stage per light: a 1.5 m RectLight, a 0.75 m DiskLight,
a 0.4 m SphereLight, a 1.5 m CylinderLight, all 2.6 m above the ground, and a DistantLight
of angle 10 degrees (a 0.53 degree one for the sun-sized case) 50 degrees high, its shadow
toward `bench usd`'s camera. Every light is normalized (its
intensity is the illuminance or intensity a point receiver far away sees), so a shadow's width
is the only thing the extent changes. The box is 0.8 m with its top at 0.8 m: the penumbra the
rect light's 1.5 m puts across the shadow of a top edge is w h / (H - h) = 1.5 x 0.8 / 1.8 =
0.67 m wide (similar triangles)."""
from __future__ import annotations

import sys
from pathlib import Path

from bench.stage_files import write_usda

HEADER = '#usda 1.0\n(\n    defaultPrim = "World"\n    upAxis = "Y"\n    metersPerUnit = 1\n)\n'
BODY = """def Xform "World"
{
    def Cube "Box"
    {
        double size = 0.8
        double3 xformOp:translate = (0, 0.4, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]
    }
    def Mesh "Ground"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-3, 0, 3), (3, 0, 3), (3, 0, -3), (-3, 0, -3)]
        normal3f[] normals = [(0,1,0),(0,1,0),(0,1,0),(0,1,0)] ( interpolation = "vertex" )
        color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]
    }
LIGHT}
"""
HEIGHT = 2.6  # of the local lights' centres
# beside the box (toward -x, -z), so that its shadow falls on the ground in view
OVERHEAD = (f'        double3 xformOp:translate = (-1.3, {HEIGHT}, -0.7)\n'
            '        float3 xformOp:rotateXYZ = (-90, 0, 0)\n'  # -Z (the emitting side) down
            '        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]\n')
LIGHTS = {
    "rect": ('RectLight', 'float inputs:width = 1.5\n        float inputs:height = 1.5\n'
             '        float inputs:intensity = 12\n', OVERHEAD),
    "disk": ('DiskLight', 'float inputs:radius = 0.75\n        float inputs:intensity = 12\n', OVERHEAD),
    "sphere": ('SphereLight', 'float inputs:radius = 0.4\n        float inputs:intensity = 12\n',
               f'        double3 xformOp:translate = (-1.3, {HEIGHT}, -0.7)\n'
               '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'),
    "cylinder": ('CylinderLight', 'float inputs:length = 1.5\n        float inputs:radius = 0.1\n'
                 '        float inputs:intensity = 12\n',
                 f'        double3 xformOp:translate = (-1.3, {HEIGHT}, -0.7)\n'
                 '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'),
    "distant_10deg": ('DistantLight', 'float inputs:angle = 10\n        float inputs:intensity = 3\n',
                      '        float3 xformOp:rotateXYZ = (-50, -135, 0)\n'
                      '        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]\n'),
    "distant_sun": ('DistantLight', 'float inputs:intensity = 3\n',
                    '        float3 xformOp:rotateXYZ = (-50, -135, 0)\n'
                    '        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]\n'),
}


def stage_text(name: str) -> str:
    kind, inputs, xform = LIGHTS[name]
    light = (f'    def {kind} "Light"\n    {{\n        bool inputs:normalize = 1\n'
             f'        {inputs}{xform}    }}\n')
    return HEADER + BODY.replace("LIGHT", light)


def write_stages(folder: Path) -> list[Path]:
    return write_usda(Path(folder) / "usd" / "Penumbra", {name: stage_text(name) for name in LIGHTS})


if __name__ == "__main__":
    for p in write_stages(Path(sys.argv[1] if len(sys.argv) > 1 else "bench/stages_penumbra")):
        print(p)
