"""UsdGeom BasisCurves and Points as triangle meshes, in the prim's own space.

Curves: each curve is evaluated by its `type` / `basis` / `wrap` (linear; cubic bezier,
bspline, catmullRom; nonperiodic, periodic, pinned) into a polyline, SAMPLES points per
cubic segment; a linear segment is its own two ends, so that its rings are square to it and the
width holds along it (as Storm draws it; rings square to the vertex's mean tangent made a sharp
zigzag a third thinner), the two rings at a corner bridged. Then swept into an open tube of SIDES sides whose
diameter is the authored width there (rotation-minimising frames, a periodic curve's twist
spread along it so that the tube closes). Points: a low-poly sphere (an icosphere once
subdivided) of the point's width per point. Widths absent: Storm's fallback, DEFAULT_WIDTH.

Primvars are evaluated as USD defines their interpolation on curves: constant; uniform per
curve; vertex through the curve's basis (the same weights as the positions); varying linearly
between the segment's ends (one value per segment end). Each output vertex carries up to eight
(control vertex, weight) pairs and its varying pair, so every primvar costs one weighted sum.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.usd.shapes import icosphere

SAMPLES = 8  # polyline points per cubic segment
SIDES = 8  # tube sides
DEFAULT_WIDTH = 1.0  # Storm's width for curves and points that author none
_SPHERE = icosphere(1)  # 42 vertices, 80 triangles per point

# weights of the 4 control vertices at t: [t^3, t^2, t, 1] @ M (USD's basis matrices)
BASES = {
    "bezier": np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]], float),
    "bspline": np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]], float) / 6,
    "catmullRom": np.array([[-1, 3, -3, 1], [2, -5, 4, -1], [-1, 0, 1, 0], [0, 2, 0, 0]], float) / 2,
}


@dataclass
class Samples:
    """Where each output vertex's values come from (E output vertices)."""
    idx: np.ndarray       # E x 8 control vertex indices (into the prim's points)
    w: np.ndarray         # E x 8 their weights
    vary: np.ndarray      # E x 2 varying element indices
    vary_w: np.ndarray    # E x 2 their weights
    curve: np.ndarray     # E, curve (uniform element) of each vertex


class CurveError(ValueError):
    """The curve topology does not fit its basis and wrap (a message for the warning)."""


def segment_count(n: int, kind: str, basis: str, wrap: str) -> int:
    """Segments of one curve of `n` control vertices; CurveError when `n` does not fit."""
    if kind == "linear":
        if n < 2:
            raise CurveError(f"a linear curve of {n} vertex")
        return n if wrap == "periodic" else n - 1
    if basis == "bezier":
        if wrap == "periodic":
            if n < 3 or n % 3:
                raise CurveError(f"a periodic bezier curve of {n} vertices (a multiple of 3)")
            return n // 3
        if n < 4 or (n - 4) % 3:
            raise CurveError(f"a bezier curve of {n} vertices (4 + 3k)")
        return (n - 4) // 3 + 1
    if wrap == "periodic":
        if n < 3:
            raise CurveError(f"a periodic {basis} curve of {n} vertices")
        return n
    if wrap == "pinned":
        if n < 2:
            raise CurveError(f"a pinned {basis} curve of {n} vertices")
        return n - 1
    if n < 4:
        raise CurveError(f"a {basis} curve of {n} vertices (4 or more)")
    return n - 3


def varying_count(n: int, kind: str, basis: str, wrap: str) -> int:
    s = segment_count(n, kind, basis, wrap)
    return s if wrap == "periodic" else s + 1


