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

from core.scene import Cage, Creases, Mesh, Scene
from pipeline.normals import compute_tangents, smooth_normals

INFINITE = 10.0  # OpenSubdiv's Sdc::Crease::SHARPNESS_INFINITE: sharp at every level
BUDGET = 2_000_000  # triangles drawn (instances counted) that refinement may grow a scene to
COARSE = (2_500, 25_000)  # below the first: two levels; below the second: one; else none


def levels_for(triangles: int) -> int:
    return 2 if triangles < COARSE[0] else 1 if triangles < COARSE[1] else 0


def refine_scene(scene: Scene, budget: int, levels: int | None = None) -> int:
    """Refine every marked mesh of `scene` in place (`levels`, or `levels_for` its size),
    keeping the triangles drawn (instances counted) under `budget`; returns meshes refined.
    Meshes that share a Catmull-Clark cage (one per GeomSubset) are refined together, once."""
    uses = np.bincount([i.mesh for i in scene.instances], minlength=len(scene.meshes))
    drawn = sum(int(uses[i]) * m.triangle_count for i, m in enumerate(scene.meshes))
    refined = 0
    cages: dict[int, RefinedCage] = {}
    for i, mesh in enumerate(scene.meshes):
        if not mesh.subdivision or not uses[i]:
            continue
        n = levels_for(mesh.triangle_count if mesh.cage is None else _cage_triangles(mesh.cage)) \
            if levels is None else levels
        while n and drawn + int(uses[i]) * (refined_triangles(mesh, n) - mesh.triangle_count) > budget:
            n -= 1  # each level quadruples the triangles
        if n:
            drawn += int(uses[i]) * (refined_triangles(mesh, n) - mesh.triangle_count)
            if usable_cage(mesh):
                assert mesh.cage is not None
                key = id(mesh.cage)
                if key not in cages or cages[key].levels != n:
                    users = [m for j, m in enumerate(scene.meshes) if uses[j] and m.cage is mesh.cage]
                    cages[key] = refine_cage(mesh.cage, n, users)
                scene.meshes[i] = cages[key].mesh(mesh)
            else:
                scene.meshes[i] = refine(mesh, n)
            refined += 1
    return refined


def _cage_triangles(cage: Cage) -> int:
    return int((cage.counts - 2).sum())


def usable_cage(mesh: Mesh) -> bool:
    """A Catmull-Clark / bilinear cage whose corners still name this mesh's vertices (else the
    triangles are refined by Loop's rules)."""
    c = mesh.cage_corners
    return mesh.cage is not None and c is not None and len(c) == len(mesh.cage.corners) and \
        bool(len(c)) and int(c.max()) < len(mesh.positions) and bool((c >= 0).any())


def refined_triangles(mesh: Mesh, levels: int) -> int:
    """Triangles `mesh` has after `levels` levels: Catmull-Clark's first level makes a quad
    per polygon corner, each later one four of each quad, two triangles a quad; Loop's
    makes four triangles of each."""
    if not levels:
        return mesh.triangle_count
    if usable_cage(mesh):
        assert mesh.cage is not None and mesh.cage_corners is not None
        corners = int((mesh.cage_corners >= 0).sum())
        return 2 * corners * 4 ** (levels - 1)
    return mesh.triangle_count * 4 ** levels


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


# -- Catmull-Clark on the polygon cage --------------------------------------------------------
# One level (`cc_level`) splits each n-gon into n quads: a face point per face, an edge point
# per edge, a vertex point per vertex, with OpenSubdiv's masks (Sdc's Catmark scheme):
# - face point: the mean of the face's corners;
# - smooth edge point: 1/4 of each end and 1/4 of each face point; where one of the two faces
#   is a triangle and triangleSubdivisionRule = smooth, face weight w = (w0 + w1) / 2 with
#   0.470 for a triangle (0.25 for others) and 1/2 - w for each end;
# - smooth vertex point (n faces): (n-2)/n of itself, 1/n^2 of each edge neighbour and of
#   each face point; crease rule: 3/4 of itself, 1/8 of each end of its two sharp edges;
#   corner rule: stays put. Rule by sharpness: a vertex of sharpness > 0 or on three or more
#   sharp edges is a corner, on two a crease, else smooth (a dart: one sharp edge);
# - semi-sharp (DeRose, Kass, Truong 1998; OpenSubdiv's uniform decrement): an edge of
#   sharpness s >= 1 splits at its midpoint, 0 < s < 1 blends midpoint and smooth point by s;
#   children carry s - 1 (10 or more: for ever). Where a vertex's rule at the next level is
#   weaker than now, the two rules' points blend by the mean sharpness of what transitions.
# - borders and non-manifold edges are infinitely sharp; interpolateBoundary edgeAndCorner
#   makes a border vertex of one face a corner; none drops the faces that touch the border
#   (they still shape their neighbours, as OpenSubdiv's VTX_BOUNDARY_NONE holes do).
# Each attribute is refined as its primvar's interpolation asks (OpenSubdiv refines each
# channel on its own): vertex ones by these rules on the points, varying (and constant) ones
# bilinearly on the points, each face-varying (or uniform) one on its own topology (a corner's
# vertex there is its point and value: seams are borders) with faceVaryingLinearInterpolation:
# all = bilinear; boundaries = corners along every seam; cornersOnly = corners where a region
# has one face or is a bowtie; cornersPlus1 (USD's default) also where three or more regions
# meet at a point; cornersPlus2 also darts and both values beside a one-face region
# (`_fv_corners`); none = edgeOnly.

