"""Edge anti-aliasing: the frame is shaded once per pixel, and each pixel that a silhouette or
boundary edge crosses is blended with its neighbour across the edge by the share of the pixel
that lies beyond it (geometric post-process anti-aliasing, Persson 2011).

On a CPU rasteriser 4x MSAA costs a third of a thumbnail whatever the shader (llvmpipe's
per-sample coverage, depth and colour work), while the edges that need smoothing are a few
hundred segments. Here they are found per frame from each mesh's welded edges (core.adjacency,
baked with the mesh; each face's plane set up once per upload): an edge between a face turned
toward the camera and one turned away (the silhouette), or a boundary edge. (Creases are left alone: across a crease the neighbour pixel
often shows neither face, as on a slab thinner than a pixel, and blending it adds a seam.)
Each edge is drawn as a strip two pixels wide (shaders/edge.frag) into a two-channel target:
per pixel, the step to the neighbour across the edge times the share of the pixel that lies
beyond the edge (0 off the edges); the final pass (shaders/final.frag, EDGE) mixes the two
pixels by it. A pixel is left alone where the edge is behind the depth buffer on both sides
of it, so hidden edges blend nothing.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import moderngl
import numpy as np

from core.adjacency import MAX_TRIANGLES as MAX_TRIANGLES  # the frames this serves (else MSAA)
from core.adjacency import welded_edges
from core.baked import BakedMesh
from gl import context


@dataclass
class Adjacency:
    """A mesh's welded edges (core.adjacency) and the facing test of its faces."""
    points: np.ndarray   # N x 3 positions (float64)
    edges: np.ndarray    # E x 2 vertex indices (one vertex per welded point)
    faces: np.ndarray    # E x 2 face indices (second -1: a boundary edge)
    normal: np.ndarray   # F x 3: each face's normal (unnormalised, by winding)
    offset: np.ndarray   # F: normal . a corner (a face is turned toward e where normal . e > offset)


def adjacency(positions: np.ndarray, indices: np.ndarray,
              welded: tuple[np.ndarray, np.ndarray] | None = None) -> Adjacency:
    """`welded`: the mesh's (edges, faces) as baked (BakedMesh.edges, .edge_faces); None:
    computed now (linear in the triangles)."""
    edges, faces = welded if welded is not None else welded_edges(positions, indices)
    points = np.asarray(positions, np.float64).reshape(-1, 3)
    tri = np.asarray(indices, np.int64).reshape(-1, 3)
    p0, p1, p2 = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    return Adjacency(points, edges, faces, normal, np.einsum("ij,ij->i", normal, p0))


def of_mesh(mesh: BakedMesh) -> Adjacency:
    """A baked mesh's adjacency: its baked edges where the bake stored them."""
    welded = None if mesh.edges is None or mesh.edge_faces is None else (mesh.edges, mesh.edge_faces)
    return adjacency(mesh.positions, mesh.indices, welded)