def _template(n: int, kind: str, basis: str, wrap: str):
    """One curve of `n` vertices: per polyline point its 8 (vertex, weight) pairs and varying
    pair, local to the curve; and its varying element count."""
    segs = segment_count(n, kind, basis, wrap)
    periodic = wrap == "periodic"
    nv = segs if periodic else segs + 1
    if kind == "linear":  # each segment's own two ends: rings square to the segment
        seg = np.repeat(np.arange(segs), 2)
        u = np.tile([0.0, 1.0], segs)
    else:
        t = np.arange(segs * SAMPLES) / SAMPLES
        if not periodic:
            t = np.append(t, segs)
        seg = np.minimum(t.astype(np.int64), segs - 1)
        u = t - seg  # 0..1 within its segment (the last point: 1)
    if kind == "linear":
        a, b = seg, (seg + 1) % n
        i8 = np.stack([a, b] + [a] * 6, axis=1)
        w8 = np.stack([1 - u, u] + [np.zeros_like(u)] * 6, axis=1)
    else:
        # extended control vertices: (index, coefficient) pairs; pinned adds a phantom vertex
        # at each end, 2 P0 - P1 (and 2 Pn-1 - Pn-2)
        ia, ca = np.arange(n), np.ones(n)
        ib, cb = np.arange(n), np.zeros(n)
        if wrap == "pinned":
            ia = np.concatenate([[0], ia, [n - 1]])
            ib = np.concatenate([[1], ib, [n - 2]])
            ca = np.concatenate([[2.0], ca, [2.0]])
            cb = np.concatenate([[-1.0], cb, [-1.0]])
        step = 3 if basis == "bezier" else 1
        cv = (seg[:, None] * step + np.arange(4)[None]) % len(ia)  # E x 4 extended
        power = np.stack([u ** 3, u ** 2, u, np.ones_like(u)], axis=1)
        bw = power @ BASES[basis]  # E x 4
        i8 = np.concatenate([ia[cv], ib[cv]], axis=1)
        w8 = np.concatenate([bw * ca[cv], bw * cb[cv]], axis=1)
    return i8, w8, np.stack([seg, (seg + 1) % nv], axis=1), np.stack([1 - u, u], axis=1), nv


def sample_curves(counts: np.ndarray, kind: str, basis: str, wrap: str,
                  keep: np.ndarray | None = None) -> tuple[Samples, list[int], list[bool]]:
    """Per output polyline point, where its values come from; and each curve's polyline length
    and whether it closes. `counts` are curveVertexCounts (CurveError where one does not fit);
    `keep` (per curve) leaves curves out, their elements still counted. Curves of one count
    share their template (hair: one)."""
    kind = "linear" if kind == "linear" or basis not in BASES else kind
    if kind == "cubic" and basis == "bezier" and wrap == "pinned":
        wrap = "nonperiodic"  # pinned means nothing for bezier (USD)
    counts = np.asarray(counts, np.int64)
    sizes, which = np.unique(counts, return_inverse=True)
    templates = [_template(int(n), kind, basis, wrap) for n in sizes]
    nv = np.array([t[4] for t in templates], np.int64)[which]
    length = np.array([len(t[0]) for t in templates], np.int64)[which]
    start, vstart = np.cumsum(counts) - counts, np.cumsum(nv) - nv
    kept = np.arange(len(counts)) if keep is None else np.flatnonzero(keep)
    out_start = np.cumsum(length[kept]) - length[kept]
    total = int(length[kept].sum())
    idx, w = np.zeros((total, 8), np.int64), np.zeros((total, 8))
    vary, vary_w = np.zeros((total, 2), np.int64), np.zeros((total, 2))
    curve = np.zeros(total, np.int64)
    for k, (i8, w8, vl, vw, _) in enumerate(templates):
        members = np.flatnonzero(which[kept] == k)  # positions among the kept curves
        if not len(members):
            continue
        c = kept[members]
        at = out_start[members][:, None] + np.arange(len(i8))[None]  # B x L
        idx[at] = start[c][:, None, None] + i8[None]
        w[at] = w8[None]
        vary[at] = vstart[c][:, None, None] + vl[None]
        vary_w[at] = vw[None]
        curve[at] = c[:, None]
    return Samples(idx, w, vary, vary_w, curve), [int(x) for x in length[kept]], \
        [wrap == "periodic"] * len(kept)


def evaluate(values: np.ndarray, interpolation: str, s: Samples) -> np.ndarray:
    """A primvar (elements x k, indices already resolved) at every output point."""
    if interpolation == "constant":
        return np.repeat(values[:1], len(s.curve), axis=0)
    if interpolation == "uniform":
        return values[s.curve]
    if interpolation == "varying":
        return np.einsum("ej,ejk->ek", s.vary_w, values[s.vary])
    return np.einsum("ej,ejk->ek", s.w, values[s.idx])


