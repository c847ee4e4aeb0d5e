"""Static batching: many small meshes placed once with one material become one BakedMesh.

A studio stage of thousands of small prims (a block world, a kit's bolts and panels) bakes to
thousands of BakedMeshes of one placement each, and every later step pays per mesh: the cache's
arrays, the GPU buffers and draw calls, the edges, the framing. `batch` concatenates those that
can be drawn as one, with their vertices moved into world space as pbr.vert would move them
(position by the model matrix, normal by the normal matrix, tangent by the model's linear part),
so the frame is the one the separate draws make: the same triangles, the same welded edges
(welded per part, never across parts), the same support points (each part's, placed) and the
same baked occlusion. What is left alone: meshes placed more than once (drawn instanced
already), mirrored placements (the raster flips their winding per draw), blended and
transmissive materials (drawn sorted per mesh, or with interior vectors), glTF material
variants, backdrops (left out of the framing per instance) and parts over MAX_PART_VERTICES
(few, and each a draw worth its call).
"""
from __future__ import annotations

import numpy as np

from core.baked import BakedMesh, dequantise_directions, quantise_directions
from core.hull import support_points

MAX_PART_VERTICES = 1 << 14
_OPTIONAL = ("tangents", "uv0", "uv1", "colors", "ao", "bent")


def batchable(mesh: BakedMesh, backdrop: bool) -> bool:
    if backdrop or mesh.variants or mesh.interior is not None or len(mesh.transforms) != 1:
        return False
    if mesh.material.alpha_mode == "BLEND" or mesh.material.material_class == "transmissive":
        return False
    if len(mesh.positions) > MAX_PART_VERTICES or mesh.ao_per_placement:
        return False
    if mesh.ao is not None and len(mesh.ao) != len(mesh.positions):
        return False
    return bool(np.linalg.det(np.asarray(mesh.transforms[0], np.float64)[:3, :3]) > 0)


def batch(meshes: list[BakedMesh], backdrop: list[bool],
          with_edges: bool = True) -> tuple[list[BakedMesh], list[list[int]]]:
    """(the meshes with each batchable group concatenated at its first part's place, per
    output mesh the input meshes it holds). A group: one material (the same object) and the
    same optional arrays present; a group of one is left as it is."""
    groups: dict[tuple, list[int]] = {}
    for i, m in enumerate(meshes):
        if batchable(m, backdrop[i]):
            key = (id(m.material), tuple(getattr(m, n) is not None for n in _OPTIONAL))
            groups.setdefault(key, []).append(i)
    first = {g[0]: g for g in groups.values() if len(g) > 1}
    taken = {i for g in first.values() for i in g}
    out, members = [], []
    for i, m in enumerate(meshes):
        if i in first:
            merged = merge([meshes[k] for k in first[i]], with_edges)
            if merged.edge_order is not None:  # part number -> that part's place
                merged.edge_order = np.asarray(first[i], np.int32)[merged.edge_order]
            out.append(merged)
            members.append(first[i])
        elif i not in taken:
            if first and with_edges:
                m.edge_order = np.array([i], np.int32)
            out.append(m)
            members.append([i])
    return out, members