@dataclasses.dataclass
class Level:
    counts: np.ndarray  # F face sizes
    ids: np.ndarray     # per corner: its vertex
    values: np.ndarray  # N x d
    esharp: np.ndarray  # per corner: authored sharpness of the edge to the face's next corner
    vsharp: np.ndarray  # N authored vertex sharpness
    root: np.ndarray    # F: the cage face each face comes from


def _dec(s: np.ndarray) -> np.ndarray:
    return np.where(s >= INFINITE, s, np.maximum(s - 1.0, 0.0))


def _sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Rows of `values` summed by `index` into n rows (np.bincount per column: fast)."""
    return np.stack([np.bincount(index, values[:, k], minlength=n)
                     for k in range(values.shape[1])], axis=1)


def _edges(counts: np.ndarray, ids: np.ndarray, n: int):
    """(face of each corner, first corner of each face, previous corner, edge of each corner
    (to the next), edge ends e0 < e1)."""
    face = np.repeat(np.arange(len(counts)), counts)
    start = np.cumsum(counts) - counts
    first = start[face]
    pos = np.arange(len(ids)) - first
    size = counts[face]
    nxt, prv = first + (pos + 1) % size, first + (pos - 1) % size
    a, b = ids, ids[nxt]
    key, edge_of = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True)
    return face, start, prv, edge_of.reshape(-1), key // n, key % n


def cc_level(lv: Level, bilinear: bool = False, boundary: str = "edgeAndCorner",
             smooth_triangles: bool = False, extra_corners: np.ndarray | None = None) -> Level:
    """One level of Catmull-Clark (or bilinear) refinement; `extra_corners`: vertices made
    corners at this level (face-varying rules)."""
    counts, ids, p = lv.counts, lv.ids, lv.values
    n = len(p)
    face, start, prv, edge_of, e0, e1 = _edges(counts, ids, n)
    n_edges, n_faces = len(e0), len(counts)
    nf = np.bincount(edge_of, minlength=n_edges)
    authored = np.zeros(n_edges)
    authored[edge_of] = lv.esharp
    es = np.where(nf != 2, INFINITE, authored)
    vs = lv.vsharp
    vf = np.bincount(ids, minlength=n)
    if boundary == "edgeAndCorner":
        border = np.zeros(n, bool)
        border[e0[nf == 1]] = border[e1[nf == 1]] = True
        vs = np.where(border & (vf == 1), INFINITE, vs)
    if extra_corners is not None:
        vs = np.where(extra_corners, INFINITE, vs)
    if bilinear:
        es, vs = np.full(n_edges, INFINITE), np.full(n, INFINITE)

    fp = np.add.reduceat(p[ids], start, axis=0) / counts[:, None]
    a, b = p[e0], p[e1]
    w = np.where((counts[face] == 3) & smooth_triangles, 0.470, 0.25)
    fw = (0.5 * np.bincount(edge_of, weights=w, minlength=n_edges))[:, None]
    smooth_e = (0.5 - fw) * (a + b) + fw * _sum(edge_of, fp[face], n_edges)
    t = np.clip(es, 0.0, 1.0)[:, None]
    ep = (1 - t) * smooth_e + t * 0.5 * (a + b)

    ends, other = np.concatenate([e0, e1]), np.concatenate([e1, e0])
    k = np.maximum(vf, 1)[:, None].astype(np.float64)
    smooth_v = (k - 2) / k * p + (_sum(ends, p[other], n) + _sum(ids, fp[face], n)) / k ** 2

    def rule(esv, vsv):
        sharp = np.concatenate([esv > 0, esv > 0])
        count = np.bincount(ends[sharp], minlength=n)
        kind = np.where((vsv > 0) | (count > 2), 2, np.where(count == 2, 1, 0))
        crease = 0.75 * p + 0.125 * _sum(ends[sharp], p[other[sharp]], n)
        return kind, np.where((kind == 0)[:, None], smooth_v,
                              np.where((kind == 1)[:, None], crease, p))
    es_c, vs_c = _dec(es), _dec(vs)
    kind, now = rule(es, vs)
    kind_c, then = rule(es_c, vs_c)
    edge_tr = (es > 0) & (es_c <= 0)
    vert_tr = (vs > 0) & (vs_c <= 0)
    tsum = np.bincount(ends, weights=np.tile(np.where(edge_tr, es, 0.0), 2), minlength=n) + \
        np.where(vert_tr, vs, 0.0)
    tcount = np.bincount(ends, weights=np.tile(edge_tr, 2).astype(np.float64), minlength=n) + vert_tr
    weight = np.clip(tsum / np.maximum(tcount, 1), 0.0, 1.0)[:, None]
    vp = np.where((kind == kind_c)[:, None], now, weight * now + (1 - weight) * then)

    zero = np.zeros(len(ids))
    half = _dec(authored)
    return Level(
        counts=np.full(len(ids), 4, np.int64),
        ids=np.stack([ids, n + edge_of, n + n_edges + face, n + edge_of[prv]], axis=1).reshape(-1),
        values=np.concatenate([vp, ep, fp]),
        esharp=np.stack([half[edge_of], zero, zero, half[edge_of[prv]]], axis=1).reshape(-1),
        vsharp=np.concatenate([_dec(lv.vsharp), np.zeros(n_edges + n_faces)]),
        root=np.repeat(lv.root, counts))


def _fv_corners(mode: str, ids: np.ndarray, points: np.ndarray, counts: np.ndarray) -> np.ndarray | None:
    """Face-varying vertices made corners by `mode` at a level, as OpenSubdiv's FVarLevel
    tags a vertex's values (its "siblings", one per region of faces that share a value):
    boundaries: every value on a seam or the mesh's border; otherwise a value whose region
    is not one fan of faces (a bowtie); cornersPlus1 / cornersPlus2 also every value of a
    point where three or more regions meet, and both of two where one is a bowtie;
    cornersPlus2 also a dart (one value at an interior point a seam ends at) and both of two
    values where one region is a single face. A region of one face is a corner by
    edgeAndCorner's rule in `cc_level` (every mode but none)."""
    n = int(ids.max()) + 1
    point_of = np.zeros(n, np.int64)
    point_of[ids] = points
    _, _, _, edge_of, e0, e1 = _edges(counts, ids, n)
    once = np.bincount(edge_of, minlength=len(e0)) == 1  # borders of the value mesh: seams
    seam_edges = np.bincount(np.concatenate([e0[once], e1[once]]), minlength=n)
    if mode == "boundaries":
        return seam_edges > 0
    if mode not in ("none", "cornersOnly", "cornersPlus1", "cornersPlus2"):
        return None
    present = np.zeros(n, bool)
    present[ids] = True
    n_points = int(points.max()) + 1
    regions = np.bincount(point_of[present], minlength=n_points)[point_of]  # values at its point
    bowtie = present & (seam_edges > 2)
    sharp = bowtie.copy()
    if mode in ("cornersPlus1", "cornersPlus2"):
        bowtie_at = np.bincount(point_of[bowtie], minlength=n_points)[point_of] > 0
        sharp |= present & ((regions >= 3) | ((regions == 2) & bowtie_at))
    if mode == "cornersPlus2":
        _, _, _, p_edge_of, _, _ = _edges(counts, points, n_points)
        border_edge = np.bincount(p_edge_of) == 1
        on_border = np.zeros(n_points, bool)
        on_border[points[border_edge[p_edge_of]]] = True
        faces = np.bincount(ids, minlength=n)
        single_at = np.bincount(point_of[present & (faces == 1)], minlength=n_points)[point_of] > 0
        dart = present & (regions == 1) & (seam_edges > 0) & ~on_border[point_of]
        sharp |= dart | (present & (regions == 2) & single_at)
    return sharp


