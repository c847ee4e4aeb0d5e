"""What a thumbnail frames: backdrop geometry is found at ingest and left out of the bounds.

A backdrop is a skybox / photo-studio sphere or cylinder around the content (as in the VC
sample): one instance whose world box encloses every other instance with room to spare, and
that is drawn from the inside (its normals face its centre) or is unlit / emissive-only. Framing
it would shrink the content to a dot, so Scene.bounds skips it (the renderer still draws it).
"""
from __future__ import annotations

import numpy as np

from core.scene import Scene, point_box, transformed_bounds

ENCLOSE_MARGIN = 2.0  # the backdrop's box is at least this many times the content's diagonal


def mark_backdrops(scene: Scene) -> list[str]:
    """Set Instance.backdrop on backdrop instances; returns their mesh names (for a warning)."""
    if len(scene.instances) < 2:
        return []
    # Boxes from each mesh's local box corners: cheap for many instances, and never smaller
    # than the exact ones (so "encloses the rest" can only be stricter).
    corners = [_corners(m.positions) for m in scene.meshes]
    boxes = [transformed_bounds(corners[i.mesh], i.matrix) for i in scene.instances]
    order = sorted(range(len(boxes)), key=lambda k: -float(np.prod(np.maximum(
        boxes[k][1] - boxes[k][0], 1e-12))))
    names = []
    for k in order[:4]:  # only the largest few can enclose everything else
        rest = [b for j, b in enumerate(boxes) if j != k and not scene.instances[j].backdrop]
        if not rest:
            break
        lo = np.min([b[0] for b in rest], axis=0)
        hi = np.max([b[1] for b in rest], axis=0)
        blo, bhi = transformed_bounds(scene.meshes[scene.instances[k].mesh].positions,
                                      scene.instances[k].matrix)
        if not (np.all(blo <= lo) and np.all(bhi >= hi)):
            continue
        if float(np.linalg.norm(bhi - blo)) < ENCLOSE_MARGIN * max(float(np.linalg.norm(hi - lo)), 1e-12):
            continue
        inst = scene.instances[k]
        mesh, mat = scene.meshes[inst.mesh], scene.materials[inst.material]
        emissive_only = max(mat.base_color[:3]) == 0 and max(mat.emissive) > 0
        if mat.unlit or emissive_only or _faces_inward(mesh, inst.matrix, (lo + hi) / 2):
            inst.backdrop = True
            names.append(mesh.name)
    if names:
        scene.__dict__.pop("bounds", None)
    return names


def _corners(positions: np.ndarray) -> np.ndarray:
    """The 8 corners of the points' box (none for no points)."""
    if not len(positions):
        return positions
    lo, hi = point_box(positions)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _faces_inward(mesh, matrix: np.ndarray, centre: np.ndarray) -> bool:
    """Do most triangles face the content's centre (a surface seen from inside)?"""
    p = mesh.positions.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
    tri = p[mesh.indices]
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.linalg.det(matrix[:3, :3]) < 0:
        face = -face
    to_centre = centre - tri.mean(axis=1)
    area = np.linalg.norm(face, axis=1)
    inward = np.einsum("ij,ij->i", face, to_centre) > 0
    return bool(area[inward].sum() > 0.75 * area.sum())
