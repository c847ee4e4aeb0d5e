"""Baked visibility: per-vertex ambient occlusion of the environment by the asset itself.

The raster's image light (shaders/ibl.glsl) and the ray tracer's diffuse share read the
environment without visibility, so a duck's underside or a box's inside is lit by sky that a
path tracer finds blocked. Here, per vertex of every opaque mesh, a fixed stratified set of
cosine-weighted rays over the hemisphere about the vertex normal is cast against every
placement of every opaque mesh of the asset in world space (Embree, as the interior pass:
pipeline.interior.embree); the fraction that leaves the asset within `AO_DISTANCE` x the
asset's bounding-box diagonal is the vertex's ambient visibility (1: open, 0: enclosed).

Decisions:
- occluders: every instance whose material is not transmissive or blended (glass and
  see-through layers let the sky through; a MASK material counts as solid, its cut-outs are
  not seen by the rays) and does not emit (emissive factor x strength above `EMIT_THRESHOLD`
  in some channel, untextured: a path tracer finds an emitter's own light where it hides the
  sky, so open is nearer than dark; an emissive texture says per texel where it glows, so a
  textured emitter still occludes); receivers: the same meshes, unlit and transmissive ones
  get none;
- stored as uint8 (visibility x 255, core.baked.quantise_visibility): its steps are below the ray
  set's 1/64; readers take BakedMesh.visibility();
- a mesh with several placements gets a visibility per placement (K x N rows, placement-major:
  instances in other surroundings differ, as SimpleInstancing's 125 cubes, open on the outside
  and enclosed in the middle) while every placement fits the budget at `AO_MIN_RAYS`; past it,
  one shared row, the mean over its first `AO_INSTANCES` placements;
- the ray set: s x s strata of the unit square mapped to the cosine-weighted hemisphere
  (Malley), turned per vertex by a fixed pseudo-random rotation (seeded: a bake is
  reproducible) so that neighbouring vertices do not share one pattern's bias;
- each ray starts a scale-aware epsilon off the surface along the normal and as far toward
  the middle of the vertex's own triangles (a smooth normal's hemisphere never dips into a
  convex neighbour, so only real occluders are met; a vertex on a wall's foot or in a
  corner starts inside the walls and meets them);
- cost: `AO_RAYS` per vertex while the bake stays under `AO_MAX_RAYS`, fewer (down to
  `AO_MIN_RAYS`) on bigger assets; past that budget at the minimum, the placements traced per
  mesh drop to `AO_INSTANCES` (shared rows), then to one, and then vertices are sampled on a
  stride, the rest taking their sampled neighbour's (index order) value.
- refinement (a bake's, `refine`): per-vertex values interpolated over a large triangle
  cannot hold an occluder's shadow on it (a floor quad's four open corners before a wall, a
  box's contact shadow on a 2-triangle ground), so the triangles whose longest edge exceeds
  `REFINE_MIN_EDGE` x the diagonal (the biggest first, within `REFINE_MAX_RAYS`)
  are looked at on a coarse barycentric lattice (2 levels short of the finest, 1 to
  `REFINE_COARSE`; within half the budget), and those over
  which it finds the visibility varying by half the threshold are probed on one at their
  finest level (split until edges are no longer than `REFINE_MIN_EDGE` x the
  diagonal, `REFINE_DEPTH` levels at most), each probe averaged with its lattice neighbours
  (the ray set's noise would split triangles over which nothing varies); then, level by level,
  a triangle splits where a probe inside it is off the interpolation of its corners by more
  than `REFINE_THRESHOLD` in visibility (or `REFINE_BENT` in bent normal): its three edges
  split at their midpoints (the probe there gives the new vertex its values), and so do those
  edges in the triangles beside it and in their twins under other vertex indices (seams), each
  triangle splitting in 2, 3 or 4 by its split edges, so no crack opens. Every attribute of a
  new vertex is the mean of its edge's ends (split_mesh): the surface, its shading and its
  texturing are those interpolated before; only the visibility is finer. At most
  `REFINE_MAX_VERTICES` vertices (x placements where they are kept apart) per bake; an asset
  traced on a stride, transmissive and unlit meshes (no visibility) and emitters (the raster's
  area lights are their polygons) are never split;
- poses and rig frames bake no occlusion (pipeline.bake.POSED_OPTIONS) and so are never split:
  a rig re-poses its own unsplit template.
The renderer applies it to the environment terms only, never to punctual lights or the
ground shadow (core.lobes: the diffuse and specular occlusion functions).
"""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from core.baked import quantise_directions, quantise_visibility

