"""`load_scene`: one entry for every format, and one finishing step they all share.

Format readers (pipeline.gltf.reader, pipeline.usd.stage, pipeline.mesh) turn a file into a Scene; `finish`
then holds every format to the same rules: finite positions, indices inside the vertex
count, degenerate triangles dropped (counted in a warning), normals and tangents computed
where missing, empty meshes removed, and an empty scene refused.

Time bound: the whole load runs under `deadline.within(Limits.ingest_seconds)`; readers
check it per node / primitive / prim / texture and `finish` per mesh. A single native call
(json.loads, Usd.Stage.Open, a PLY parse) cannot be interrupted; its input size is bounded
by Limits.max_file_bytes instead, so its running time is bounded too.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import stat
import time
from pathlib import Path

import numpy as np

from core.animation import Moment
from core.errors import (
    AssetError,
    EmptyScene,
    LimitExceeded,
    MalformedAsset,
    MissingFile,
    NotInAsset,
    UnsupportedFormat,
)
from core.scene import Mesh, Scene
from pipeline import deadline
from pipeline import mesh as plain_mesh
from pipeline.framing import mark_backdrops
from pipeline.limits import Limits
from pipeline.normals import compute_tangents, smooth_normals

log = logging.getLogger(__name__)

READERS = {".gltf": "gltf", ".glb": "gltf",
           ".usd": "usd", ".usda": "usd", ".usdc": "usd", ".usdz": "usd",
           ".obj": "mesh", ".ply": "mesh", ".stl": "mesh"}


def _reader(kind: str):
    """The format's reader module."""
    if kind == "gltf":
        from pipeline.gltf import reader as gltf  # as usd below: each format's reader when it reads
        return gltf
    if kind == "usd":
        from pipeline.usd import stage as usd  # usd-core is heavy: imported by USD reads only
        return usd
    return plain_mesh  # (trimesh is imported by its reads only)


