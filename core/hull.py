"""Points on an asset's convex hull, baked (pipeline.bake) so that a first frame does not take
them from every vertex; computed at render time for assets made in memory:
- `hull_points`: points whose convex hull holds every drawn surface, the final pass's bound on
  the pixels the object can reach (renderer.view.regions): every vertex of the hull, and the
  few other points that the cheap test below cannot rule out (no qhull: scipy.spatial's import
  was most of a cold bake of any mesh past DIRECT_POINTS vertices);
- `support_points`: a mesh's points farthest along a few hundred directions, what the default
  camera frames (renderer.view.framing); over every vertex they would slow a large mesh's first frame.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import combinations

import numpy as np

from core.baked import BakedMesh
from core.scene import point_box

DIRECT_POINTS = 4096        # fewer points are bounded as they are: qhull would save <0.3 ms a
                            # frame (the points are projected per frame)
MAX_HULL_MESH = 50_000      # vertices: a bigger mesh is bounded by its box's corners instead
                            # (qhull's time and the hull's size grow with it)
MAX_HULL_POINTS = 200_000   # all instances' points: past this, every instance by its box
OUTER_MAX_POINTS = 100_000  # points `_outer` takes in one hull_points (about 1 us each) before
                            # qhull, whose scipy import costs what ~300k of them do, is cheaper


def hull_points(meshes: Sequence[BakedMesh], qhull: bool = False) -> np.ndarray | None:
    """World-space points whose convex hull holds every instance of every mesh (backdrops
    included: the bound holds every drawn surface): the points not inside it (`_outer`), or
    all of them when they are few. None when there is no hull to take (no vertices, degenerate,
    or too many vertices to be worth it). `_outer` takes the first OUTER_MAX_POINTS points to
    hull, qhull the rest, and all of them with `qhull` (a pose a frame, pipeline.gltf.rig:
    scipy's import is paid once there, qhull's speed every frame)."""
    budget = 0 if qhull else OUTER_MAX_POINTS

    def take(points: np.ndarray) -> np.ndarray:
        nonlocal budget
        if len(points) <= budget:
            budget -= len(points)
            return _outer(points)
        return _hull(points)

    locals_ = []
    for m in meshes:
        if len(m.positions) == 0:
            continue
        p = np.asarray(m.positions, np.float64)
        local = p if len(p) <= DIRECT_POINTS else take(p) if len(p) <= MAX_HULL_MESH else _box(p)
        locals_.append((local, np.asarray(m.transforms, np.float64)))
    if sum(len(h) * len(t) for h, t in locals_) > MAX_HULL_POINTS:
        locals_ = [(_box(h), t) for h, t in locals_]
    parts = [h @ t[:3, :3].T + t[:3, 3] for h, ts in locals_ for t in ts]
    if not parts or sum(len(x) for x in parts) > MAX_HULL_POINTS:
        return None
    pts = np.concatenate(parts)
    return pts if len(pts) <= DIRECT_POINTS else take(pts)


def _box(points: np.ndarray) -> np.ndarray:
    """The eight corners of the points' bounding box (a looser hull, as cheap as can be)."""
    lo, hi = point_box(points)
    return np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])


OUTER_DIRECTIONS = 24  # extremes spanning the inner polytope (C(24, 3) planes tried)


