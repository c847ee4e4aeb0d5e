"""Triangles paired into quads for Embree: the same surface in half the primitives.

Embree's SAH build costs per primitive, and it is most of the interior pass on a large mesh
(pipeline.interior.vectors, README "bench bake"). Embree splits a quad (v0, v1, v2, v3) into the
triangles (v0, v1, v3) and (v2, v3, v1); two triangles sharing an edge, each with its own
winding, are written as that quad exactly, so the quad mesh holds the very triangles of the
input (same vertices, same order up to rotation) and rays meet the same surface: 100k
triangles build in half the time (bench bake, interior-parts). A triangle left without a
partner becomes the quad (a, b, c, c), whose second half is degenerate and never hit.

Pairing is greedy and linear: first a triangle with the next one in the index buffer (how
exporters write a quad, and how grids and most meshes are laid out), then the rest among the
triangles around their vertices (scanned meshes such as the bunny). Any pairing is correct; a
better one only saves more build.
"""
from __future__ import annotations

from concurrent.futures import Executor

import numpy as np
from numba import njit

# Triangles from which pair_quads splits the work: below, the hand-off costs what it saves.
SPLIT_AT = 8192


@njit(cache=True, nogil=True)
def _shared_edge(tris, t, s):
    """The edge e of triangle t (t[e] -> t[e+1]) that triangle s has reversed, and the
    position f in s of that edge's start (s[f] = t[e+1]); (-1, -1) when there is none."""
    for e in range(3):
        x, y = tris[t, e], tris[t, (e + 1) % 3]
        if x == y:
            continue
        for f in range(3):
            if tris[s, f] == y and tris[s, (f + 1) % 3] == x:
                return e, f
    return -1, -1


@njit(cache=True, nogil=True)
def _write_pair(tris, quads, q, t, e, s, f):
    """Quad q from triangle t = (z, x, y) (rotated so that x -> y is the shared edge) and
    s = (y, x, d): v0 = z, v1 = x, v2 = d, v3 = y, so (v0, v1, v3) = t and (v2, v3, v1) = s."""
    quads[q, 0] = tris[t, (e + 2) % 3]
    quads[q, 1] = tris[t, e]
    quads[q, 2] = tris[s, (f + 2) % 3]
    quads[q, 3] = tris[t, (e + 1) % 3]


@njit(cache=True, nogil=True)
def _pair(tris, nverts):
    count = tris.shape[0]
    partner = np.full(count, -1, np.int32)  # 32-bit lists: half the memory traffic
    # 1. neighbours in the index buffer
    t = 0
    while t + 1 < count:
        e, f = _shared_edge(tris, t, t + 1)
        if e >= 0:
            partner[t], partner[t + 1] = t + 1, t
            t += 2
        else:
            t += 1
    # 2. the rest through the triangles around each vertex (a counting sort: one array of
    # lists): a partner of t's edge x -> y holds y -> x, so it is listed at y with x after y.
    start = np.zeros(nverts + 1, np.int32)
    for t in range(count):
        if partner[t] < 0:
            for e in range(3):
                start[tris[t, e] + 1] += 1
    for v in range(nverts):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    owner = np.empty(start[nverts], np.int32)
    after = np.empty(start[nverts], np.uint32)  # the vertex following this one in the owner
    for t in range(count):
        if partner[t] < 0:
            for e in range(3):
                v = tris[t, e]
                owner[fill[v]] = t
                after[fill[v]] = tris[t, (e + 1) % 3]
                fill[v] += 1
    for t in range(count):
        if partner[t] >= 0:
            continue
        for e in range(3):
            x, y = tris[t, e], tris[t, (e + 1) % 3]
            if x == y:  # a collapsed edge pairs nothing (as in _shared_edge)
                continue
            for k in range(start[y], start[y + 1]):
                s = owner[k]
                if after[k] == x and s != t and partner[s] < 0:
                    partner[t], partner[s] = s, t
                    break
            if partner[t] >= 0:
                break
    quads = np.empty((count, 4), np.uint32)  # at most one a triangle; the rows used are returned
    q = 0
    for t in range(count):
        s = partner[t]
        if s < 0:
            quads[q, 0], quads[q, 1], quads[q, 2] = tris[t, 0], tris[t, 1], tris[t, 2]
            quads[q, 3] = tris[t, 2]
            q += 1
        elif s > t:
            e, f = _shared_edge(tris, t, s)
            _write_pair(tris, quads, q, t, e, s, f)
            q += 1
    return quads[:q]


def pair_quads(triangles: np.ndarray, pool: Executor | None = None) -> np.ndarray:
    """(n, 3) triangle indices -> (m, 4) uint32 Embree quads holding the same triangles.

    Given a pool (a spare thread), a large mesh is paired as two halves of its index buffer at
    once: the pairs that straddle the halves are lost (a few percent more quads on the bunny,
    none on a grid), for a shorter pairing."""
    tris = np.ascontiguousarray(triangles, np.uint32).reshape(-1, 3)
    if len(tris) >= 2**31:
        raise ValueError(f"{len(tris)} triangles: more than the pairing's 32-bit lists hold")
    nverts = int(tris.max()) + 1 if len(tris) else 0
    if pool is None or len(tris) < SPLIT_AT:
        return _pair(tris, nverts)
    half = len(tris) // 2
    second = pool.submit(_pair, tris[half:], nverts)
    return np.concatenate([_pair(tris[:half], nverts), second.result()])