def merge(parts: list[BakedMesh], with_edges: bool = True) -> BakedMesh:
    """The parts (each placed once, not mirrored) as one mesh in world space, with their welded
    edges (`with_edges`: the bake stores them) and support points: those each part would
    have, renumbered and placed."""
    counts = np.array([len(p.positions) for p in parts])
    offsets = np.r_[0, np.cumsum(counts)[:-1]]
    part_of = np.repeat(np.arange(len(parts)), counts)
    model = np.stack([np.asarray(p.transforms[0], np.float64) for p in parts])  # P x 4 x 4
    linear = model[:, :3, :3]
    with np.errstate(all="ignore"):  # a singular part: its normals vanish, as the shader's pinv
        normal = np.nan_to_num(np.linalg.pinv(linear).transpose(0, 2, 1))
    obj = np.concatenate([np.asarray(p.positions, np.float32) for p in parts])
    # As pbr.vert: world = model * (p, 1) and normal = normal matrix * n, here in float64
    # (the shader's float32 products differ from these by rounding only).
    world = np.einsum("vij,vj->vi", linear[part_of], obj.astype(np.float64)) + model[part_of, :3, 3]
    normals = np.einsum("vij,vj->vi", normal[part_of],
                        np.concatenate([np.asarray(p.normals, np.float64) for p in parts]))
    indices = np.concatenate([np.asarray(p.indices, np.uint32).reshape(-1, 3) + np.uint32(o)
                              for p, o in zip(parts, offsets)])
    extra: dict[str, np.ndarray | None] = {}
    for name in _OPTIONAL:
        values = [getattr(p, name) for p in parts]
        if values[0] is None:
            extra[name] = None
            continue
        arr = np.concatenate(values)
        if name == "tangents":  # mat3(model) * xyz; w kept (no part mirrors)
            xyz = np.einsum("vij,vj->vi", linear[part_of], arr[:, :3].astype(np.float64))
            arr = np.concatenate([xyz, arr[:, 3:4]], axis=1).astype(np.float32)
        elif name == "bent":  # object-space directions turned as the normals are
            d = dequantise_directions(arr).reshape(-1, 2, 3).astype(np.float64)
            d = np.einsum("vij,vsj->vsi", normal[part_of], d)
            d /= np.maximum(np.linalg.norm(d, axis=2, keepdims=True), 1e-30)
            arr = quantise_directions(d.reshape(-1, 6))
        extra[name] = arr
    edges, edge_faces = welded_edges_parts(obj, indices, part_of) if with_edges else (None, None)
    edge_part = None if edges is None else part_of[edges[:, 0]].astype(np.int32)
    support = []
    for p, m in zip(parts, model):
        s = support_points(p.positions) if p.support is None else np.asarray(p.support, np.float64)
        support.append(s @ m[:3, :3].T + m[:3, 3])
    name = f"{parts[0].name} (+{len(parts) - 1} batched)"
    return BakedMesh(name=name, positions=world.astype(np.float32), normals=normals.astype(np.float32),
                     indices=indices, material=parts[0].material,
                     transforms=np.eye(4, dtype=np.float64)[None], edges=edges, edge_faces=edge_faces,
                     support=np.concatenate(support), edge_order=edge_part, tangents=extra["tangents"],
                     uv0=extra["uv0"], uv1=extra["uv1"], colors=extra["colors"], ao=extra["ao"],
                     bent=extra["bent"])


def welded_edges_parts(positions: np.ndarray, indices: np.ndarray,
                       part_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """core.adjacency.welded_edges of each part (its object-space positions, vertices and
    faces numbered within the whole), concatenated in part order: in one sort, the part's
    number leading each position's bytes so that no two parts weld."""
    raw = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    # big-endian part number first: the bytes sort by part, then as welded_edges sorts them
    keyed = np.empty(len(raw), dtype=[("part", ">u4"), ("xyz", np.float32, 3)])
    keyed["part"], keyed["xyz"] = part_of, raw
    keys = keyed.view(np.dtype((np.void, 16))).reshape(-1)
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    tri = inverse.reshape(-1)[np.asarray(indices, np.int64).reshape(-1, 3)]
    # faces in the order welded_edges visits them per part: corner pair 01 of the part's faces,
    # then 12, then 20; the parts one after another
    face = np.arange(len(tri))
    pair = np.repeat([0, 1, 2], len(tri))
    faces3 = np.tile(face, 3)
    ends = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    lo, hi = ends.min(axis=1), ends.max(axis=1)
    key = lo * len(first) + hi
    # points are numbered part by part, so sorting by (key, pair, face) is welded_edges' stable
    # sort within each part
    order = np.lexsort((faces3, pair, key))
    key, face_sorted = key[order], faces3[order]
    start = np.flatnonzero(np.r_[len(key) > 0, key[1:] != key[:-1]])
    count = np.diff(np.r_[start, len(key)])
    faces = np.stack([face_sorted[start],
                      np.where(count >= 2, face_sorted[np.minimum(start + 1, len(face_sorted) - 1)], -1)], 1)
    edges = np.stack([lo[order][start], hi[order][start]], 1)
    keep = edges[:, 0] != edges[:, 1]
    return first[edges[keep]].astype(np.uint32), faces[keep].astype(np.int32)
