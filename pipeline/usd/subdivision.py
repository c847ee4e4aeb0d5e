"""Subdivision surfaces refined at bake: Loop subdivision of the triangulated cage, in numpy.

USD meshes whose `subdivisionScheme` is catmullClark or loop are subdivision surfaces; USD's
ingest keeps their control cage (so counts match a pxr traversal and usdview's low
complexity) and marks the Mesh (`Mesh.subdivision`). At bake a coarse cage is refined one or
two levels (`levels_for`) so silhouettes are smooth. Both schemes are refined with Loop's
rules on the triangulated cage: the limit is smooth and close to Catmull-Clark's, though not
identical on quads. Vertices split for UV seams or hard edges are welded by position for the
stencils, so the surface does not crack along seams; UVs and colours are interpolated
linearly (face-varying linear, as USD's `faceVaryingLinearInterpolation = all`). Creases,
authored corners and holes are not read (holes were dropped at ingest); a border vertex
where the border turns by more than 45 degrees is kept as a corner. Normals become smooth
vertex normals of the refined surface; tangents are recomputed where the mesh had them.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from core.scene import Mesh, Scene
from pipeline.normals import compute_tangents, smooth_normals

BUDGET = 2_000_000  # triangles drawn (instances counted) that refinement may grow a scene to
COARSE = (2_500, 25_000)  # below the first: two levels; below the second: one; else none


def levels_for(triangles: int) -> int:
    return 2 if triangles < COARSE[0] else 1 if triangles < COARSE[1] else 0


def refine_scene(scene: Scene, budget: int, levels: int | None = None) -> int:
    """Refine every marked mesh of `scene` in place (`levels`, or `levels_for` its size),
    keeping the triangles drawn (instances counted) under `budget`; returns meshes refined."""
    uses = np.bincount([i.mesh for i in scene.instances], minlength=len(scene.meshes))
    drawn = sum(int(uses[i]) * m.triangle_count for i, m in enumerate(scene.meshes))
    refined = 0
    for i, mesh in enumerate(scene.meshes):
        if not mesh.subdivision or not uses[i]:
            continue
        n = levels_for(mesh.triangle_count) if levels is None else levels
        while n and drawn + int(uses[i]) * mesh.triangle_count * (4 ** n - 1) > budget:
            n -= 1  # each level quadruples the triangles
        if n:
            drawn += int(uses[i]) * mesh.triangle_count * (4 ** n - 1)
            scene.meshes[i] = refine(mesh, n)
            refined += 1
    return refined


def refine(mesh: Mesh, levels: int) -> Mesh:
    pos, tri = mesh.positions.astype(np.float64), mesh.indices.astype(np.int64)
    attrs = {k: getattr(mesh, k) for k in ("uv0", "uv1", "colors") if getattr(mesh, k) is not None}
    for _ in range(levels):
        pos, tri, attrs = loop_step(pos, tri, attrs)
    _, weld = np.unique(pos, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    welded = np.zeros((weld.max() + 1, 3))
    welded[weld] = pos
    normals = smooth_normals(welded, weld[tri])[weld]
    out = dataclasses.replace(mesh, positions=pos.astype(np.float32), normals=normals,
                              indices=tri.astype(np.uint32), subdivision=None,
                              **{k: v.astype(np.float32) for k, v in attrs.items()})
    if mesh.tangents is not None:
        uv = out.uv0 if out.uv0 is not None else out.uv1
        out.tangents = None if uv is None else compute_tangents(out.positions, normals, uv,
                                                                out.indices)
    return out


def loop_step(pos: np.ndarray, tri: np.ndarray, attrs: dict[str, np.ndarray]):
    """One level of Loop subdivision: (positions, triangles, attributes), each triangle split
    in four; stencils on the position-welded topology, attributes linear on the split one."""
    n, t = len(pos), len(tri)
    _, wid = np.unique(pos, axis=0, return_inverse=True)
    wid = wid.reshape(-1)
    wpos = np.zeros((wid.max() + 1, 3))
    wpos[wid] = pos
    half = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])  # edge k of t at k*T+t
    opposite = wid[np.concatenate([tri[:, 2], tri[:, 0], tri[:, 1]])]
    split_edges, split_of = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True)
    split_of = split_of.reshape(-1)
    welded_edges, welded_of = np.unique(np.sort(wid[half], axis=1), axis=0, return_inverse=True)
    welded_of = welded_of.reshape(-1)
    faces = np.bincount(welded_of, minlength=len(welded_edges))
    opp_sum = np.zeros((len(welded_edges), 3))
    np.add.at(opp_sum, welded_of, wpos[opposite])
    a, b = wpos[welded_edges[:, 0]], wpos[welded_edges[:, 1]]
    edge_point = np.where((faces == 2)[:, None], 0.375 * (a + b) + 0.125 * opp_sum, 0.5 * (a + b))

    ends = welded_edges.reshape(-1)
    other = welded_edges[:, ::-1].reshape(-1)
    valence = np.bincount(ends, minlength=len(wpos))
    ring = np.zeros_like(wpos)
    np.add.at(ring, ends, wpos[other])
    border = np.repeat(faces == 1, 2)
    b_count = np.bincount(ends[border], minlength=len(wpos))
    b_ring = np.zeros_like(wpos)
    np.add.at(b_ring, ends[border], wpos[other[border]])
    k = np.maximum(valence, 1)[:, None]
    beta = np.where(k > 3, 3.0 / (8.0 * k), 3.0 / 16.0)
    vertex_point = (1 - k * beta) * wpos + beta * ring
    crease = (b_count == 2)[:, None]
    vertex_point = np.where(crease, 0.75 * wpos + 0.125 * b_ring, vertex_point)
    # A border vertex where the border turns sharply is a corner and stays put, as USD's
    # default interpolateBoundary (edgeAndCorner) keeps a cage's corners; non-manifold too.
    ends_b, other_b = ends[border], other[border]
    d = wpos[other_b] - wpos[ends_b]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    dir_sum = np.zeros_like(wpos)
    np.add.at(dir_sum, ends_b, d)
    corner = (b_count == 2) & (np.linalg.norm(dir_sum, axis=1) > 2 * np.cos(np.radians(67.5)))
    vertex_point = np.where((corner | (b_count > 2))[:, None], wpos, vertex_point)

    first = np.empty(len(split_edges), np.int64)
    first[split_of] = np.arange(len(half))
    new_pos = np.concatenate([vertex_point[wid], edge_point[welded_of[first]]])
    new_attrs = {name: np.concatenate([v, 0.5 * (v[split_edges[:, 0]] + v[split_edges[:, 1]])])
                 for name, v in attrs.items()}
    m = n + split_of.reshape(3, t).T  # midpoints of edges (0,1), (1,2), (2,0)
    v0, v1, v2 = tri.T
    m0, m1, m2 = m.T
    new_tri = np.concatenate([np.stack(f, 1) for f in ((v0, m0, m2), (m0, v1, m1),
                                                      (m2, m1, v2), (m0, m1, m2))])
    return new_pos, new_tri, new_attrs