def _value_level(first: Level, own: np.ndarray, corner_own: np.ndarray, pts: np.ndarray,
                 vals: np.ndarray, by_point: bool) -> Level:
    """The cage level of one attribute over `mesh`'s own faces: by point (vertex / varying:
    one value a point) or on its own face-varying topology (a value per distinct point and
    value: where neighbours disagree, a seam that is a border of that topology)."""
    key = pts[:, None].astype(np.float64) if by_point else \
        np.concatenate([pts[:, None].astype(np.float64), vals], axis=1)
    _, fv = np.unique(key, axis=0, return_inverse=True)
    fv = fv.reshape(-1)
    values = np.zeros((int(fv.max()) + 1, vals.shape[1]))
    values[fv] = vals
    vsharp = np.zeros(len(values))
    vsharp[fv] = first.vsharp[pts]
    return Level(first.counts[own], fv, values, first.esharp[corner_own], vsharp,
                 np.flatnonzero(own))


@dataclasses.dataclass
class RefinedCage:
    """A cage refined `levels` levels: every level of its points (the face-varying data of
    each Mesh is refined beside them, on its own faces)."""
    cage: Cage
    levels: int
    steps: list[Level]   # level 0 (the cage) .. levels
    normals: np.ndarray  # per final point: smooth over every drawn quad
    drawn: np.ndarray    # per cage face: drawn (not dropped by interpolateBoundary none)

    def mesh(self, mesh: Mesh) -> Mesh:
        return _cage_mesh(self, mesh)


