"""Implicit USD shapes (Sphere, Cube, Cylinder, Cone, Capsule, Plane) as triangle meshes.

Tessellated in the prim's own space, sized by its attributes and turned to its `axis`
(USD's default is Z). Round shapes get smooth normals; the rest are left
without normals, so the shared finishing step gives them flat ones (hard edges).
"""
from __future__ import annotations

import numpy as np
from pxr import Usd

# Rotations taking the Z-aligned primitives to the prim's axis (det +1).
_AXIS = {"Z": np.eye(3), "X": np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float),
         "Y": np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], float)}
SHAPES = ("Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane")


def tessellate(prim: Usd.Prim, time: Usd.TimeCode):
    """(points N x 3 float32, triangles M x 3, smooth normals or None) for an implicit shape,
    or None when the prim is not one of SHAPES."""
    kind = str(prim.GetTypeName())
    get = lambda name, default: _positive(prim.GetAttribute(name).Get(time), default)  # noqa: E731
    axis = str(prim.GetAttribute("axis").Get(time) or "Z")
    normals = None
    if kind == "Sphere":
        r = get("radius", 1.0)
        unit, faces = icosphere(3)
        points, normals = unit * r, unit
    elif kind == "Cube":
        points, faces = _box(get("size", 2.0) / 2)
    elif kind == "Cylinder":
        points, faces = _lathe(get("radius", 1.0), get("height", 2.0), apex=False)
    elif kind == "Cone":
        points, faces = _lathe(get("radius", 1.0), get("height", 2.0), apex=True)
    elif kind == "Capsule":
        points, faces, normals = _capsule(get("radius", 0.5), get("height", 1.0))
    elif kind == "Plane":  # width along X (Z for axis X), length along Y (Z for axis Y)
        w, ln = get("width", 2.0) / 2, get("length", 2.0) / 2
        plane = {"X": [(0, -ln, w), (0, -ln, -w), (0, ln, -w), (0, ln, w)],
                 "Y": [(-w, 0, ln), (w, 0, ln), (w, 0, -ln), (-w, 0, -ln)]}.get(
            axis, [(-w, -ln, 0), (w, -ln, 0), (w, ln, 0), (-w, ln, 0)])
        return np.array(plane, np.float32), np.array([[0, 1, 2], [0, 2, 3]]), None
    else:
        return None
    return _turn(points, axis), np.asarray(faces, np.int64), None if normals is None else _turn(normals, axis)


# Tessellated here with numpy rather than trimesh.creation, whose import (trimesh, scipy)
# was half a second of a cold render of any stage with a sphere.
def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (points, outward triangles); each subdivision splits a triangle in 4."""
    t = (1 + 5 ** 0.5) / 2
    v = np.array([(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
                  (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)], float)
    f = np.array([(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
                  (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
                  (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)], np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[unique].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(-1) + len(v)
        n = len(f)
        ab, bc, ca = m[:n], m[n:2 * n], m[2 * n:]
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        f = np.concatenate([np.stack(x, axis=1) for x in
                            ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))])
        v = np.concatenate([v, mid])
    return v, f


def _box(h: float) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return corners, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def _lathe(r: float, h: float, apex: bool, sections: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """A Z-aligned cylinder (or cone, apex up) centred on the origin, capped, outward faces."""
    ang = np.arange(sections) * (2 * np.pi / sections)
    ring = np.stack([r * np.cos(ang), r * np.sin(ang), np.full(sections, -h / 2)], axis=1)
    i = np.arange(sections)
    j = (i + 1) % sections
    bottom = len(ring) * (1 if apex else 2)
    if apex:
        points = np.concatenate([ring, [(0, 0, h / 2), (0, 0, -h / 2)]])
        top = sections
        sides = np.stack([i, j, np.full(sections, top)], axis=1)
        caps = np.stack([np.full(sections, top + 1), j, i], axis=1)
    else:
        points = np.concatenate([ring, ring + (0, 0, h), [(0, 0, -h / 2), (0, 0, h / 2)]])
        u = i + sections
        uj = j + sections
        sides = np.concatenate([np.stack([i, j, uj], axis=1), np.stack([i, uj, u], axis=1)])
        caps = np.concatenate([np.stack([np.full(sections, bottom), j, i], axis=1),
                               np.stack([np.full(sections, bottom + 1), u, uj], axis=1)])
    return points, np.concatenate([sides, caps])


def _capsule(r: float, h: float, count: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A Z-aligned capsule: two hemispheres `h` apart, joined; smooth (sphere) normals."""
    rows = count // 2 * 2 + 1  # odd: an equator row for each hemisphere
    lat = np.linspace(np.pi / 2, -np.pi / 2, rows)
    lat = np.concatenate([lat[:rows // 2 + 1], lat[rows // 2:]])  # the equator twice
    lon = np.arange(count) * (2 * np.pi / count)
    cl, sl = np.cos(lat)[:, None], np.sin(lat)[:, None]
    normals = np.stack([cl * np.cos(lon), cl * np.sin(lon), np.broadcast_to(sl, (len(lat), count))],
                       axis=-1).reshape(-1, 3)
    shift = np.where(np.arange(len(lat)) <= rows // 2, h / 2, -h / 2)
    points = normals * r + np.repeat(shift, count)[:, None] * (0, 0, 1)
    faces = []
    for k in range(len(lat) - 1):
        a = k * count + np.arange(count)
        b = k * count + (np.arange(count) + 1) % count
        c, d = a + count, b + count
        faces += [np.stack([a, c, d], axis=1), np.stack([a, d, b], axis=1)]
    f = np.concatenate(faces)
    p = points[f]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return points, f[area > 1e-12 * max(r, 1e-9) ** 2], normals  # the poles' slivers dropped


def _turn(v: np.ndarray, axis: str) -> np.ndarray:
    return (v @ _AXIS.get(axis, _AXIS["Z"]).T).astype(np.float32)


def _positive(value, default: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    return v if np.isfinite(v) and v > 0 else default