log = logging.getLogger(__name__)

AO_RAYS = 64            # per vertex (8 x 8 strata), when the budget allows
AO_MIN_RAYS = 16        # per vertex at least (4 x 4 strata)
AO_MAX_RAYS = 1_000_000  # per bake: about 1.5 s on two loaded cores (0.6-0.9 M rays/s)
AO_DISTANCE = 1.0       # occluders count within this x the bounds' diagonal (the whole asset)
AO_INSTANCES = 4        # placements of one mesh averaged when not all fit the budget
EPSILON_SCALE = 1e-4    # ray start offset, x the bounds' diagonal
EMIT_THRESHOLD = 0.05   # emissive factor x strength (linear, max channel): a face emits above it
PASS_THROUGH = 3        # single-sided back faces a ray goes on through
_CHUNK = 1 << 20        # rays per Embree call (bounds the ray buffers' memory)
REFINE_DEPTH = 6        # split levels: an edge ends 1/64 as long at most
REFINE_THRESHOLD = 0.1  # a probe's visibility off its triangle's interpolation by more than
#                         this splits the triangle
REFINE_BENT = 0.2       # or its bent normal (unit vectors' distance: about 11 degrees)
REFINE_MIN_EDGE = 1 / 64  # edges shorter than this x the bounds' diagonal are not tested
REFINE_MAX_VERTICES = 20_000  # vertices (x placements kept apart) the refinement adds per bake
REFINE_MAX_RAYS = 500_000  # the refinement's probes per bake, at the vertices' rays each
REFINE_COARSE = 3       # the levels of the first look at a triangle (45 probes), at most


@dataclass
class OcclusionResult:
    # per mesh: N x 2 uint8 visibility x 255 (front, back side), K x N x 2 flattened to
    # (K N) x 2 when kept per placement, or None
    ao: list[np.ndarray | None]
    rays: int
    rays_per_vertex: int
    stride: int                  # 1: every vertex traced
    seconds: float
    # per mesh: N x 6 uint8 bent normals (core.baked.quantise_directions), front then back,
    # object space, shared by the placements; or None where `ao` is None
    bent: list[np.ndarray | None] | None = None
    # per mesh: how its triangles were split to hold its visibility (`ao` and `bent` are of
    # the split mesh), or None where it was left whole
    splits: list[Split | None] | None = None

    @property
    def vertices_added(self) -> int:
        return sum(len(s.parents) for s in self.splits or [] if s is not None)


@dataclass
class Split:
    """A mesh's triangles split at edge midpoints: vertex N + k is the mean of vertices
    parents[k] (each parent older than it), and `indices` are the new triangles."""
    parents: np.ndarray  # V x 2 int64
    indices: np.ndarray  # M' x 3 uint32
    depth: int = 1       # split levels


def split_mesh(mesh, split: Split):
    """`mesh` (core.baked.BakedMesh) with `split`'s vertices, every vertex attribute the
    mean of its two parents' (linear along the edge, as the raster interpolates it: the
    surface, its shading and its texturing stay as they were), and its triangles."""
    def grow(a: np.ndarray | None) -> np.ndarray | None:
        if a is None or len(a) != len(mesh.positions):
            return a
        out = np.concatenate([a, np.zeros((len(split.parents),) + a.shape[1:], a.dtype)])
        p, q = split.parents.T
        for _ in range(split.depth):  # a parent split at level d is right after d passes
            out[len(a):] = (out[p].astype(np.float64) + out[q]) / 2
        return out
    return dataclasses.replace(
        mesh, positions=grow(mesh.positions), normals=grow(mesh.normals),
        indices=split.indices, tangents=grow(mesh.tangents), uv0=grow(mesh.uv0), uv1=grow(mesh.uv1),
        colors=grow(mesh.colors), interior=grow(mesh.interior), edges=None, edge_faces=None,
        support=None, edge_order=None)


def hemisphere_set(rays: int) -> np.ndarray:
    """The fixed s x s stratified cosine-weighted directions about +Z ((s*s, 3) float64)."""
    s = max(1, int(math.isqrt(rays)))
    u1, u2 = np.meshgrid((np.arange(s) + 0.5) / s, (np.arange(s) + 0.5) / s, indexing="ij")
    r, phi = np.sqrt(u1.ravel()), 2 * np.pi * u2.ravel()
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u1.ravel()))], axis=1)