def refine_cage(cage: Cage, levels: int, users: list[Mesh]) -> RefinedCage:
    points, ids = np.unique(cage.corners, return_inverse=True)  # only points the faces use
    ids = ids.reshape(-1)
    n = len(points)
    lut = np.full(max(int(cage.corners.max()), int(cage.crease_edges.max(initial=0)),
                      int(cage.corner_points.max(initial=0))) + 1, -1, np.int64)
    lut[points] = np.arange(n)
    counts = cage.counts
    face, _, _, edge_of, e0, e1 = _edges(counts, ids, n)
    es = np.zeros(len(e0))
    ce = lut[cage.crease_edges] if len(cage.crease_edges) else np.zeros((0, 2), np.int64)
    ok = (ce >= 0).all(axis=1)
    ce, cs = np.sort(ce[ok], axis=1), cage.crease_sharpness[ok]
    key = e0 * n + e1
    at = np.searchsorted(key, ce[:, 0] * n + ce[:, 1])
    hit = at < len(key)
    hit[hit] &= key[at[hit]] == ce[hit, 0] * n + ce[hit, 1]
    np.maximum.at(es, at[hit], cs[hit])
    vs = np.zeros(n)
    cp = lut[cage.corner_points] if len(cage.corner_points) else np.zeros(0, np.int64)
    np.maximum.at(vs, cp[cp >= 0], cage.corner_sharpness[cp >= 0])
    drawn = np.ones(len(counts), bool)
    if cage.interpolate_boundary == "none":
        nf = np.bincount(edge_of)
        border = np.zeros(n, bool)
        border[e0[nf == 1]] = border[e1[nf == 1]] = True
        drawn = ~np.logical_or.reduceat(border[ids], np.cumsum(counts) - counts)
    lv = Level(counts, ids, cage.points[points].astype(np.float64), es[edge_of], vs,
               np.arange(len(counts)))
    steps = [lv]
    for _ in range(levels):
        lv = cc_level(lv, bilinear=cage.scheme == "bilinear", boundary=cage.interpolate_boundary,
                      smooth_triangles=cage.triangle_rule == "smooth" and len(steps) == 1)
        steps.append(lv)
    used = np.zeros(len(counts), bool)
    for m in users:
        if m.cage_corners is not None:
            used |= np.logical_or.reduceat(m.cage_corners >= 0, np.cumsum(counts) - counts)
    quads = lv.ids.reshape(-1, 4)[(used & drawn)[lv.root]]
    normals = smooth_normals(lv.values, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]))
    return RefinedCage(cage, levels, steps, normals, drawn)