def _outer(points: np.ndarray) -> np.ndarray:
    """The points not strictly inside the polytope P spanned by their extremes along
    OUTER_DIRECTIONS directions (Akl and Toussaint's filter). P lies inside the points' hull,
    so no hull vertex is strictly inside it: the points kept have the same hull as all of
    them. P's facets are every plane through three of its vertices with all of them on one
    side (brute force over few points); a flat P keeps every point (qhull's coplanar case)."""
    ext = support_points(points, OUTER_DIRECTIONS)
    lo, hi = point_box(points)
    eps = 1e-9 * max(float(np.linalg.norm(hi - lo)), 1e-300) + 1e-12 * float(np.abs(points).max())
    if len(ext) < 4 or np.linalg.svd(ext - ext.mean(axis=0), compute_uv=False)[-1] <= eps:
        return points
    i, j, k = np.array(list(combinations(range(len(ext)), 3))).T
    normal = np.cross(ext[j] - ext[i], ext[k] - ext[i])
    length = np.linalg.norm(normal, axis=1)
    ok = length > 1e-12 * length.max()  # not three points in a line
    normal = normal[ok] / length[ok, None]
    offset = np.einsum("ij,ij->i", normal, ext[i[ok]])
    side = ext @ normal.T - offset  # each extreme point against each plane
    below, above = (side <= eps).all(axis=0), (side >= -eps).all(axis=0)
    planes = np.concatenate([np.c_[normal[below], offset[below]], -np.c_[normal[above], offset[above]]])
    # the planes of one facet, met through each of its triangles, once (no np.unique: numpy.ma)
    planes = planes[sorted({tuple(np.round(q / eps).astype(np.int64)): n for n, q in enumerate(planes)}.values())]
    keep = np.ones(len(points), bool)
    for start in range(0, len(points), SUPPORT_BLOCK):
        block = points[start:start + SUPPORT_BLOCK]
        keep[start:start + len(block)] = ((block @ planes[:, :3].T - planes[:, 3]) >= -eps).any(axis=1)
    return points[keep]


def _hull(points: np.ndarray) -> np.ndarray:
    """The points on the convex hull (all of them when qhull finds none: flat or tiny)."""
    from scipy.spatial import ConvexHull, QhullError  # heavy: only bakes take hulls, not renders from the cache
    if len(points) <= 8:
        return points
    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):  # coplanar or degenerate: every point is kept
        return points


SUPPORT_BLOCK = 16384  # points a block: 16384 x 256 doubles is 32 MiB


def support_points(points: np.ndarray, directions: int = 256) -> np.ndarray:
    """The points farthest along `directions` evenly spread unit vectors (a Fibonacci
    sphere): a few hundred points whose projection bounds the object's almost as tightly as
    all of them, at any view."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) <= directions:
        return points
    i = np.arange(directions) + 0.5
    z = 1 - 2 * i / directions
    phi = math.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    # The farthest point per direction, over blocks of points: the whole N x directions product
    # of a million-vertex mesh would be gigabytes, the bake's peak memory.
    # A vertex repeated (split for normals or UVs: four times on a faceVarying quad mesh) is
    # never farther than its first copy, which an argmax picks first: only first copies are
    # searched, in their order, so the result is the one the whole search gives.
    keys = np.ascontiguousarray(points).view(np.dtype((np.void, 24))).reshape(-1)
    _, first = np.unique(keys, return_index=True)
    first.sort()
    candidates = points[first]
    best = np.full(directions, -np.inf)
    where = np.zeros(directions, np.int64)
    rows = np.arange(directions)
    for start in range(0, len(candidates), SUPPORT_BLOCK):
        # directions x points: the argmax runs along contiguous rows (along axis 0 of a
        # points x directions product it is a strided reduction, ~50x slower)
        dots = d @ candidates[start:start + SUPPORT_BLOCK].T
        arg = np.argmax(dots, axis=1)
        top = dots[rows, arg]
        better = top > best  # strictly: the first block's point wins a tie, as one argmax would
        best[better], where[better] = top[better], arg[better] + start
    keep = np.zeros(len(points), bool)  # each extreme point once, in order (np.unique's
    keep[first[where]] = True           # result, without its numpy.ma import)
    return points[keep]


def hull_support_points(points: np.ndarray, directions: int = 256) -> np.ndarray:
    """support_points over the points' convex hull vertices: the same extremes (a point
    farthest along a direction is a hull vertex), or every hull vertex when there are fewer
    than `directions`; for a surface that moves every frame (pipeline.gltf.rig), where qhull
    over N points beats N x directions dot products."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return support_points(_hull(points) if len(points) > directions else points, directions)
