"""Interior vectors for refractive meshes (paper §4.2.3.2): per vertex, vertex -> exit point.

For each vertex a ray starts a small, scale-aware epsilon inside the surface and travels along
the negated vertex normal; Embree finds the first triangle of the mesh's own geometry it hits
(pipeline.interior.embree: the mesh shared in place as quads, an SAH BVH, packets traced on every core).
We store the object-space vector from the vertex to that hit (not a bare distance) so the
renderer can transform it by any world matrix, non-uniform scales included.

Edge cases, decided once here:
- a hit within epsilon of the ray origin is a neighbouring triangle grazed at the start (creases,
  corners of split-normal meshes), not the far side: the ray is continued past it;
- a ray that still misses (open meshes, sheets, holes) gets the FALLBACK: the distance along the
  ray to where it leaves the mesh's axis-aligned bounding box. Always finite; a flat sheet gets
  ~0, a half-open shape a plausible thickness. Misses are counted;
- a vertex with a zero or non-finite normal gets the zero vector (counted as degenerate);
- seam-split vertices (same position, different UV or normal) each cast their own ray; equal
  position and normal give equal vectors, so UV seams never show;
- several shells are handled by testing against all triangles of the mesh: a ray from one shell
  exits through its own shell, or through a nested one (a hollow glass's inner wall), which is
  where light leaves that material.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.interior.embree import TriangleScene, spare_thread
from pipeline.interior.pairing import pair_quads

log = logging.getLogger(__name__)

EPSILON_SCALE = 1e-4    # ray start offset, as a fraction of the mesh's bounding-box diagonal
GRAZE_RETRIES = 3       # times a ray is continued past a hit at ~0 distance


@dataclass
class InteriorResult:
    vectors: np.ndarray      # N x 3 float32, object space, vertex -> exit point
    rays: int                # rays cast, continuations included
    misses: int              # vertices that got the bounding-box fallback
    degenerate: int          # vertices with an unusable normal (zero vector stored)
    build_seconds: float     # quad pairing and Embree BVH build
    trace_seconds: float     # ray casting, continuations included

    @property
    def seconds(self) -> float:
        return self.build_seconds + self.trace_seconds

    @property
    def rays_per_second(self) -> float:
        """Throughput of BVH build plus tracing (the ray setup and fallbacks, ~5% more, are not
        timed here; `bench bake` times the whole call)."""
        return self.rays / self.seconds if self.seconds > 0 else 0.0


def interior_vectors(positions: np.ndarray, normals: np.ndarray, indices: np.ndarray,
                     epsilon: float | None = None) -> InteriorResult:
    """Object-space vectors from each vertex to where a ray along -normal leaves the mesh."""
    p = np.ascontiguousarray(positions, dtype=np.float32).reshape(-1, 3)
    nrm = np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3)
    tris = np.ascontiguousarray(indices, dtype=np.uint32).reshape(-1, 3)
    count = len(p)
    if len(nrm) != count:  # the compiled loops index both by vertex
        raise ValueError(f"{len(nrm)} normals for {count} vertices")
    if len(tris) and int(tris.max()) >= count:  # Embree would read past the vertex buffer
        raise ValueError(f"triangle index {int(tris.max())} out of range for {count} vertices")
    if count == 0:
        return InteriorResult(np.zeros((0, 3), np.float32), 0, 0, 0, 0.0, 0.0)

    lo, hi, direction, usable = _ray_setup(p, nrm)
    diagonal = float(np.linalg.norm(hi - lo))
    if epsilon is None:
        # Scale-aware, and never below float32 resolution at the mesh's coordinates.
        ulp = float(np.spacing(np.float32(max(-lo.min(), hi.max()))))
        epsilon = max(EPSILON_SCALE * diagonal, 16 * ulp, 1e-12)
    todo = np.flatnonzero(usable)
    degenerate = count - len(todo)

    start = time.perf_counter()
    # The triangles as Embree quads: half the primitives for the BVH build (pipeline.interior.pairing).
    scene = TriangleScene(p, pair_quads(tris, spare_thread())) if len(tris) else None
    build = time.perf_counter() - start

    start = time.perf_counter()
    travelled = np.full(count, epsilon, np.float32)  # distance from the vertex, per ray
    hit = np.zeros(count, bool)
    rays = 0
    live = todo
    for attempt in range(GRAZE_RETRIES + 1):
        if len(live) == 0 or scene is None:
            break
        t = scene.closest(p, direction, travelled, live)  # rays from p + travelled * direction
        rays += len(live)
        live = _advance(travelled, hit, live, t, np.float32(epsilon), attempt < GRAZE_RETRIES)
    trace = time.perf_counter() - start

    missed = np.flatnonzero(usable & ~hit)
    if len(missed):
        travelled[missed] = _box_exit(p[missed], direction[missed], lo, hi)
    out = _vectors(direction, travelled)
    result = InteriorResult(out, rays, len(missed), degenerate, build, trace)
    log.debug("interior: %d vertices, %d rays, %d misses, %.2f M rays/s", count, rays,
              len(missed), result.rays_per_second / 1e6)
    return result


@njit(cache=True, nogil=True)
def _box_exit(origin, direction, lo, hi):
    """Distance along each ray (rows of (m, 3) float32) to where it leaves the box [lo, hi]
    (origins inside or on it; 0 where none is found)."""
    out = np.empty(len(origin), np.float32)
    for k in range(len(origin)):
        t = np.float32(np.inf)
        for axis in range(3):
            d = direction[k, axis]
            if d > 0:
                t = min(t, (hi[axis] - origin[k, axis]) / d)
            elif d < 0:
                t = min(t, (lo[axis] - origin[k, axis]) / d)
        out[k] = max(t, np.float32(0.0)) if np.isfinite(t) else np.float32(0.0)
    return out


@njit(cache=True, nogil=True)
def _ray_setup(p, normals):
    """The mesh's bounds, and per vertex the ray direction (the unit negated normal) and
    whether the normal is usable (finite, not zero; else the direction is zero). One compiled
    pass over the (N, 3) rows: numpy's reductions over such rows, or the (3, N) copies that
    avoid them, cost about as much as a small mesh's tracing."""
    lo, hi = p[0].copy(), p[0].copy()
    direction = np.zeros(p.shape, np.float32)
    usable = np.zeros(len(p), np.bool_)
    shortest = np.float32(1e-8)
    for k in range(len(p)):
        for axis in range(3):
            lo[axis] = min(lo[axis], p[k, axis])
            hi[axis] = max(hi[axis], p[k, axis])
        x, y, z = normals[k, 0], normals[k, 1], normals[k, 2]
        length = np.sqrt(x * x + y * y + z * z)
        if np.isfinite(length) and length > shortest:
            usable[k] = True
            direction[k, 0], direction[k, 1], direction[k, 2] = -x / length, -y / length, -z / length
    return lo, hi, direction, usable


