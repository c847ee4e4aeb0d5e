"""Subdivision surfaces refined at bake: Loop subdivision of the triangulated cage, in numpy.

USD meshes whose `subdivisionScheme` is catmullClark or loop are subdivision surfaces; USD's
ingest keeps their control cage (so counts match a pxr traversal and usdview's low
complexity) and marks the Mesh (`Mesh.subdivision`). At bake a coarse cage is refined one or
two levels (`levels_for`) so silhouettes are smooth. Both schemes are refined with Loop's
rules on the triangulated cage: the limit is smooth and close to Catmull-Clark's, though not
identical on quads. Vertices split for UV seams or hard edges are welded by position for the
stencils, so the surface does not crack along seams; UVs and colours are interpolated
linearly (face-varying linear, as USD's `faceVaryingLinearInterpolation = all`). Holes were
dropped at ingest; a border vertex where the border turns by more than 45 degrees is kept
as a corner.

Creases and corners (`Mesh.creases`, USD creaseIndices / cornerIndices) follow the semi-sharp
rules of DeRose, Kass and Truong (1998) on Loop's stencils: an edge of sharpness s >= 1 splits
at its midpoint and its halves carry s - 1 to the next level (10 or more: for ever, OpenSubdiv's
SHARPNESS_INFINITE); 0 < s < 1 blends the smooth and the sharp point by s. A vertex on two
sharp edges moves by the crease rule (3/4 v + 1/8 each crease neighbour), on three or more,
or an authored corner, stays put; by their mean sharpness (the corner's), blended likewise.
An infinitely sharp crease is a sharp line on the limit surface, a semi-sharp one a rounded
bevel that tightens with the sharpness. Normals become smooth
vertex normals of the refined surface; tangents are recomputed where the mesh had them.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from core.scene import Creases, Mesh, Scene
from pipeline.normals import compute_tangents, smooth_normals

INFINITE = 10.0  # OpenSubdiv's Sdc::Crease::SHARPNESS_INFINITE: sharp at every level
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
    sharp = _sharp_indices(pos, mesh.creases)
    for _ in range(levels):
        pos, tri, attrs, sharp = loop_step(pos, tri, attrs, sharp)
    _, weld = np.unique(pos, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    welded = np.zeros((weld.max() + 1, 3))
    welded[weld] = pos
    normals = smooth_normals(welded, weld[tri])[weld]
    if sharp is not None and (len(sharp[0]) or len(sharp[2])):
        pos, tri, attrs, normals = _split_normals(pos, tri, attrs, normals, weld, welded,
                                                  np.unique(weld[np.concatenate(
                                                      [sharp[0].reshape(-1), sharp[2]])]))
    out = dataclasses.replace(mesh, positions=pos.astype(np.float32), normals=normals,
                              indices=tri.astype(np.uint32), subdivision=None, creases=None,
                              **{k: v.astype(np.float32) for k, v in attrs.items()})
    if mesh.tangents is not None:
        uv = out.uv0 if out.uv0 is not None else out.uv1
        out.tangents = None if uv is None else compute_tangents(out.positions, normals, uv,
                                                                out.indices)
    return out


SHARP_NORMAL_COS = 0.5  # faces within 60 degrees of a corner's own share its normal there


def _split_normals(pos, tri, attrs, normals, weld, welded, sharp_vertices):
    """Normals that break along the creases still sharp after the last level: at each
    vertex on one, every triangle corner gets its own vertex whose normal averages only the
    incident faces turned less than 60 degrees from its own (the other side of the crease
    is not smoothed into it)."""
    wt = weld[tri]
    fn = np.cross(welded[wt[:, 1]] - welded[wt[:, 0]], welded[wt[:, 2]] - welded[wt[:, 0]])
    unit = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
    t_idx, k_idx = np.nonzero(np.isin(wt, sharp_vertices))
    order = np.argsort(wt[t_idx, k_idx], kind="stable")
    t_idx, k_idx = t_idx[order], k_idx[order]
    groups = np.split(np.arange(len(t_idx)), np.nonzero(np.diff(wt[t_idx, k_idx]))[0] + 1)
    new_normals = np.zeros((len(t_idx), 3))
    for g in groups:
        faces = t_idx[g]
        near = unit[faces] @ unit[faces].T > SHARP_NORMAL_COS  # corner x incident face
        n = near.astype(np.float64) @ fn[faces]
        new_normals[g] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    src = tri[t_idx, k_idx]
    tri = tri.copy()
    tri[t_idx, k_idx] = len(pos) + np.arange(len(t_idx))
    used, tri = np.unique(tri, return_inverse=True)  # the copies' originals drop out
    tri = tri.reshape(-1, 3)
    def keep(v, extra):
        return np.concatenate([v, extra])[used]
    return (keep(pos, pos[src]), tri, {k: keep(v, v[src]) for k, v in attrs.items()},
            keep(normals, new_normals.astype(normals.dtype)))


Sharp = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # edges K x 2, s, corners C, s


def _sharp_indices(pos: np.ndarray, creases: Creases | None) -> Sharp | None:
    """Creases by position -> by a vertex index of that position (any split copy: the
    stencils weld by position); ends that match no vertex are dropped."""
    if creases is None:
        return None
    table = {p.tobytes(): i for i, p in enumerate(pos)}
    def find(points):
        return np.array([table.get(p.tobytes(), -1) for p in
                         np.asarray(points, np.float64).reshape(-1, 3)], np.int64)
    e = find(creases.edges).reshape(-1, 2)
    ok = (e >= 0).all(axis=1)
    c = find(creases.corners)
    return (e[ok], np.asarray(creases.edge_sharpness, np.float64)[ok],
            c[c >= 0], np.asarray(creases.corner_sharpness, np.float64)[c >= 0])


def _sharpen(sharp: Sharp, wid, wpos, welded_edges, edge_point, vertex_point, b_count, n,
             rep_split):
    """Apply the semi-sharp crease and corner rules to the level's points; the next level's
    creases (halves, sharpness - 1) and corners (sharpness - 1)."""
    e_idx, e_s, c_idx, c_s = sharp
    nw = len(wpos)
    key = welded_edges[:, 0] * nw + welded_edges[:, 1]  # sorted: np.unique's rows are
    ends = np.sort(wid[e_idx], axis=1) if len(e_idx) else np.zeros((0, 2), np.int64)
    at = np.searchsorted(key, ends[:, 0] * nw + ends[:, 1]) if len(ends) else np.zeros(0, np.int64)
    ok = (at < len(key)) & (ends[:, 0] != ends[:, 1])
    ok[ok] &= key[at[ok]] == ends[ok, 0] * nw + ends[ok, 1]
    e_idx, e_s, at = e_idx[ok], e_s[ok], at[ok]
    es = np.zeros(len(welded_edges))
    np.maximum.at(es, at, e_s)
    a, b = wpos[welded_edges[:, 0]], wpos[welded_edges[:, 1]]
    w = np.clip(es, 0.0, 1.0)[:, None]
    edge_point = (1 - w) * edge_point + w * 0.5 * (a + b)

    on = es > 0
    both = welded_edges[on].reshape(-1)
    count = np.bincount(both, minlength=nw)
    s_sum = np.bincount(both, weights=np.repeat(es[on], 2), minlength=nw)
    ring = np.zeros_like(wpos)
    np.add.at(ring, both, wpos[welded_edges[on][:, ::-1].reshape(-1)])
    cs = np.zeros(nw)
    np.maximum.at(cs, wid[c_idx], c_s)
    crease_rule = np.where((count == 2)[:, None], 0.75 * wpos + 0.125 * ring, wpos)
    weight = np.where(cs > 0, cs, np.where(count >= 2, s_sum / np.maximum(count, 1), 0.0))
    weight = np.where((b_count > 0) & (cs <= 0), 0.0, weight)  # the border keeps its own rule
    rule = np.where((cs > 0)[:, None], wpos, crease_rule)
    wv = np.clip(weight, 0.0, 1.0)[:, None]
    vertex_point = (1 - wv) * vertex_point + wv * rule

    def less(s):
        return np.where(s >= INFINITE, s, s - 1.0)
    mid = n + rep_split[at]
    halves = np.concatenate([np.stack([e_idx[:, 0], mid], 1), np.stack([mid, e_idx[:, 1]], 1)])
    hs = np.tile(less(e_s), 2)
    next_sharp = (halves[hs > 0], hs[hs > 0], c_idx[less(c_s) > 0], less(c_s)[less(c_s) > 0])
    return edge_point, vertex_point, next_sharp


def loop_step(pos: np.ndarray, tri: np.ndarray, attrs: dict[str, np.ndarray],
              sharp: Sharp | None = None):
    """One level of Loop subdivision: (positions, triangles, attributes, creases), each
    triangle split in four; stencils on the position-welded topology, attributes linear on
    the split one; `sharp`: creases and corners by vertex index (`_sharp_indices`)."""
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
    if sharp is not None:
        rep_split = np.empty(len(welded_edges), np.int64)  # a split edge of each welded one
        rep_split[welded_of[first]] = np.arange(len(split_edges))
        edge_point, vertex_point, sharp = _sharpen(sharp, wid, wpos, welded_edges, edge_point,
                                                   vertex_point, b_count, n, rep_split)
    new_pos = np.concatenate([vertex_point[wid], edge_point[welded_of[first]]])
    new_attrs = {name: np.concatenate([v, 0.5 * (v[split_edges[:, 0]] + v[split_edges[:, 1]])])
                 for name, v in attrs.items()}
    m = n + split_of.reshape(3, t).T  # midpoints of edges (0,1), (1,2), (2,0)
    v0, v1, v2 = tri.T
    m0, m1, m2 = m.T
    new_tri = np.concatenate([np.stack(f, 1) for f in ((v0, m0, m2), (m0, v1, m1),
                                                      (m2, m1, v2), (m0, m1, m2))])
    return new_pos, new_tri, new_attrs, sharp
