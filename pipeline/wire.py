"""Points and lines as thin triangle geometry, so every renderer (raster and ray tracer) draws
them: each line segment becomes a square tube, each point a small octahedron. The caller picks
the radius from the scene size so they come out a few pixels wide in a default thumbnail.
"""
from __future__ import annotations

import numpy as np

POINTS, LINES, LINE_LOOP, LINE_STRIP = 0, 1, 2, 3


def segments(idx: np.ndarray, mode: int) -> np.ndarray:
    """Vertex index pairs (S x 2) of a LINES, LINE_LOOP or LINE_STRIP primitive."""
    if mode == LINES:
        return idx[: len(idx) - len(idx) % 2].reshape(-1, 2)
    if len(idx) < 2:
        return np.zeros((0, 2), idx.dtype)
    pairs = np.stack([idx[:-1], idx[1:]], axis=1)
    if mode == LINE_LOOP:
        pairs = np.concatenate([pairs, [[idx[-1], idx[0]]]])
    return pairs


def tubes(positions: np.ndarray, pairs: np.ndarray, radius: float, colors: np.ndarray | None):
    """Square tubes along `pairs` of `positions`: (positions, normals, triangles, colors)."""
    a, b = positions[pairs[:, 0]].astype(np.float64), positions[pairs[:, 1]].astype(np.float64)
    d = b - a
    length = np.linalg.norm(d, axis=1)
    keep = length > 0
    a, b, d, pairs = a[keep], b[keep], d[keep] / length[keep, None], pairs[keep]
    helper = np.where(np.abs(d[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    ring = np.stack([u, v, -u, -v], axis=1)                      # S x 4 x 3 outward directions
    pos = np.concatenate([a[:, None] + radius * ring, b[:, None] + radius * ring], axis=1)
    nrm = np.concatenate([ring, ring], axis=1)                   # S x 8 x 3
    k = np.arange(4)
    quads = np.stack([k, (k + 1) % 4, 4 + (k + 1) % 4, 4 + k], axis=1)  # 4 sides
    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])   # 8 x 3, outward
    tri = (tri[None] + 8 * np.arange(len(pos))[:, None, None]).reshape(-1, 3)
    col = None
    if colors is not None:
        col = np.concatenate([np.repeat(colors[pairs[:, 0]][:, None], 4, axis=1),
                              np.repeat(colors[pairs[:, 1]][:, None], 4, axis=1)], axis=1)
        col = col.reshape(-1, colors.shape[1])
    return (pos.reshape(-1, 3).astype(np.float32), nrm.reshape(-1, 3).astype(np.float32),
            tri.astype(np.uint32), col)


_OCTA = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
_OCTA_TRI = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                      [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])


def octahedra(positions: np.ndarray, idx: np.ndarray, radius: float, colors: np.ndarray | None):
    """A small octahedron at each point `idx`: (positions, normals, triangles, colors)."""
    centres = positions[idx].astype(np.float64)
    pos = centres[:, None] + radius * _OCTA[None]
    nrm = np.broadcast_to(_OCTA, pos.shape)
    tri = (_OCTA_TRI[None] + 6 * np.arange(len(idx))[:, None, None]).reshape(-1, 3)
    col = None if colors is None else np.repeat(colors[idx], 6, axis=0)
    return (pos.reshape(-1, 3).astype(np.float32), nrm.reshape(-1, 3).astype(np.float32),
            tri.astype(np.uint32), col)