def _frames(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents t, b for unit normals n (Duff et al. 2017, branchless)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bt = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bt


def _ring_centres(pos: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Per vertex, the mean centroid of the triangles around it (itself where it has none)."""
    centroids = pos[tris].mean(axis=1)
    count = np.bincount(tris.ravel(), minlength=len(pos)).astype(np.float64)
    out = np.stack([np.bincount(tris.ravel(), np.repeat(centroids[:, k], 3), minlength=len(pos))
                    for k in range(3)], axis=1)
    return np.where(count[:, None] > 0, out / np.maximum(count, 1)[:, None], pos)


def _receives(material) -> bool:
    return material.material_class != "transmissive" and not material.unlit


def emits(material) -> bool:
    """Whether the material is an emitter the rays see through (see the module's decisions)."""
    if material.emissive_texture is not None:
        return False
    return max(material.emissive) * material.emissive_strength > EMIT_THRESHOLD


def _occludes(material) -> bool:
    return (material.material_class != "transmissive" and material.alpha_mode != "BLEND"
            and not emits(material))


def ambient_occlusion(meshes, bounds: np.ndarray, max_rays: int = AO_MAX_RAYS,
                      rays: int = AO_RAYS, refine: bool = False) -> OcclusionResult:
    """Per-vertex visibility of `meshes` (core.baked.BakedMesh: positions, normals, indices,
    transforms, material) against all of them; see the module's decisions. `refine`: split
    the triangles whose visibility varies across them (OcclusionResult.splits; apply with
    `split_mesh`)."""
    from pipeline.interior.embree import TriangleScene, spare_thread  # numba and Embree: bakes only
    from pipeline.interior.pairing import pair_quads

    start = time.perf_counter()
    out: list[np.ndarray | None] = [None] * len(meshes)
    bent_out: list[np.ndarray | None] = [None] * len(meshes)
    lo, hi = np.asarray(bounds, np.float64)
    diagonal = float(np.linalg.norm(hi - lo))
    receivers = [i for i, m in enumerate(meshes) if _receives(m.material) and len(m.positions)
                 and m.normals is not None and len(m.normals) == len(m.positions)]
    if not receivers or not diagonal > 0 or not math.isfinite(diagonal):
        return OcclusionResult(out, 0, 0, 1, time.perf_counter() - start)

    # Occluders: every placement in world space, one triangle soup, wound so that Embree's
    # geometric normal points out of the front (a mirroring placement reverses the winding).
    verts, tris, starts, single, base = [], [], [], [], 0
    for m in meshes:
        if not _occludes(m.material) or not len(m.indices):
            continue
        p = np.asarray(m.positions, np.float64)
        for x in np.asarray(m.transforms, np.float64).reshape(-1, 4, 4):
            verts.append(p @ x[:3, :3].T + x[:3, 3])
            t = np.asarray(m.indices, np.int64).reshape(-1, 3) + base
            tris.append(t[:, ::-1] if np.linalg.det(x[:3, :3]) < 0 else t)
            starts.append(base)
            single.append(not m.material.double_sided)
            base += len(p)
    if not tris:
        return OcclusionResult(out, 0, 0, 1, time.perf_counter() - start)
    quads = pair_quads(np.concatenate(tris).astype(np.uint32), spare_thread())
    scene = TriangleScene(np.concatenate(verts).astype(np.float32), quads)
    # Per quad: whether it is single-sided. Rays pass through such a face from behind, as
    # the raster culls it and the ray tracer lets its rays through.
    block = np.searchsorted(np.asarray(starts), quads[:, 0].astype(np.int64), side="right") - 1
    one_sided = np.asarray(single, bool)[block]

    # The budget: rays per vertex, then placements (every one kept apart, a few averaged,
    # one), then a vertex stride (a double-sided mesh traces both sides).
    sides = {i: 2 if meshes[i].material.double_sided else 1 for i in receivers}

    def count(placements: dict[int, int]) -> int:
        return sum(len(meshes[i].positions) * placements[i] * sides[i] for i in receivers)

    placements = {i: len(meshes[i].transforms) for i in receivers}
    apart = any(p > 1 for p in placements.values()) and count(placements) * AO_MIN_RAYS <= max_rays
    if not apart:
        placements = {i: min(len(meshes[i].transforms), AO_INSTANCES) for i in receivers}
    vertex_count = count(placements)
    per_vertex = max(AO_MIN_RAYS, min(rays, max_rays // max(vertex_count, 1)))
    per_vertex = int(math.isqrt(per_vertex)) ** 2
    if vertex_count * per_vertex > max_rays:
        placements = dict.fromkeys(receivers, 1)
        vertex_count = count(placements)
    stride = max(1, -(-vertex_count * per_vertex // max_rays))
    trace = _Tracer(scene, one_sided, hemisphere_set(per_vertex), max(EPSILON_SCALE * diagonal, 1e-7),
                    AO_DISTANCE * diagonal)
    rng = np.random.default_rng(0x0CC1)
    refine_rng = np.random.default_rng(0x0CC2)  # its own: a mesh left whole traces as before
    refine_rays = min(max_rays, REFINE_MAX_RAYS)
    refine_vertices = REFINE_MAX_VERTICES
    splits: list[Split | None] = [None] * len(meshes)
    traced_at: dict[int, tuple] = {}
    for i in receivers:
        m = meshes[i]
        pos = np.asarray(m.positions, np.float64)
        nrm = np.asarray(m.normals, np.float64)
        faces = np.asarray(m.indices, np.int64).reshape(-1, 3)
        traced = np.arange(0, len(pos), stride)
        xs = np.asarray(m.transforms, np.float64).reshape(-1, 4, 4)[:placements[i]]
        inward = (_ring_centres(pos, faces) - pos)[traced]
        acc, bent = _trace_points(trace, pos[traced], nrm[traced], inward, xs, sides[i],
                                  rng.uniform(0, 2 * np.pi, len(traced)))
        traced_at[i] = (pos, nrm, faces, traced, xs, acc, bent)
    # the refinement's budget goes to the meshes of the biggest triangles first (a backdrop
    # before the labels on it)
    def biggest(i: int) -> float:
        pos, _, faces, _, xs, _, _ = traced_at[i]
        if not len(faces):
            return 0.0
        c = pos[faces]
        edge = np.linalg.norm(c - np.roll(c, 1, axis=1), axis=2).max()
        return float(edge * np.max(np.linalg.svd(xs[:, :3, :3], compute_uv=False)))

    # emitters are left whole: the raster's area lights are their polygons (core.area_lights)
    # and their own light outshines the sky they would hide
    whole = {i for i in receivers if max(meshes[i].material.emissive) * meshes[i].material.emissive_strength > 0}
    for i in sorted(set(receivers) - whole, key=lambda i: -biggest(i)) if refine and stride == 1 else []:
        pos, nrm, faces, traced, xs, acc, bent = traced_at[i]
        kept_apart = apart and len(xs) > 1
        if refine_rays <= 0 or refine_vertices <= 0 or not len(faces):
            break
        grown, tested = _refine(trace, refine_rng, pos, nrm, faces, acc, bent, xs, sides[i],
                                kept_apart, REFINE_MIN_EDGE * diagonal, refine_rays // per_vertex,
                                refine_vertices // len(xs) if kept_apart else refine_vertices)
        refine_rays -= tested * per_vertex
        if grown is not None:
            split, pos, nrm, acc, bent = grown
            splits[i] = split
            refine_vertices -= len(split.parents) * (len(xs) if kept_apart else 1)
            traced_at[i] = (pos, nrm, faces, np.arange(len(pos)), xs, acc, bent)
    for i in receivers:
        pos, nrm, _, traced, xs, acc, bent = traced_at[i]
        if apart and len(xs) > 1:  # stride is 1 here: every placement fit at the minimum
            # no bent normals: placements in other surroundings bend other ways, and a mean
            # over them points nowhere in particular (the visibility rows still differ)
            out[i] = quantise_visibility(acc.reshape(-1, 2))
            continue
        bent_out[i] = _bent_rows(bent, nrm[traced], stride, len(pos))
        ao = quantise_visibility(acc.mean(axis=0))
        out[i] = ao if stride == 1 else np.repeat(ao, stride, axis=0)[:len(pos)]
    seconds = time.perf_counter() - start
    total = trace.rays
    result = OcclusionResult(out, total, per_vertex, stride, seconds, bent_out, splits)
    log.info("ambient occlusion: %d rays (%d per vertex, stride %d), %d vertices added, in %.2f s",
             total, per_vertex, stride, result.vertices_added, seconds)
    return result


def _trace_points(trace, pos, nrm, inward, xs, sides: int, turn):
    """Visibility (K x n x 2, per placement in `xs` and side) and bent normals (n x 2 x 3,
    object space, summed over the placements) at object-space points."""
    acc = np.zeros((len(xs), len(pos), 2))
    bent = np.zeros((len(pos), 2, 3))
    # every placement's points in one call (many small instances cost one Embree pass)
    lin = xs[:, :3, :3]
    p = (np.einsum("vj,kij->kvi", pos, lin) + xs[:, None, :3, 3]).reshape(-1, 3)
    n = np.einsum("vj,kji->kvi", nrm, np.linalg.inv(lin)).reshape(-1, 3)
    inward_w = np.einsum("vj,kij->kvi", inward, lin).reshape(-1, 3)
    turns = np.tile(turn, len(xs))
    for side in range(sides):
        visible, mean_dir = trace(p, -n if side else n, inward_w, turns)
        acc[..., side] = visible.reshape(len(xs), -1)
        # world directions back to object space as normals go (n_w = inv(L)^T n_o)
        bent[:, side] = np.einsum("kvi,kij->vj", mean_dir.reshape(len(xs), -1, 3), lin)
    if sides == 1:
        acc[..., 1] = acc[..., 0]  # never seen: culled from behind
        bent[:, 1] = -bent[:, 0]
    return acc, bent


def _unit_bent(bent: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Summed bent normals (n x 2 x 3) as unit vectors, the normal where every ray was blocked."""
    fallback = np.stack([normals, -normals], axis=1)
    length = np.linalg.norm(bent, axis=2, keepdims=True)
    unit = np.where(length > 1e-9, bent / np.maximum(length, 1e-30), fallback)
    return unit / np.maximum(np.linalg.norm(unit, axis=2, keepdims=True), 1e-30)


def _lattice(n: int) -> np.ndarray:
    """Barycentric points (1 - i/n - j/n, i/n, j/n) for i + j <= n, row i after row i - 1:
    point (i, j) is number i (n + 1) - i (i - 1) / 2 + j."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = (i + j <= n).ravel()
    i, j = i.ravel()[keep], j.ravel()[keep]
    return np.stack([n - i - j, i, j], axis=1) / n


def _refine(trace, rng, pos, nrm, tris, acc, bent, xs, sides: int, per_placement: bool,
            shortest: float, tests: int, vertices: int):
    """Split the triangles over which the visibility (or bent normal) traced at a lattice of
    probes is off the interpolation of their corners' by more than the thresholds, level by
    level (see the module's decisions): (None where none splits, else (Split, positions,
    normals, visibility, bent normals) of the split mesh; the hemispheres traced)."""
    cost = len(xs) * sides  # hemispheres per point
    scale = float(np.max(np.linalg.svd(xs[:, :3, :3], compute_uv=False)))
    corner = pos[tris]
    longest = np.linalg.norm(corner - np.roll(corner, 1, axis=1), axis=2).max(axis=1) * scale
    with np.errstate(divide="ignore"):
        levels = np.clip(np.ceil(np.log2(np.maximum(longest, 1e-30) / shortest)), 0, REFINE_DEPTH)
    levels = levels.astype(np.int64)
    size = (2 ** levels + 1) * (2 ** levels + 2) // 2  # a lattice's probes
    order = np.argsort(-longest, kind="stable")
    order = order[levels[order] > 0]
    # a coarse look first (`REFINE_COARSE` levels): only a triangle over which it finds the
    # visibility varying by half the threshold is probed finely (a convex solid, or a dense
    # mesh whose triangles each hold their shadow, costs a few probes a triangle)
    coarse = np.clip(levels - 2, 1, REFINE_COARSE)
    coarse_size = (2 ** coarse + 1) * (2 ** coarse + 2) // 2
    order = order[np.cumsum(coarse_size[order]) * cost <= tests // 2]  # the other half: fine
    if not len(order):
        return None, 0
    lattices = [_lattice(2 ** c) for c in coarse[order]]
    owner = np.repeat(np.arange(len(order)), coarse_size[order])
    bary = np.concatenate(lattices)
    ot = tris[order][owner]
    probe_p = np.einsum("pk,pkj->pj", bary, pos[ot])
    probe_n = np.einsum("pk,pkj->pj", bary, nrm[ot])
    v, b = _trace_points(trace, probe_p, probe_n, pos[ot].mean(axis=1) - probe_p, xs, sides,
                         rng.uniform(0, 2 * np.pi, len(bary)))
    tested = len(bary) * cost
    tests -= tested
    dev = np.abs(v - np.einsum("pk,xpks->xps", bary, acc[:, ot])).max(axis=(0, 2))
    if not per_placement:
        unit = _unit_bent(bent, nrm)
        mean = np.einsum("pk,pksj->psj", bary, unit[ot])
        mean /= np.maximum(np.linalg.norm(mean, axis=2, keepdims=True), 1e-30)
        turned = np.linalg.norm(_unit_bent(b, probe_n) - mean, axis=2).max(axis=1)
        dev = np.maximum(dev, turned * (REFINE_THRESHOLD / REFINE_BENT))
    varies = np.zeros(len(order))
    np.maximum.at(varies, owner, dev)
    order = order[varies > REFINE_THRESHOLD / 2]
    origins = order[np.cumsum(size[order]) * cost <= tests]  # the biggest first, in the budget
    if not len(origins):
        return None, tested
    # the probes: per origin triangle its lattice at its finest level
    first = np.concatenate([[0], np.cumsum(size[origins])])
    bary = np.concatenate([_lattice(2 ** levels[t]) for t in origins])
    owner = np.repeat(np.arange(len(origins)), size[origins])
    ot = tris[origins][owner]
    probe_p = np.einsum("pk,pkj->pj", bary, pos[ot])
    probe_n = np.einsum("pk,pkj->pj", bary, nrm[ot])
    inward = pos[ot].mean(axis=1) - probe_p  # toward the triangle's middle, as a vertex's ring
    probe_v, probe_b = _trace_points(trace, probe_p, probe_n, inward, xs, sides,
                                     rng.uniform(0, 2 * np.pi, len(bary)))
    tested += len(bary) * cost
    # each probe the mean of itself and its lattice neighbours: the ray set's noise (about
    # 0.03 at 64 rays where an occluder's outline crosses the hemisphere) would split
    # triangles over which nothing varies
    n = 2 ** levels[origins][owner]
    i, j = np.rint(bary[:, 1] * n).astype(np.int64), np.rint(bary[:, 2] * n).astype(np.int64)
    sum_v, sum_b, count = probe_v.copy(), probe_b.copy(), np.ones(len(bary))
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, -1), (-1, 1)):
        ni, nj = i + di, j + dj
        ok = (ni >= 0) & (nj >= 0) & (ni + nj <= n)
        at = first[owner[ok]] + ni[ok] * (n[ok] + 1) - ni[ok] * (ni[ok] - 1) // 2 + nj[ok]
        sum_v[:, ok] += probe_v[:, at]
        sum_b[ok] += probe_b[at]
        count[ok] += 1
    probe_v, probe_b = sum_v / count[None, :, None], sum_b / count[:, None, None]
    probe_u = _unit_bent(probe_b, probe_n)
    # per triangle: its origin (-1: none) and its corners' barycentrics in that origin
    origin = np.full(len(tris), -1, np.int64)
    origin[origins] = np.arange(len(origins))
    corners = np.tile(np.eye(3), (len(tris), 1, 1))
    fresh = np.ones(len(tris), bool)
    parents: list[np.ndarray] = []
    big = np.int64(1 << 31)
    depth = 0
    for _level in range(REFINE_DEPTH):
        # the triangles not tested yet, against their origin's probes inside them
        need = np.zeros(len(tris))
        unit = _unit_bent(bent, nrm)
        cand = np.flatnonzero(fresh & (origin >= 0))
        for c in np.array_split(cand, max(1, int(size[origins][origin[cand]].sum()) // 500_000 + 1)):
            count = size[origins][origin[c]]
            tri_of = np.repeat(c, count)
            probe = (first[origin[tri_of]] + np.arange(len(tri_of))
                     - np.repeat(np.cumsum(count) - count, count))
            inv = np.repeat(np.linalg.inv(corners[c]), count, axis=0)
            lam = np.einsum("pk,pkj->pj", bary[probe], inv)
            inside = (lam >= -1e-9).all(axis=1)
            tri_of, probe, lam = tri_of[inside], probe[inside], lam[inside]
            vt = tris[tri_of]
            mean = np.einsum("pk,xpks->xps", lam, acc[:, vt])
            dev = np.abs(probe_v[:, probe] - mean).max(axis=(0, 2))
            if not per_placement:
                b = np.einsum("pk,pksj->psj", lam, unit[vt])
                b /= np.maximum(np.linalg.norm(b, axis=2, keepdims=True), 1e-30)
                turned = np.linalg.norm(probe_u[probe] - b, axis=2).max(axis=1)
                dev = np.maximum(dev, turned * (REFINE_THRESHOLD / REFINE_BENT))
            np.maximum.at(need, tri_of, dev)
        fresh[:] = False
        split_tri = need > REFINE_THRESHOLD
        if not split_tri.any():
            break
        # the edges: every edge of a triangle that splits, and its twins under other vertex
        # indices (a UV seam, a hard edge), or a crack would open between them
        slots = tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)  # triangle t's edge k: slot 3 t + k
        ends = np.sort(slots, axis=1)
        edges, slot_edge = np.unique(ends[:, 0] * big + ends[:, 1], return_inverse=True)
        slot_edge = slot_edge.reshape(-1, 3)
        a, b_ = edges // big, edges % big
        _, weld = np.unique(pos, axis=0, return_inverse=True)
        weld = weld.ravel()
        welded, edge_weld = np.unique(np.minimum(weld[a], weld[b_]) * big + np.maximum(weld[a], weld[b_]),
                                      return_inverse=True)
        edge_weld = edge_weld.ravel()
        w_need = np.zeros(len(welded))
        np.maximum.at(w_need, edge_weld[slot_edge[split_tri]].ravel(), np.repeat(need[split_tri], 3))
        w_order = np.argsort(-w_need, kind="stable")
        w_order = w_order[w_need[w_order] > REFINE_THRESHOLD]
        w_count = np.bincount(edge_weld, minlength=len(welded))
        w_order = w_order[np.cumsum(w_count[w_order]) <= vertices]  # the most off first
        if not len(w_order):
            break
        go = np.zeros(len(welded), bool)
        go[w_order] = True
        split_edges = np.flatnonzero(go[edge_weld])
        vertices -= len(split_edges)
        depth += 1
        ta, tb = a[split_edges], b_[split_edges]
        mid_p, mid_n = (pos[ta] + pos[tb]) / 2, (nrm[ta] + nrm[tb]) / 2
        # the midpoints' values: a probe where one lies there, else traced now
        v_mid = np.zeros((len(xs), len(split_edges), 2))
        b_mid = np.zeros((len(split_edges), 2, 3))
        found = np.zeros(len(split_edges), bool)
        slot_of = np.full(len(edges), -1, np.int64)
        slot_of[slot_edge.ravel()] = np.arange(slot_edge.size)  # some slot holding each edge
        s_ = slot_of[split_edges]
        t_, k_ = s_ // 3, s_ % 3
        has = origin[t_] >= 0
        if has.any():
            o = origin[t_[has]]
            m = (corners[t_[has], k_[has]] + corners[t_[has], (k_[has] + 1) % 3]) / 2
            n = 2 ** levels[origins[o]]
            ij = m[:, 1:] * n[:, None]
            exact = np.all(np.abs(ij - np.rint(ij)) < 1e-6, axis=1)
            i, j = np.rint(ij).astype(np.int64).T
            at = first[o] + i * (n + 1) - i * (i - 1) // 2 + j
            where = np.flatnonzero(has)[exact]
            v_mid[:, where] = probe_v[:, at[exact]]
            b_mid[where] = probe_b[at[exact]]
            found[where] = True
        if not found.all():
            miss = np.flatnonzero(~found)
            centroid = pos[tris[t_[miss]]].mean(axis=1)
            v_mid[:, miss], b_mid[miss] = _trace_points(
                trace, mid_p[miss], mid_n[miss], centroid - mid_p[miss], xs, sides,
                rng.uniform(0, 2 * np.pi, len(miss)))
            tested += len(miss) * cost
        mid_of = np.full(len(edges), -1, np.int64)
        mid_of[split_edges] = len(pos) + np.arange(len(split_edges))
        parents.append(np.stack([ta, tb], axis=1))
        pos = np.concatenate([pos, mid_p])
        nrm = np.concatenate([nrm, mid_n])
        acc = np.concatenate([acc, v_mid], axis=1)
        bent = np.concatenate([bent, b_mid])
        mids = mid_of[slot_edge]
        parent, local = _split_triangles(mids >= 0)
        table = np.concatenate([tris, mids], axis=1)  # v0 v1 v2 m0 m1 m2
        bary6 = np.concatenate([corners, (corners + np.roll(corners, -1, axis=1)) / 2], axis=1)
        tris = np.take_along_axis(table[parent], local, axis=1)
        corners = np.take_along_axis(bary6[parent], local[..., None], axis=1)
        fresh = (mids[parent] >= 0).any(axis=1)
        origin = origin[parent]
        if vertices <= 0:
            break
    if not parents:
        return None, tested
    return (Split(np.concatenate(parents), tris.astype(np.uint32), depth), pos, nrm, acc, bent), tested


def _split_triangles(has: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (v0, v1, v2) with midpoints m_k on edge (v_k, v_k+1) where has[:, k], split
    in 2, 3 or 4 by how many edges split, each keeping the winding: per new triangle its
    parent and its corners as places 0-5 (v0 v1 v2 m0 m1 m2) of the parent."""
    count = has.sum(axis=1)
    # turn each triangle so that a lone split is on edge 0 and a lone whole edge is edge 2
    turn = np.where(count == 1, np.argmax(has, axis=1),
                    np.where(count == 2, (np.argmin(has, axis=1) + 1) % 3, 0))
    v = (np.arange(3)[None, :] + turn[:, None]) % 3  # turned corners v0 v1 v2
    m = v + 3                                        # and midpoints m0 m1 m2
    v0, v1, v2 = v.T
    m0, m1, m2 = m.T
    pieces = {0: [(v0, v1, v2)], 1: [(v0, m0, v2), (m0, v1, v2)],
              2: [(m0, v1, m1), (v0, m0, m1), (v0, m1, v2)],
              3: [(v0, m0, m2), (m0, v1, m1), (m2, m1, v2), (m0, m1, m2)]}
    parent, local = [], []
    for c, shapes in pieces.items():
        rows = np.flatnonzero(count == c)
        for shape in shapes:
            parent.append(rows)
            local.append(np.stack([x[rows] for x in shape], axis=1))
    return np.concatenate(parent), np.concatenate(local)


def _bent_rows(bent: np.ndarray, normals: np.ndarray, stride: int, count: int) -> np.ndarray:
    """Per traced vertex and side the mean unoccluded direction, normalised (a vertex whose
    every ray was blocked keeps its normal), quantised and spread over the stride."""
    rows = quantise_directions(_unit_bent(bent, normals).reshape(-1, 6))
    return rows if stride == 1 else np.repeat(rows, stride, axis=0)[:count]


class _Tracer:
    """Visibility of the hemispheres about normals n at points p, by the fixed ray set."""

    def __init__(self, scene, one_sided: np.ndarray, directions: np.ndarray, epsilon: float, reach: float):
        self.scene, self.one_sided, self.directions = scene, one_sided, directions
        self.epsilon, self.reach, self.rays = epsilon, reach, 0

    def __call__(self, p: np.ndarray, n: np.ndarray, inward: np.ndarray,
                 turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(visibility, the mean of the unblocked directions: the bent normal, unnormalised)
        per vertex; `inward`: per vertex, toward the middle of its own triangles."""
        eps, dirs = self.epsilon, self.directions
        length = np.linalg.norm(n, axis=1)
        usable = length > 1e-12
        n = n / np.where(usable, length, 1.0)[:, None]
        inward = inward / np.maximum(np.linalg.norm(inward, axis=1), 1e-30)[:, None]
        # The start: off the surface along the normal, and as far toward the middle of the
        # vertex's own triangles: a vertex on a wall's foot or in a box's corner starts inside
        # the walls it stands on, so its rays meet them (from a start on their planes, or
        # past their edges, they slip by).
        p = p + eps * (n + inward)
        t, b = _frames(n)
        c, s = np.cos(turn)[:, None], np.sin(turn)[:, None]
        t, b = c * t + s * b, c * b - s * t  # the vertex's turn of the set
        step = max(1, _CHUNK // len(dirs))
        visible = np.ones(len(p))
        mean_dir = n.copy()
        for a in range(0, len(p), step):
            sl = slice(a, a + step)
            d = (dirs[None, :, 0:1] * t[sl, None] + dirs[None, :, 1:2] * b[sl, None]
                 + dirs[None, :, 2:3] * n[sl, None]).reshape(-1, 3)
            origins = np.repeat(p[sl], len(dirs), axis=0).astype(np.float32)
            d = d.astype(np.float32)
            met = self._blocked(origins, d)
            visible[sl] = 1.0 - met.reshape(-1, len(dirs)).mean(axis=1)
            mean_dir[sl] = (d.reshape(-1, len(dirs), 3) * ~met.reshape(-1, len(dirs), 1)).mean(axis=1)
        return np.where(usable, visible, 1.0), np.where(usable[:, None], mean_dir, n)

    def _blocked(self, origins: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Whether each ray meets an occluder within reach. A single-sided face met from behind
        lets the ray through, as the raster culls it and the ray tracer passes it: the ray goes
        on past it (a few times: then it counts as open)."""
        blocked = np.zeros(len(d), bool)
        travelled = np.zeros(len(d), np.float32)
        live = np.arange(len(d))
        for _ in range(PASS_THROUGH + 1):
            hit, ng, prim = self.scene.closest(origins, d, travelled, live, normals=True)
            self.rays += len(live)
            met = hit + travelled[live] <= self.reach
            behind = met.copy()
            behind[met] = self.one_sided[prim[met]] & (np.einsum("ij,ij->i", d[live[met]], ng[met]) > 0)
            blocked[live[met & ~behind]] = True
            travelled[live[behind]] += hit[behind] + np.float32(self.epsilon)
            live = live[behind]
            if not len(live):
                break
        return blocked