def tubes(centres: np.ndarray, radii: np.ndarray, lengths: list[int], closed: list[bool]):
    """(positions, normals, triangles, source point of each vertex) of a tube per polyline;
    vertex S x k + j is side j of polyline point k. Curves of one length and wrap are swept
    together (hair: thousands at once)."""
    total = int(sum(lengths))
    pos = np.zeros((total * SIDES, 3))
    nrm = np.zeros((total * SIDES, 3))
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64) if lengths else \
        np.zeros(0, np.int64)
    ang = np.arange(SIDES) * (2 * np.pi / SIDES)
    cos, sin = np.cos(ang), np.sin(ang)
    tris = []
    groups: dict[tuple[int, bool], list[int]] = {}
    for c, key in enumerate(zip(lengths, closed)):
        groups.setdefault(key, []).append(c)
    for (m, periodic), members in groups.items():
        at = starts[members][:, None] + np.arange(m)[None]  # B x m polyline points
        p = centres[at].astype(np.float64)
        if periodic:
            tangent = np.roll(p, -1, axis=1) - np.roll(p, 1, axis=1)
        else:
            tangent = np.gradient(p, axis=1) if m > 1 else np.tile([1.0, 0, 0], (len(p), 1, 1))
        tangent /= np.maximum(np.linalg.norm(tangent, axis=2, keepdims=True), 1e-30)
        normal = np.zeros_like(p)
        t0 = tangent[:, 0]
        seed = np.eye(3)[np.argmin(np.abs(t0), axis=1)]
        n0 = np.cross(t0, seed)
        normal[:, 0] = n0 / np.maximum(np.linalg.norm(n0, axis=1, keepdims=True), 1e-30)
        for k in range(1, m):  # parallel transport: the previous normal, made normal to t_k
            prev, t = normal[:, k - 1], tangent[:, k]
            v = prev - t * np.einsum("bk,bk->b", prev, t)[:, None]
            nv = np.linalg.norm(v, axis=1, keepdims=True)
            normal[:, k] = np.where(nv > 1e-12, v / np.maximum(nv, 1e-30), prev)
        binormal = np.cross(tangent, normal)
        if periodic and m > 2:  # spread the twist that transport leaves around the loop
            end = normal[:, -1] - t0 * np.einsum("bk,bk->b", normal[:, -1], t0)[:, None]
            angle = np.arctan2(np.einsum("bk,bk->b", end, binormal[:, 0]),
                               np.einsum("bk,bk->b", end, normal[:, 0]))
            twist = angle[:, None] * np.arange(m)[None] / m
            c, s = np.cos(twist)[..., None], np.sin(twist)[..., None]
            normal, binormal = c * normal - s * binormal, s * normal + c * binormal
        ring = cos[None, None, :, None] * normal[:, :, None] + sin[None, None, :, None] * binormal[:, :, None]
        where = (at[..., None] * SIDES + np.arange(SIDES)).reshape(-1)
        pos[where] = (p[:, :, None] + ring * radii[at][..., None, None]).reshape(-1, 3)
        nrm[where] = ring.reshape(-1, 3)
        rows = m if periodic else m - 1
        i = np.arange(rows)[:, None] * SIDES
        j = np.arange(SIDES)[None]
        a, b = i + j, i + (j + 1) % SIDES
        c2, d = (i + SIDES) % (m * SIDES) + j, (i + SIDES) % (m * SIDES) + (j + 1) % SIDES
        local = np.stack([a, b, d, a, d, c2], axis=-1).reshape(-1, 3)
        tris.append((starts[members][:, None, None] * SIDES + local[None]).reshape(-1, 3))
    tri = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
    return pos, nrm, tri, np.repeat(np.arange(total), SIDES)


def spheres(centres: np.ndarray, radii: np.ndarray):
    """(positions, normals, triangles, source point of each vertex): a sphere per point."""
    unit, faces = _SPHERE
    n, k = len(centres), len(unit)
    pos = centres[:, None] + unit[None] * radii[:, None, None]
    tri = (np.arange(n)[:, None, None] * k + faces[None]).reshape(-1, 3)
    return (pos.reshape(-1, 3), np.broadcast_to(unit[None], (n, k, 3)).reshape(-1, 3), tri,
            np.repeat(np.arange(n), k))


def sphere_size(n: int) -> tuple[int, int]:
    return n * len(_SPHERE[0]), n * len(_SPHERE[1])
