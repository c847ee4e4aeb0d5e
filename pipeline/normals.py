"""Vertex normals and tangents computed where an asset has none: the one implementation every
reader and the finishing step share."""
from __future__ import annotations

import numpy as np


def smooth_normals(positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unused vertices get +Y)."""
    p = positions.astype(np.float64)
    face = np.cross(p[indices[:, 1]] - p[indices[:, 0]], p[indices[:, 2]] - p[indices[:, 0]])
    acc = _scatter(indices, face, len(p))
    return _normalise(acc, fallback=np.array([0.0, 1.0, 0.0])).astype(np.float32)


def compute_tangents(positions: np.ndarray, normals: np.ndarray, uv: np.ndarray,
                     indices: np.ndarray) -> np.ndarray:
    """Per-vertex tangents (N x 4) from UV gradients, accumulated per vertex (Lengyel).

    UVs are glTF's (v down from the image top) while a normal map's green channel points up
    the image, so the bitangent is taken along -v: w = +1 when cross(N, T) points up the
    image. Shaders use B = cross(N, T.xyz) * T.w, as glTF specifies.
    """
    p, t = positions.astype(np.float64), uv.astype(np.float64)
    i0, i1, i2 = indices[:, 0], indices[:, 1], indices[:, 2]
    e1, e2 = p[i1] - p[i0], p[i2] - p[i0]
    d1, d2 = t[i1] - t[i0], t[i2] - t[i0]
    d1[:, 1] *= -1.0  # v up the image
    d2[:, 1] *= -1.0
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    inv = np.where(np.abs(det) > 1e-20, 1.0 / np.where(det == 0, 1.0, det), 0.0)[:, None]
    sdir = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    tdir = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    n = normals.astype(np.float64)
    s = _scatter(indices, sdir, len(p))
    b = _scatter(indices, tdir, len(p))
    s -= n * np.einsum("ij,ij->i", n, s)[:, None]  # Gram-Schmidt against the normal
    # Where UVs give no direction, any unit vector perpendicular to the normal will do.
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    fallback = np.cross(n, helper)
    s = np.where((np.linalg.norm(s, axis=1) > 1e-12)[:, None], s, fallback)
    s = _normalise(s, fallback=np.array([1.0, 0.0, 0.0]))
    w = np.where(np.einsum("ij,ij->i", np.cross(n, s), b) < 0.0, -1.0, 1.0)
    return np.concatenate([s, w[:, None]], axis=1).astype(np.float32)


def _scatter(indices: np.ndarray, per_face: np.ndarray, n: int) -> np.ndarray:
    """Sum a per-face vector onto each of the face's three vertices."""
    corners = indices.reshape(-1)
    values = np.repeat(per_face, 3, axis=0)
    return np.stack([np.bincount(corners, values[:, k], minlength=n) for k in range(3)], axis=1)


def _normalise(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    ok = length[:, 0] > 1e-20
    return np.where(ok[:, None], v / np.where(ok[:, None], length, 1.0), fallback)