def _cage_mesh(rc: RefinedCage, mesh: Mesh) -> Mesh:
    """`mesh`'s own faces of a refined cage, with its UVs and colours refined as
    faceVaryingLinearInterpolation asks, smooth normals broken along creases still sharp."""
    assert mesh.cage_corners is not None
    cage, first = rc.cage, rc.steps[0]
    starts = np.cumsum(first.counts) - first.counts
    own = np.logical_or.reduceat(mesh.cage_corners >= 0, starts) & rc.drawn
    names = [k for k in ("uv0", "uv1", "colors") if getattr(mesh, k) is not None]
    final = rc.steps[-1]
    keep_quads = own[final.root]
    pos_ids = final.ids.reshape(-1, 4)[keep_quads].reshape(-1)
    if names:
        corner_own = np.repeat(own, first.counts)
        pts = first.ids[corner_own]
        fv_mode = "all" if cage.scheme == "bilinear" else cage.face_varying
        kinds = mesh.cage_interpolation or {}
        # Attributes refined alike on one topology are refined together: vertex ones as the
        # points are, varying ones bilinearly on the points, each face-varying (or uniform)
        # one on its own values' topology (OpenSubdiv refines each channel on its own).
        groups: dict[str, list[str]] = {}
        for k in names:
            kind = kinds.get(k, "faceVarying")
            group = {"vertex": "vertex", "varying": "varying", "constant": "varying"}.get(kind, "fv:" + k)
            groups.setdefault(group, []).append(k)
        corner_ids = [pos_ids]
        rows: dict[str, np.ndarray] = {}
        for group, members in groups.items():
            vals = np.concatenate([getattr(mesh, k).astype(np.float64) for k in members],
                                  axis=1)[mesh.cage_corners[corner_own]]
            lv = _value_level(first, own, corner_own, pts, vals, not group.startswith("fv:"))
            for step in rc.steps[:-1]:
                step_own = np.repeat(own[step.root], step.counts)
                if group == "vertex":
                    lv = cc_level(lv, bilinear=cage.scheme == "bilinear",
                                  boundary=cage.interpolate_boundary,
                                  smooth_triangles=cage.triangle_rule == "smooth" and step is first)
                elif group == "varying":
                    lv = cc_level(lv, bilinear=True)
                else:
                    lv = cc_level(lv, bilinear=fv_mode == "all",
                                  boundary="edgeOnly" if fv_mode == "none" else "edgeAndCorner",
                                  smooth_triangles=cage.triangle_rule == "smooth" and step is first,
                                  extra_corners=_fv_corners(fv_mode, lv.ids, step.ids[step_own],
                                                            lv.counts))
            corner_ids.append(lv.ids)
            col = 0
            for k in members:
                width = getattr(mesh, k).shape[1]
                rows[k] = lv.values[:, col:col + width]
                col += width
        # A drawn vertex per distinct (point, value of each group) at a refined corner.
        table = np.stack(corner_ids, axis=1)
        _, first_at, vertex = np.unique(table, axis=0, return_index=True, return_inverse=True)
        vertex = vertex.reshape(-1)
        weld = pos_ids[first_at]
        picks = dict(zip(groups, table[first_at, 1:].T))
        attrs_of = {k: rows[k][picks[g]] for g, members in groups.items() for k in members}
    else:
        weld, vertex = np.unique(pos_ids, return_inverse=True)
        vertex = vertex.reshape(-1)
        attrs_of = {}
    quads = vertex.reshape(-1, 4)
    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    pos = final.values[weld]
    normals = rc.normals[weld]
    attrs: dict[str, np.ndarray] = {k: attrs_of[k] for k in names}
    sharp_corners = final.esharp > 0
    if sharp_corners.any():
        edge_ends = np.stack([final.ids, final.ids.reshape(-1, 4)[:, [1, 2, 3, 0]].reshape(-1)], 1)
        sharp_points = np.unique(edge_ends[sharp_corners & np.repeat(keep_quads, 4)])
        if len(sharp_points):
            pos, tri, attrs, normals = _split_normals(pos, tri, attrs, normals, weld,
                                                      final.values, sharp_points)
    out = dataclasses.replace(mesh, positions=pos.astype(np.float32), normals=normals,
                              indices=tri.astype(np.uint32), subdivision=None, creases=None,
                              cage=None, cage_corners=None)
    for k, v in attrs.items():
        setattr(out, k, v.astype(np.float32))
    if mesh.tangents is not None:
        uv = out.uv0 if out.uv0 is not None else out.uv1
        out.tangents = None if uv is None else compute_tangents(out.positions, normals, uv,
                                                                out.indices)
    return out
