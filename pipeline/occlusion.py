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
The renderer applies it to the environment terms only, never to punctual lights or the
ground shadow (core.lobes: the diffuse and specular occlusion functions).
"""
from __future__ import annotations

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
                      rays: int = AO_RAYS) -> OcclusionResult:
    """Per-vertex visibility of `meshes` (core.baked.BakedMesh: positions, normals, indices,
    transforms, material) against all of them; see the module's decisions."""
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
    for i in receivers:
        m = meshes[i]
        pos = np.asarray(m.positions, np.float64)
        nrm = np.asarray(m.normals, np.float64)
        traced = np.arange(0, len(pos), stride)
        turn = rng.uniform(0, 2 * np.pi, len(traced))  # per vertex, shared by its placements
        xs = np.asarray(m.transforms, np.float64).reshape(-1, 4, 4)[:placements[i]]
        acc = np.zeros((len(xs), len(traced), 2))
        bent = np.zeros((len(traced), 2, 3))  # object space, summed over the placements
        inward = (_ring_centres(pos, np.asarray(m.indices, np.int64).reshape(-1, 3)) - pos)[traced]
        # every placement's vertices in one call (many small instances cost one Embree pass)
        lin = xs[:, :3, :3]
        p = (np.einsum("vj,kij->kvi", pos[traced], lin) + xs[:, None, :3, 3]).reshape(-1, 3)
        n = np.einsum("vj,kji->kvi", nrm[traced], np.linalg.inv(lin)).reshape(-1, 3)
        inward_w = np.einsum("vj,kij->kvi", inward, lin).reshape(-1, 3)
        turns = np.tile(turn, len(xs))
        for side in range(sides[i]):
            visible, mean_dir = trace(p, -n if side else n, inward_w, turns)
            acc[..., side] = visible.reshape(len(xs), -1)
            # world directions back to object space as normals go (n_w = inv(L)^T n_o)
            bent[:, side] = np.einsum("kvi,kij->vj", mean_dir.reshape(len(xs), -1, 3), lin)
        if sides[i] == 1:
            acc[..., 1] = acc[..., 0]  # never seen: culled from behind
            bent[:, 1] = -bent[:, 0]
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
    log.info("ambient occlusion: %d rays (%d per vertex, stride %d) in %.2f s", total, per_vertex,
             stride, seconds)
    return OcclusionResult(out, total, per_vertex, stride, seconds, bent_out)


def _bent_rows(bent: np.ndarray, normals: np.ndarray, stride: int, count: int) -> np.ndarray:
    """Per traced vertex and side the mean unoccluded direction, normalised (a vertex whose
    every ray was blocked keeps its normal), quantised and spread over the stride."""
    fallback = np.stack([normals, -normals], axis=1)
    length = np.linalg.norm(bent, axis=2, keepdims=True)
    unit = np.where(length > 1e-9, bent / np.maximum(length, 1e-30), fallback)
    unit /= np.maximum(np.linalg.norm(unit, axis=2, keepdims=True), 1e-30)
    rows = quantise_directions(unit.reshape(-1, 6))
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