def segments(adj: Adjacency, transforms: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """World endpoints (N x 2 x 3) of the edges to smooth, over every instance seen from `eye`:
    silhouettes (one face turned toward the eye, the other away) and boundary edges of a face
    turned toward it."""
    return ranked_segments(adj, transforms, eye, None)[0]


def ranked_segments(adj: Adjacency, transforms: np.ndarray, eye: np.ndarray,
                    order: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """segments, and per segment its edge's `order` (BakedMesh.edge_order: one value per
    edge, or one for all; None: none)."""
    out, ranks = [], []
    a, b = adj.faces[:, 0], adj.faces[:, 1]
    boundary = b < 0
    eye4 = np.append(np.asarray(eye, np.float64), 1.0)
    for m in np.asarray(transforms, np.float64):
        try:
            local_eye = np.linalg.solve(m, eye4)[:3]  # the facing test in mesh space
        except np.linalg.LinAlgError:  # a flattened instance (scale 0): nothing to smooth
            continue
        toward = adj.normal @ local_eye > adj.offset
        ta, tb = toward[a], toward[np.maximum(b, 0)]
        chosen = np.where(boundary, ta, ta != tb)
        ends = adj.points[adj.edges[chosen]]
        out.append(ends @ m[:3, :3].T + m[:3, 3])
        if order is not None:
            ranks.append(order[chosen] if len(order) == len(chosen) and len(order) != 1
                         else np.full(int(chosen.sum()), order[0] if len(order) else 0, np.int32))
    if not out:
        return np.zeros((0, 2, 3)), None if order is None else np.zeros(0, np.int32)
    return np.concatenate(out), None if order is None else np.concatenate(ranks)


_lines: dict[int, tuple[moderngl.Buffer, moderngl.VertexArray]] = {}


GUARD = 1.5  # edges are clipped to this many half-frames about the centre (a guard band)


def _clip(hom: np.ndarray) -> np.ndarray:
    """Edges in clip coordinates (N x 2 x 4) cut to the view volume widened by GUARD on x and
    y (Liang-Barsky, all edges at once), so that every end has a finite, modest NDC position;
    edges wholly outside are dropped."""
    a, d = hom[:, 0], hom[:, 1] - hom[:, 0]
    t0, t1 = np.zeros(len(hom)), np.ones(len(hom))
    for axis, k in ((0, GUARD), (1, GUARD), (2, 1.0)):
        for sign in (1.0, -1.0):  # inside where k w - sign * coordinate >= 0
            da = k * a[:, 3] - sign * a[:, axis]
            dd = k * d[:, 3] - sign * d[:, axis]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -da / dd
            t0 = np.where(dd > 0, np.maximum(t0, t), t0)
            t1 = np.where(dd < 0, np.minimum(t1, t), t1)
            t1 = np.where((dd == 0) & (da < 0), -1.0, t1)  # parallel and outside
    keep = t0 < t1
    a, b, d, t0, t1 = a[keep], hom[keep, 1], d[keep], t0[keep, None], t1[keep, None]
    out = np.stack([np.where(t0 > 0, a + t0 * d, a), np.where(t1 < 1, a + t1 * d, b)], axis=1)
    return out[(out[..., 3] > 0).all(axis=1)]


def _strips(ndc: np.ndarray, w: int, h: int) -> np.ndarray:
    """Two triangles per edge (N x 2 x 3 NDC ends) covering every pixel whose centre lies within
    a pixel of it across its minor axis (the pixels it can cover part of), each vertex with
    both ends in window pixels: 6N x 7 float32."""
    pixels = (ndc[..., :2] * 0.5 + 0.5) * (w, h)
    d = np.abs(pixels[:, 1] - pixels[:, 0])
    off = np.zeros((len(ndc), 3))  # 1 pixel across the minor axis, in NDC
    horizontal = d[:, 0] >= d[:, 1]
    off[horizontal, 1] = 2.0 / h
    off[~horizontal, 0] = 2.0 / w
    a, b = ndc[:, 0], ndc[:, 1]
    out = np.empty((len(ndc), 6, 7), np.float32)
    out[:, :, :3] = np.stack([a - off, a + off, b + off, a - off, b + off, b - off], axis=1)
    out[:, :, 3:] = pixels.reshape(-1, 1, 4)
    return out.reshape(-1, 7)


def draw(ctx: moderngl.Context, fbo: moderngl.Framebuffer, depth: moderngl.Texture,
         world: np.ndarray, view_proj: np.ndarray, w: int, h: int) -> None:
    """Clear `fbo` (the edge target) and draw the edges `world` (N x 2 x 3) into it, tested
    against the frame's `depth` texture."""
    fbo.use()
    ctx.viewport = (0, 0, w, h)
    fbo.clear(0.0, 0.0, 0.0, 0.0)
    if not len(world):
        return
    vp = np.asarray(view_proj, np.float64)
    hom = _clip(world @ vp[:, :3].T + vp[:, 3])
    if not len(hom):
        return
    ndc = hom[..., :3] / hom[..., 3:4]
    verts = _strips(ndc, w, h)
    data = np.ascontiguousarray(verts).tobytes()
    prog = context.program("edge.vert", "edge.frag", {})
    buf, vao = _lines.get(id(ctx), (None, None))
    if buf is None or vao is None or buf.size < len(data):
        if buf is not None and vao is not None:
            vao.release()
            buf.release()
        _lines.clear()
        buf = ctx.buffer(reserve=max(len(data) * 2, 1 << 16))
        vao = ctx.vertex_array(prog, [(buf, "3f 4f", "in_ndc", "in_line")])
        _lines[id(ctx)] = (buf, vao)
    buf.write(data)
    members = cast(dict, prog)
    members["u_depth"].value = 0
    members["u_size"].value = (w, h)
    depth.use(0)
    vao.render(moderngl.TRIANGLES, vertices=len(verts))
