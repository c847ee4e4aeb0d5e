"""Plain meshes (.obj, .ply, .stl) into a Scene, read by trimesh, with the default material.

trimesh is handed the file's bytes, not its path, so it cannot follow an OBJ's `mtllib` or
texture references out of the asset's folder; OBJ materials are not read (one default
material, as for PLY and STL). Vertex colours (PLY) are taken as sRGB and made linear.
"""
from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np

from core.colour import srgb_to_linear
from core.errors import LimitExceeded, MalformedAsset
from core.scene import Instance, Mesh, Scene, default_material
from pipeline import deadline
from pipeline.limits import Limits
from pipeline.normals import smooth_normals

log = logging.getLogger(__name__)


def load(path: Path, limits: Limits, root: Path | None = None) -> Scene:  # noqa: ARG001 (no references)
    """Read a plain mesh file into a Scene with one default material."""
    import trimesh  # heavy import, only when a plain mesh is read

    kind = path.suffix.lower().lstrip(".")
    data = path.read_bytes()
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=kind, process=False,
                              skip_materials=True)
    except Exception as exc:  # trimesh's parsers fail in many ways on hostile bytes
        raise MalformedAsset(path, f"not a readable {kind.upper()} file ({exc})") from None
    deadline.check()
    if isinstance(loaded, trimesh.Scene):
        parts = []
        for node in loaded.graph.nodes_geometry:
            matrix, name = loaded.graph[node]
            geom = loaded.geometry.get(name)
            if isinstance(geom, trimesh.Trimesh):
                parts.append((str(node), geom, np.asarray(matrix, np.float64)))
    elif isinstance(loaded, trimesh.Trimesh):
        parts = [(path.stem, loaded, np.eye(4))]
    else:
        raise MalformedAsset(path, f"holds no triangle mesh ({type(loaded).__name__})")
    scene = Scene(source=str(path), format=kind, materials=[default_material()])
    for name, geom, matrix in parts:
        deadline.check()
        n, m = len(geom.vertices), len(geom.faces)
        if n > limits.max_vertices or m > limits.max_triangles:
            raise LimitExceeded(path, f"{name}: {n} vertices / {m} triangles, over the limits "
                                      f"({limits.max_vertices} / {limits.max_triangles})")
        faces = np.asarray(geom.faces)
        if m and (faces.min() < 0 or faces.max() >= n):
            raise MalformedAsset(path, f"{name}: face index outside 0..{n - 1}")
        positions = np.asarray(geom.vertices, np.float32)
        indices = faces.astype(np.uint32).reshape(-1, 3)
        normals = _file_normals(geom)
        if normals is None and m:
            # Smooth, area-weighted (STL's unshared vertices come out flat). Ours: trimesh's
            # vertex_normals costs twenty times as much on the bunny.
            normals = smooth_normals(positions, indices)
        scene.meshes.append(Mesh(name=name, positions=positions,
                                 normals=normals, indices=indices,  # type: ignore[arg-type]  # None: pipeline.ingest computes them
                                 uv0=_uv(geom), colors=_colors(geom)))
        scene.instances.append(Instance(len(scene.meshes) - 1, 0, matrix))
    return scene


def _file_normals(geom) -> np.ndarray | None:
    """Vertex normals the file itself stored (trimesh keeps them in its cache), else None."""
    stored = getattr(getattr(geom, "_cache", None), "cache", {}).get("vertex_normals")
    if stored is None or np.shape(stored) != (len(geom.vertices), 3):
        return None
    return np.asarray(stored, np.float32)


def _uv(geom) -> np.ndarray | None:
    uv = getattr(geom.visual, "uv", None)
    if uv is None or len(uv) != len(geom.vertices):
        return None
    uv = np.asarray(uv, np.float32).copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # OBJ/PLY put v=0 at the image bottom; glTF at the top
    return uv


def _colors(geom) -> np.ndarray | None:
    if getattr(geom.visual, "kind", None) != "vertex":
        return None
    rgba8 = np.asarray(geom.visual.vertex_colors).astype(np.uint8, copy=False)  # trimesh: RGBA8
    if rgba8.shape != (len(geom.vertices), 4):
        return None
    c = rgba8.astype(np.float32) / 255.0
    c[:, :3] = srgb_to_linear(rgba8[:, :3])
    return c
