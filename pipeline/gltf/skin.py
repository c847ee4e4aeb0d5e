"""Posing glTF geometry at ingest: morph targets at their default weights, then skins from the
nodes' rest transforms, so a thumbnail shows the mesh as other viewers show it before any
animation plays. Plain numpy over whole arrays.
"""
from __future__ import annotations

import numpy as np


def morph(base: np.ndarray, deltas: list[np.ndarray | None], weights) -> np.ndarray:
    """base + sum_k weights[k] * deltas[k] (glTF morph targets), float32."""
    out = base.astype(np.float32, copy=True)
    for w, d in zip(weights, deltas):
        if d is not None and w != 0.0:
            out[:, :d.shape[1]] += np.float32(w) * d[:, :out.shape[1]]
    return out


def blend_matrices(joint_matrices: np.ndarray, joints: list[np.ndarray],
                   weights: list[np.ndarray]) -> np.ndarray:
    """Per vertex, the weighted sum of its joints' 4x4 matrices (linear blend skinning).

    `joints` / `weights` hold the JOINTS_n / WEIGHTS_n sets (each N x 4). Weights are
    normalised to sum to 1 (exporters often leave them slightly off); a vertex with no weight
    keeps the identity."""
    w = np.concatenate(weights, axis=1).astype(np.float64)
    j = np.concatenate(joints, axis=1).astype(np.int64)
    total = w.sum(axis=1, keepdims=True)
    unweighted = total[:, 0] <= 0
    w = np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.0)
    out = np.einsum("vk,vkij->vij", w, joint_matrices[j])
    out[unweighted] = np.eye(4)
    return out


CHUNK = 1 << 16  # vertices per step: bounds the per-vertex matrices to a few tens of MB


def skin(joint_matrices: np.ndarray, joints: list[np.ndarray], weights: list[np.ndarray],
         positions: np.ndarray, normals: np.ndarray | None, tangents: np.ndarray | None):
    """Positions, normals and tangents posed by linear blend skinning, a chunk of vertices at
    a time (per-vertex 4x4 matrices for a whole large mesh would cost gigabytes)."""
    n = len(positions)
    p = np.empty((n, 3), np.float32)
    nrm = None if normals is None else np.empty((n, 3), np.float32)
    tan = None if tangents is None else np.empty((n, 4), np.float32)
    for a in range(0, n, CHUNK):
        b = min(a + CHUNK, n)
        blend = blend_matrices(joint_matrices, [j[a:b] for j in joints], [w[a:b] for w in weights])
        p[a:b], n_, t_ = apply_skin(blend, positions[a:b],
                                    None if normals is None else normals[a:b],
                                    None if tangents is None else tangents[a:b])
        if nrm is not None:
            nrm[a:b] = n_
        if tan is not None:
            tan[a:b] = t_
    return p, nrm, tan


def apply_skin(blend: np.ndarray, positions: np.ndarray, normals: np.ndarray | None,
               tangents: np.ndarray | None):
    """Positions, normals and tangents moved by per-vertex matrices `blend` (N x 4 x 4)."""
    lin = blend[:, :3, :3]
    p = np.einsum("vij,vj->vi", lin, positions.astype(np.float64)) + blend[:, :3, 3]
    n = t = None
    if normals is not None:
        # The inverse transpose keeps normals perpendicular under non-uniform joint scale; the
        # cofactor matrix is it times det(M), so its columns (cross products of M's columns)
        # give the same direction without a per-vertex inverse, det's sign keeping the side.
        c0, c1, c2 = lin[:, :, 0], lin[:, :, 1], lin[:, :, 2]
        x01, x12, x20 = np.cross(c0, c1), np.cross(c1, c2), np.cross(c2, c0)
        nf = normals.astype(np.float64)
        cof_n = nf[:, :1] * x12 + nf[:, 1:2] * x20 + nf[:, 2:3] * x01
        sign = np.where(np.einsum("vi,vi->v", c0, x12) < 0, -1.0, 1.0)[:, None]
        # a joint scaled to zero (a common way to hide a part) leaves no cofactor: the normal
        # is then moved by M itself, or kept where M is zero too (the vertex is collapsed)
        lost = ~(np.abs(cof_n).sum(axis=1) > 0)
        cof_n[lost] = np.einsum("vij,vj->vi", lin[lost], nf[lost])
        lost = ~(np.abs(cof_n).sum(axis=1) > 0)
        cof_n[lost] = nf[lost]
        n = _unit(cof_n * sign)
    if tangents is not None:
        t = tangents.astype(np.float32, copy=True)
        t[:, :3] = _unit(np.einsum("vij,vj->vi", lin, tangents[:, :3].astype(np.float64)))
    return p.astype(np.float32), n, t


def _unit(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return (v / np.where(length > 0, length, 1.0)).astype(np.float32)