@njit(cache=True, nogil=True)
def _advance(travelled, hit, live, t, epsilon, retry):
    """Each live ray's end moved to its hit (t: the distances from the ray origins, inf for a
    miss). A hit closer than epsilon grazed a neighbour at the start: with `retry` that ray
    continues from epsilon past it, and it is returned among the rays to cast again. In
    float32 throughout, as the rays are (epsilon a float32)."""
    again = np.empty(len(live), np.int64)
    count = 0
    for k in range(len(live)):
        v, d = live[k], t[k]
        if not np.isfinite(d):
            continue
        if retry and d < epsilon:
            travelled[v] += d + epsilon
            again[count] = v
            count += 1
        else:
            travelled[v] += d
            hit[v] = True
    return again[:count]


@njit(cache=True, nogil=True)
def _vectors(direction, travelled):
    """Vertex -> exit point: direction times distance (zero where the normal was unusable),
    and never inf or NaN."""
    out = np.empty_like(direction)
    for k in range(len(direction)):
        for axis in range(3):
            x = direction[k, axis] * travelled[k]
            out[k, axis] = x if np.isfinite(x) else np.float32(0.0)
    return out


def _compile() -> None:
    """Compile (or load from numba's cache) the pass's kernels on a tiny mesh: `python -m
    pipeline.interior.vectors`, run by `make install` and the Docker build, so a bake worker never
    compiles them."""
    t0 = time.perf_counter()
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    interior_vectors(corners, corners - 0.25, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    print(f"pipeline.interior.vectors kernels compiled or loaded in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    _compile()