def load_scene(path, limits: Limits | None = None, root=None, moment: Moment | None = None,
               variant_sets: tuple[str, ...] = (), purposes: tuple[str, ...] = ("render",),
               draw_mode: str = "authored") -> Scene:
    """Read any supported asset into a finished Scene; bad input raises an AssetError.
    Files it references must lie inside `root` (default: its folder; `paths.sandbox_root`).
    `moment`: the animation time to pose it at (glTF, USD; core.animation), None at rest.
    `variant_sets`: USD variant selections, "[PRIM:]SET=NAME" (pipeline.usd.stage.load);
    `purposes`: the USD purposes drawn besides default (other formats have none); `draw_mode`:
    USD model:drawMode stand-ins ("authored") or the geometry ("full")."""
    path = Path(path)
    limits = limits or Limits.from_env()
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise MissingFile(path, "no such file") from None
    except OSError as exc:
        raise MissingFile(path, f"cannot be read: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise UnsupportedFormat(path, "not a regular file")
    kind = READERS.get(path.suffix.lower())
    if kind is None:
        raise UnsupportedFormat(path, f"unsupported file type {path.suffix or '(none)'!r}; "
                                      f"reads {', '.join(sorted(READERS))}")
    size = st.st_size
    if size == 0:
        raise MalformedAsset(path, "file is empty")
    if size > limits.max_file_bytes:
        raise LimitExceeded(path, f"file is {size} bytes, over the limit of "
                                  f"{limits.max_file_bytes} (ASSET_PREVIEW_MAX_FILE_BYTES)")
    reader = _reader(kind)
    start = time.perf_counter()
    with deadline.within(limits.ingest_seconds, str(path)):
        try:
            if variant_sets and kind != "usd":
                raise NotInAsset(path, "variant sets are USD's; this asset has none")
            extra: dict = {"variant_sets": tuple(variant_sets)} if variant_sets else {}
            if kind == "usd" and tuple(purposes) != ("render",):
                extra["purposes"] = tuple(purposes)
            if kind == "usd" and draw_mode != "authored":
                extra["draw_mode"] = draw_mode
            if moment is None:
                scene = reader.load(path, limits, root, **extra)
            elif kind == "mesh":
                raise UnsupportedFormat(path, f"{path.suffix} files carry no animation (--time, --animate)")
            else:
                scene = reader.load(path, limits, root, moment=moment, **extra)
            finish(scene, limits)
            deadline.check()
        except AssetError:
            raise
        except MemoryError:
            raise LimitExceeded(path, "ran out of memory while reading") from None
        except RecursionError:
            raise MalformedAsset(path, "structure nested too deeply") from None
        except Exception as exc:  # a parser choking on hostile bytes must not crash the caller
            log.exception("%s: reader failed", path)
            raise MalformedAsset(path, f"could not be read ({type(exc).__name__}: {exc})") from None
    own = os.path.realpath(path)  # references are resolved paths too (a symlinked folder is one file set)
    if own not in scene.files:
        scene.files.insert(0, own)
    if log.isEnabledFor(logging.INFO):
        log.info("%s: %d meshes, %d triangles, %d materials, %d textures in %.1f ms", path,
                 len(scene.meshes), scene.triangle_count, len(scene.materials),
                 len(scene.textures), 1000 * (time.perf_counter() - start))
    return scene


def finish(scene: Scene, limits: Limits) -> Scene:
    """Validate and complete a Scene in place (shared by every format); see the module doc."""
    path = scene.source
    needs_tangents = {inst.mesh: scene.materials[inst.material].normal_texture
                      for inst in scene.instances
                      if 0 <= inst.material < len(scene.materials)
                      and scene.materials[inst.material].normal_texture is not None}
    dropped = 0
    total_vertices = 0
    for i, mesh in enumerate(scene.meshes):
        deadline.check()
        dropped += _check(mesh, path)
        if mesh.normals is None or len(mesh.normals) != len(mesh.positions):
            flat_normals(mesh)
        else:
            mesh.normals = _unit_normals(mesh)
        ref = needs_tangents.get(i)
        uv = None if ref is None else (mesh.uv0 if ref.uv_set == 0 else mesh.uv1)
        if uv is not None and (mesh.tangents is None or len(mesh.tangents) != len(mesh.positions)):
            mesh.tangents = compute_tangents(mesh.positions, mesh.normals, uv, mesh.indices)
        total_vertices += len(mesh.positions)
    if total_vertices > limits.max_vertices:
        raise LimitExceeded(path, f"{total_vertices} vertices, over the limit of "
                                  f"{limits.max_vertices}")
    total_triangles = sum(len(m.indices) for m in scene.meshes)
    if total_triangles > limits.max_triangles:
        raise LimitExceeded(path, f"{total_triangles} triangles, over the limit of "
                                  f"{limits.max_triangles}")
    if dropped:
        scene.warnings.append(f"dropped {dropped} degenerate triangles")
        log.warning("%s: dropped %d degenerate triangles", path, dropped)
    for inst in scene.instances:
        if not 0 <= inst.mesh < len(scene.meshes) or not 0 <= inst.material < len(scene.materials):
            raise MalformedAsset(path, f"instance refers to mesh {inst.mesh} / material "
                                       f"{inst.material}, which do not exist")
        if inst.matrix.shape != (4, 4) or not np.all(np.isfinite(inst.matrix)):
            raise MalformedAsset(path, f"mesh {scene.meshes[inst.mesh].name!r} is placed by a "
                                       "transform that is not a finite 4x4 matrix")
    _drop_empty(scene)
    if not scene.instances:
        raise EmptyScene(path, "no triangles to render" + (
            f" ({'; '.join(scene.warnings[:3])})" if scene.warnings else ""))
    scene.__dict__.pop("bounds", None)  # cached_property: recompute after the changes above
    backdrop = mark_backdrops(scene)  # after the checks: it reads positions and indices
    if backdrop:
        log.info("%s: backdrop geometry left out of the framing: %s", path, ", ".join(backdrop))
    return scene


def _check(mesh: Mesh, path: str) -> int:
    """Type and range checks for one mesh; drops degenerate triangles, returns how many."""
    mesh.positions = np.ascontiguousarray(mesh.positions, np.float32).reshape(-1, 3)
    n = len(mesh.positions)
    # A finite sum (the common case, one cheap test) means every value is finite.
    if not np.isfinite(mesh.positions.sum()):
        bad = int((~np.isfinite(mesh.positions).all(axis=1)).sum())
        if bad:
            raise MalformedAsset(path, f"mesh {mesh.name!r}: {bad} vertex positions are NaN or "
                                       "infinite")
    tri = np.asarray(mesh.indices).reshape(-1, 3)
    if len(tri) and int(tri.max()) >= n:
        raise MalformedAsset(path, f"mesh {mesh.name!r}: index {int(tri.max())} is past the "
                                   f"vertex count {n}")
    if len(tri) and tri.dtype.kind == "i" and int(tri.min()) < 0:
        raise MalformedAsset(path, f"mesh {mesh.name!r}: negative vertex index")
    tri = tri.astype(np.uint32, copy=False)
    for name in ("uv0", "uv1", "colors", "tangents"):
        value = getattr(mesh, name)
        if value is None:
            continue
        if len(value) != n:
            raise MalformedAsset(path, f"mesh {mesh.name!r}: {name} has {len(value)} values "
                                       f"for {n} vertices")
        if not np.isfinite(value.sum()) and not np.isfinite(value).all():
            if name == "tangents":  # recomputed below where a normal map needs them
                mesh.tangents = None
                continue
            raise MalformedAsset(path, f"mesh {mesh.name!r}: {name} hold NaN or infinite values")
        setattr(mesh, name, np.ascontiguousarray(value, np.float32))
    keep = _nonzero_area(mesh.positions, tri)
    mesh.indices = tri if keep.all() else np.ascontiguousarray(tri[keep])
    return int(len(tri) - keep.sum())


def _nonzero_area(positions: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Per triangle: is the cross product of two edges non-zero? An exact test (no epsilon;
    x - y == 0 iff x == y), which a repeated index fails too. Gathering per coordinate with
    `take` is several times faster than gathering rows."""
    x, y, z = (np.ascontiguousarray(c).take(tri) for c in positions.T)
    bx, by, bz = x[:, 1] - x[:, 0], y[:, 1] - y[:, 0], z[:, 1] - z[:, 0]
    cx, cy, cz = x[:, 2] - x[:, 0], y[:, 2] - y[:, 0], z[:, 2] - z[:, 0]
    return (by * cz != bz * cy) | (bz * cx != bx * cz) | (bx * cy != by * cx)


def flat_normals(mesh: Mesh) -> None:
    """Flat normals, as glTF asks for meshes without them: every triangle gets its own vertices."""
    corners = mesh.indices.reshape(-1)
    for name in ("positions", "uv0", "uv1", "colors", "tangents"):
        value = getattr(mesh, name)
        if value is not None:
            setattr(mesh, name, value.take(corners, axis=0))
    # float64: a float32 cross product of a tiny triangle (edges ~1e-12) is non-zero, as the
    # degenerate test found, yet its squared length underflows to 0 and the normal to NaN.
    tri = mesh.positions.reshape(-1, 3, 3).astype(np.float64)
    b, c = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    # np.cross's products, written out: its axis handling costs more than a small mesh's math
    face = np.stack([b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1], b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2],
                     b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]], axis=1)
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    mesh.normals = np.repeat(face, 3, axis=0).astype(np.float32)
    mesh.indices = np.arange(len(corners), dtype=np.uint32).reshape(-1, 3)


def _unit_normals(mesh: Mesh) -> np.ndarray:
    """Given normals made unit length; zero or non-finite ones replaced by area-weighted ones."""
    nrm = np.ascontiguousarray(mesh.normals, np.float32).reshape(-1, 3)
    length2 = np.einsum("ij,ij->i", nrm, nrm)
    if len(nrm) and abs(length2 - 1.0).max() < 1e-4:  # already unit, as glTF requires
        return nrm
    length = np.sqrt(length2)
    bad = ~(np.isfinite(length) & (length > 1e-12))
    out = nrm / np.where(bad, 1.0, length)[:, None]
    if bad.any():
        out[bad] = smooth_normals(mesh.positions, mesh.indices)[bad]
    return np.ascontiguousarray(out, np.float32)


def _drop_empty(scene: Scene) -> None:
    """Remove meshes left without triangles and the instances of them."""
    keep = [i for i, m in enumerate(scene.meshes) if len(m.indices)]
    if len(keep) == len(scene.meshes):
        return
    remap = {old: new for new, old in enumerate(keep)}
    scene.meshes = [scene.meshes[i] for i in keep]
    scene.instances = [dataclasses.replace(inst, mesh=remap[inst.mesh])
                       for inst in scene.instances if inst.mesh in remap]
