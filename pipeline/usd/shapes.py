"""Implicit USD shapes (Sphere, Cube, Cylinder, Cone, Capsule, Plane) as triangle meshes.

Tessellated with trimesh's primitives in the prim's own space, sized by its attributes and
turned to its `axis` (USD's default is Z). Round shapes get smooth normals; the rest are left
without normals, so the shared finishing step gives them flat ones (hard edges).
"""
from __future__ import annotations

import numpy as np
from pxr import Usd

# Rotations taking trimesh's Z-aligned primitives to the prim's axis (det +1).
_AXIS = {"Z": np.eye(3), "X": np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float),
         "Y": np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], float)}
SHAPES = ("Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane")


def tessellate(prim: Usd.Prim, time: Usd.TimeCode):
    """(points N x 3 float32, triangles M x 3, smooth normals or None) for an implicit shape,
    or None when the prim is not one of SHAPES."""
    import trimesh.creation as create  # only paid for by assets that use implicit shapes

    kind = str(prim.GetTypeName())
    get = lambda name, default: _positive(prim.GetAttribute(name).Get(time), default)  # noqa: E731
    axis = str(prim.GetAttribute("axis").Get(time) or "Z")
    smooth = True
    if kind == "Sphere":
        m = create.icosphere(subdivisions=3, radius=get("radius", 1.0))
    elif kind == "Cube":
        m, smooth = create.box(extents=[get("size", 2.0)] * 3), False
    elif kind == "Cylinder":
        m, smooth = create.cylinder(radius=get("radius", 1.0), height=get("height", 2.0),
                                    sections=64), False
    elif kind == "Cone":
        h = get("height", 2.0)
        m, smooth = create.cone(radius=get("radius", 1.0), height=h, sections=64), False
        m.apply_translation([0, 0, -h / 2])  # USD cones are centred on their origin
    elif kind == "Capsule":
        m = create.capsule(height=get("height", 1.0), radius=get("radius", 0.5), count=[32, 32])
    elif kind == "Plane":  # width along X (Z for axis X), length along Y (Z for axis Y)
        w, ln = get("width", 2.0) / 2, get("length", 2.0) / 2
        points = {"X": [(0, -ln, w), (0, -ln, -w), (0, ln, -w), (0, ln, w)],
                  "Y": [(-w, 0, ln), (w, 0, ln), (w, 0, -ln), (-w, 0, -ln)]}.get(
            axis, [(-w, -ln, 0), (w, -ln, 0), (w, ln, 0), (-w, ln, 0)])
        return np.array(points, np.float32), np.array([[0, 1, 2], [0, 2, 3]]), None
    else:
        return None
    points = _turn(np.asarray(m.vertices), axis)
    normals = _turn(np.asarray(m.vertex_normals), axis) if smooth else None
    return points, np.asarray(m.faces, np.int64), normals


def _turn(v: np.ndarray, axis: str) -> np.ndarray:
    return (v @ _AXIS.get(axis, _AXIS["Z"]).T).astype(np.float32)


def _positive(value, default: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    return v if np.isfinite(v) and v > 0 else default
