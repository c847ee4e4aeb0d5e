"""Generated USD stages for `bench ingest --usd-stages`: studio-sized input beside the cheapest
reading pxr allows, in the same run.

- `instanced`: 10,000 instanceable references to one 5,000-triangle mesh (scene-graph
  instancing), and `pointinstancer`: the same mesh placed 10,000 times by a PointInstancer.
- `materialx`: 64 meshes, each bound to its own standard_surface in one referenced .mtlx with
  an image texture (through a place2d) and constants.

The peer, `pxr traversal`, opens the same stage and reads what any ingest must: every drawn
Mesh's points, counts and indices, with instance proxies, and each PointInstancer's
transforms. Time is the median of --repeat runs; memory is each side's peak resident set in a
fresh process above that process's size after imports (USD's C++ allocations included).
"""
from __future__ import annotations

import resource
from pathlib import Path

GRID = 50  # 50 x 50 quads = 5,000 triangles
INSTANCES = 10_000
MATERIALS = 64


def _grid_mesh(name: str, indent: str = "    ") -> str:
    n = GRID
    pts = ", ".join(f"({x / n}, {y / n}, 0)" for y in range(n + 1) for x in range(n + 1))
    idx = []
    for y in range(n):
        for x in range(n):
            a = y * (n + 1) + x
            idx += [a, a + 1, a + n + 2, a + n + 1]
    st = pts.replace(", 0)", ")")
    return (f'{indent}def Mesh "{name}"\n{indent}{{\n'
            f'{indent}    int[] faceVertexCounts = [{", ".join(["4"] * n * n)}]\n'
            f'{indent}    int[] faceVertexIndices = [{", ".join(map(str, idx))}]\n'
            f'{indent}    point3f[] points = [{pts}]\n'
            f'{indent}    texCoord2f[] primvars:st = [{st}] (interpolation = "vertex")\n'
            f'{indent}    uniform token subdivisionScheme = "none"\n{indent}}}\n')


def write_stages(folder: Path) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    header = '#usda 1.0\n(\n    metersPerUnit = 1\n    defaultPrim = "World"\n)\n'
    (folder / "grid.usda").write_text(header.replace("World", "Grid") + 'def Xform "Grid"\n{\n'
                                      + _grid_mesh("Geo") + "}\n")
    side = int(INSTANCES ** 0.5)
    refs = "".join(
        f'    def Xform "I{i}" (\n        instanceable = true\n'
        f'        prepend references = @./grid.usda@\n    )\n    {{\n'
        f'        double3 xformOp:translate = ({i % side * 1.1}, {i // side * 1.1}, 0)\n'
        f'        uniform token[] xformOpOrder = ["xformOp:translate"]\n    }}\n'
        for i in range(INSTANCES))
    instanced = folder / "instanced.usda"
    instanced.write_text(header + f'def Xform "World"\n{{\n{refs}}}\n')
    positions = ", ".join(f"({i % side * 1.1}, {i // side * 1.1}, 0)" for i in range(INSTANCES))
    pi = folder / "pointinstancer.usda"
    pi.write_text(header + 'def PointInstancer "World"\n{\n'
                  '    rel prototypes = [</World/Protos/Grid>]\n'
                  f'    int[] protoIndices = [{", ".join(["0"] * INSTANCES)}]\n'
                  f'    point3f[] positions = [{positions}]\n'
                  '    def Scope "Protos"\n    {\n' + _grid_mesh("Grid", "        ") + '    }\n}\n')
    from PIL import Image
    Image.new("RGB", (256, 256), (180, 120, 60)).save(folder / "wood.png")
    looks = "".join(f"""
  <place2d name="p{i}" type="vector2"><input name="scale" type="vector2" value="{1 + i % 4}, 1"/></place2d>
  <image name="img{i}" type="color3">
    <input name="file" type="filename" value="wood.png"/>
    <input name="texcoord" type="vector2" nodename="p{i}"/>
  </image>
  <standard_surface name="S{i}" type="surfaceshader">
    <input name="base_color" type="color3" nodename="img{i}"/>
    <input name="specular_roughness" type="float" value="{(i % 10) / 10}"/>
    <input name="metalness" type="float" value="{i % 2}"/>
    <input name="coat" type="float" value="0.5"/>
  </standard_surface>
  <surfacematerial name="M{i}" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="S{i}"/>
  </surfacematerial>""" for i in range(MATERIALS))
    (folder / "looks.mtlx").write_text(f'<?xml version="1.0"?>\n<materialx version="1.38">'
                                       f'{looks}\n</materialx>\n')
    meshes = "".join(
        f'    def Xform "P{i}" (\n        prepend apiSchemas = ["MaterialBindingAPI"]\n'
        f'        prepend references = @./grid.usda@\n    )\n    {{\n'
        f'        rel material:binding = </World/mtl/M{i}>\n'
        f'        double3 xformOp:translate = ({i % 8 * 1.1}, {i // 8 * 1.1}, 0)\n'
        f'        uniform token[] xformOpOrder = ["xformOp:translate"]\n    }}\n'
        for i in range(MATERIALS))
    mtlx = folder / "materialx.usda"
    mtlx.write_text(header + 'def Xform "World"\n{\n'
                    '    def Scope "mtl" (\n        prepend references = @./looks.mtlx@</MaterialX/Materials>\n'
                    f'    )\n    {{\n    }}\n{meshes}}}\n')
    return {"instanced": instanced, "pointinstancer": pi, "materialx": mtlx}


def pxr_traversal(path: str) -> int:
    """The peer: what any ingest must read from pxr; returns triangles drawn."""
    import numpy as np
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    total = 0
    it = iter(Usd.PrimRange(stage.GetPseudoRoot(),
                            Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    xforms = UsdGeom.XformCache()
    for prim in it:
        if prim.IsA(UsdGeom.PointInstancer):
            it.PruneChildren()
            pi = UsdGeom.PointInstancer(prim)
            mats = pi.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default())
            proto = stage.GetPrimAtPath(pi.GetPrototypesRel().GetForwardedTargets()[0])
            counts = np.asarray(UsdGeom.Mesh(proto).GetFaceVertexCountsAttr().Get())
            total += len(mats) * int((counts - 2).sum())
        elif prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            np.asarray(mesh.GetPointsAttr().Get())
            np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
            xforms.GetLocalToWorldTransform(prim)
            total += int((counts - 2).sum())
    return total


def ours(path: str) -> int:
    from pipeline.ingest import load_scene
    return load_scene(path).triangle_count


def _peak_worker(name: str, path: str) -> tuple[float, int]:
    """In a fresh process: MB of peak RSS the call adds above the process after imports."""
    import pxr.UsdGeom  # noqa: F401

    import pipeline.ingest  # noqa: F401 - imports are the baseline, not the measurement
    before = _high_water_kib()
    result = {"ours": ours, "pxr": pxr_traversal}[name](path)
    return (_high_water_kib() - before) / 1024.0, result


def _high_water_kib() -> int:
    """Peak resident set of this process (VmHWM; ru_maxrss would carry the parent's peak
    across the spawn's exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def peak_mb(name: str, path: Path) -> float:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_peak_worker, name, str(path)).result()[0]
