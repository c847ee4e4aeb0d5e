"""A triangle mesh's edges over its welded positions, with the (up to two) faces of each: what
renderer.raster.edges needs to find silhouettes. Baked with each mesh by pipeline.bake (a sort of every
position and every edge), so a render only reads it; computed
at render time for meshes that were not baked with it (made in memory, or over the cap)."""
from __future__ import annotations

import numpy as np

# Frames with more triangles (instances counted) get MSAA instead of edge anti-aliasing, and
# the bake stores no adjacency for assets over it.
MAX_TRIANGLES = 200_000


def welded_edges(positions: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edges E x 2 uint32, faces E x 2 int32) of a mesh. Vertices at the same position (split
    for UVs or normals) are one point, named by its first vertex; each edge is (lower, higher)
    point in the order of the positions' bytes, edges sorted by that pair. faces: the first two
    faces of the edge (in the order face 0..F of corner pair 01, then 12, then 20; a non-manifold
    edge keeps those two), the second -1 on a boundary edge. A face's collapsed edge (two
    corners at one point) is dropped."""
    raw = np.ascontiguousarray(positions).reshape(-1, 3)
    # Welded by exact value: each position's bytes as one key (a 1-D sort, not a row sort).
    keys = raw.view(np.dtype((np.void, raw.dtype.itemsize * 3))).reshape(-1)
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    tri = inverse.reshape(-1)[np.asarray(indices, np.int64).reshape(-1, 3)]
    ends = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    lo, hi = ends.min(axis=1), ends.max(axis=1)
    key = lo * len(first) + hi  # one int64 per edge
    order = np.argsort(key, kind="stable")
    key, face = key[order], np.tile(np.arange(len(tri)), 3)[order]
    start = np.flatnonzero(np.r_[len(key) > 0, key[1:] != key[:-1]])  # (none without faces)
    count = np.diff(np.r_[start, len(key)])
    faces = np.stack([face[start], np.where(count >= 2, face[np.minimum(start + 1, len(face) - 1)], -1)], 1)
    edges = np.stack([lo[order][start], hi[order][start]], 1)
    keep = edges[:, 0] != edges[:, 1]
    return first[edges[keep]].astype(np.uint32), faces[keep].astype(np.int32)
