"""glTF mesh primitives into `Mesh`es: attributes, indices and modes (strips and fans into
triangle lists; points and lines thickened into octahedra and tubes once the scene's size is
known), Draco-compressed primitives, morph targets and skins. Flat normals and tangents, when
missing, are left to ingest's shared finishing."""
from __future__ import annotations

from typing import cast

import numpy as np

from core.errors import LimitExceeded
from core.scene import Mesh, Scene
from pipeline.gltf.accessors import COMPONENTS, WIDTH, Document, as_values
from pipeline.gltf.decode import draco_primitive
from pipeline.gltf.skin import morph
from pipeline.gltf.skin import skin as skin_vertices
from pipeline.wire import LINE_LOOP, LINE_STRIP, LINES, POINTS, octahedra, segments, tubes

TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN = 4, 5, 6
MODES = (POINTS, LINES, LINE_LOOP, LINE_STRIP, TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN)
WIRE_RADIUS = {POINTS: 0.012, LINES: 0.006}  # x the scene diagonal: a few pixels at 512 px


def primitive(d: Document, mesh_index: int, prim_index: int, prim: dict, weights=(),
              skin: np.ndarray | None = None) -> Mesh | None:
    """One primitive as a Mesh, its morph targets applied at `weights` and, given the
    skin's joint matrices, posed by them (positions then in world space). Points and lines
    come back with `indices` holding their vertex indices (1 or 2 per row), to be turned
    into thin geometry by `thicken` once the scene's size is known."""
    what = f"mesh {mesh_index} primitive {prim_index}"
    mode = prim.get("mode", TRIANGLES)
    if mode not in MODES:
        raise d.bad(f"{what}: unknown mode {mode!r}")
    attrs = d.obj(prim.get("attributes"), f"{what} attributes")
    if "POSITION" not in attrs:
        d.warnings.append(f"{what}: no POSITION attribute, skipped")
        return None
    lim = d.limits
    draco = d.obj(prim.get("extensions"), f"{what} extensions").get("KHR_draco_mesh_compression")
    if draco is not None:
        decode_draco(d, what, prim, attrs, d.obj(draco, f"{what} Draco"))
    positions = d.accessor(attrs["POSITION"], lim.max_vertices, f"{what} POSITION")
    n = len(positions)
    if positions.shape[1] != 3:
        raise d.bad(f"{what}: POSITION is not VEC3")
    colors = attribute(d, what, attrs, "COLOR_0", (4, 3), n)
    if colors is not None and colors.shape[1] == 3:
        colors = np.concatenate([colors, np.ones((n, 1), np.float32)], axis=1)
    if "indices" in prim:
        idx = d.accessor(prim["indices"], 3 * lim.max_triangles, f"{what} indices")
        if idx.dtype.kind not in "u" or idx.shape[1] != 1:
            raise d.bad(f"{what}: indices must be unsigned integer scalars")
        idx = idx[:, 0].astype(np.uint32)
    else:
        idx = np.arange(n, dtype=np.uint32)
    positions, normals, tangents = _deform(
        d, what, prim, attrs, weights, skin, positions.astype(np.float32, copy=False),
        attribute(d, what, attrs, "NORMAL", (3,), n), attribute(d, what, attrs, "TANGENT", (4,), n))
    if mode == POINTS:
        faces = idx.reshape(-1, 1)
    elif mode in (LINES, LINE_LOOP, LINE_STRIP):
        faces = segments(idx, mode)
    else:
        faces = triangles(idx, mode)
    return Mesh(name=f"{d.name('meshes', mesh_index, 'mesh')}/{prim_index}",
                positions=positions, normals=normals,  # type: ignore[arg-type]  # None: pipeline.ingest computes them
                indices=faces, tangents=tangents,
                uv0=attribute(d, what, attrs, "TEXCOORD_0", (2,), n),
                uv1=attribute(d, what, attrs, "TEXCOORD_1", (2,), n), colors=colors)


def attribute(d: Document, what: str, source: dict, name: str, widths: tuple[int, ...],
               n: int) -> np.ndarray | None:
    """Vertex attribute `name` of `source` (a primitive's attributes or a morph target) as
    float32, checked to hold `n` rows of one of `widths`; None when absent."""
    if name not in source:
        return None
    arr = d.accessor(source[name], d.limits.max_vertices, f"{what} {name}")
    if arr.shape[1] not in widths or len(arr) != n:
        raise d.bad(f"{what}: {name} has {len(arr)} x {arr.shape[1]} values, "
                    f"expected {n} x {widths[0]}")
    return arr.astype(np.float32, copy=False)


def _deform(d: Document, what: str, prim: dict, attrs: dict, weights, skin: np.ndarray | None,
            positions: np.ndarray, normals: np.ndarray | None, tangents: np.ndarray | None):
    """Positions, normals and tangents with the morph targets applied at `weights`, then posed
    by the skin's joint matrices (when given and the primitive has joints and weights)."""
    n = len(positions)
    targets = d.array(prim, "targets")
    if targets and any(weights):
        deltas: dict[str, list[np.ndarray | None]] = {k: [] for k in ("POSITION", "NORMAL", "TANGENT")}
        for t, target in enumerate(targets[:len(weights)]):
            target = d.obj(target, f"{what} target {t}")
            for k, arr in deltas.items():
                arr.append(attribute(d, what, target, k, (3,), n))
        positions = morph(positions, deltas["POSITION"], weights)
        if normals is not None:
            normals = morph(normals, deltas["NORMAL"], weights)
        if tangents is not None:
            tangents = morph(tangents, deltas["TANGENT"], weights)
    if skin is None:
        return positions, normals, tangents
    sets = [(attrs[f"JOINTS_{k}"], attrs[f"WEIGHTS_{k}"]) for k in range(8)
            if f"JOINTS_{k}" in attrs and f"WEIGHTS_{k}" in attrs]
    if not sets:
        return positions, normals, tangents
    joints = [d.accessor(j, d.limits.max_vertices, f"{what} JOINTS") for j, _ in sets]
    weights4 = [cast(np.ndarray, attribute(d, what, attrs, f"WEIGHTS_{k}", (4,), n))
                for k in range(len(sets))]
    if any(j.shape != (n, 4) or j.dtype.kind != "u" for j in joints):
        raise d.bad(f"{what}: JOINTS_n must be {n} x 4 unsigned integers")
    top = max(int(j.max()) for j in joints)
    if top >= len(skin):
        raise d.bad(f"{what}: joint {top} is past the skin's {len(skin)} joints")
    return skin_vertices(skin, joints, weights4, positions, normals, tangents)


def decode_draco(d: Document, what: str, prim: dict, attrs: dict, draco: dict) -> None:
    """Decode a Draco primitive and give its accessors (which have no bufferView of their
    own) the decoded arrays, which they are then read from."""
    ids = d.obj(draco.get("attributes"), f"{what} Draco attributes")
    targets = {name: attrs[name] for name in ids if name in attrs}
    if "indices" in prim:
        targets["indices"] = prim["indices"]
    if all(d.has_accessor(acc) for acc in targets.values()):
        return  # another primitive shared these accessors
    expected = {}
    for name, acc_index in targets.items():
        acc = d.item("accessors", acc_index, f"{what} {name}")
        ctype, kind = acc.get("componentType"), acc.get("type")
        if ctype not in COMPONENTS or kind not in WIDTH:
            raise d.bad(f"{what}: accessor {acc_index} ({name}) has an unknown type")
        count = d.integer(acc, "count", lo=1)
        if count > (3 * d.limits.max_triangles if name == "indices" else d.limits.max_vertices):
            raise LimitExceeded(d.path, f"{what}: accessor {acc_index} ({name}) has {count} "
                                        "elements, over the limit")
        expected[name] = (count, COMPONENTS[ctype], WIDTH[kind])
    view = d.integer(draco, "bufferView")
    arrays, faces = draco_primitive(d.path, f"{what} (Draco, bufferView {view})",
                                    d.view(view)[0], ids, expected, d.limits, d.account)
    for name, arr in arrays.items():
        d.set_accessor(targets[name], as_values(arr, d.item("accessors", targets[name])))
    if "indices" in targets:
        d.set_accessor(targets["indices"], faces.reshape(-1, 1))


def triangles(idx: np.ndarray, mode: int) -> np.ndarray:
    """Triangle list (M x 3) from the indices of a triangles, strip or fan primitive."""
    if mode == TRIANGLES:
        usable = len(idx) - len(idx) % 3
        return idx[:usable].reshape(-1, 3)
    if len(idx) < 3:
        return np.zeros((0, 3), np.uint32)
    i = np.arange(len(idx) - 2)
    if mode == TRIANGLE_STRIP:  # spec: {v_i, v_i+(1+i%2), v_i+(2-i%2)} keeps one winding
        odd = i % 2
        return np.stack([idx[i], idx[i + 1 + odd], idx[i + 2 - odd]], axis=1)
    return np.stack([idx[i + 1], idx[i + 2], np.full_like(idx[i], idx[0])], axis=1)


def thicken(scene: Scene, wire: dict[int, int]) -> None:
    """Points and lines (scene mesh -> primitive mode in `wire`) as octahedra and tubes a few
    pixels wide at the default framing: radii are a fraction of the scene's diagonal, in each
    mesh's own units."""
    size = float(np.linalg.norm(np.ptp(scene.bounds, axis=0))) or 1.0
    for mi, mode in wire.items():
        mesh = scene.meshes[mi]
        scales = [np.cbrt(abs(np.linalg.det(i.matrix[:3, :3]))) for i in scene.instances
                  if i.mesh == mi]
        scale = float(np.median(scales)) if scales else 1.0
        kind = POINTS if mode == POINTS else LINES
        radius = WIRE_RADIUS[kind] * size / (scale if scale > 0 else 1.0)
        build = octahedra if kind == POINTS else tubes
        idx = mesh.indices[:, 0] if kind == POINTS else mesh.indices
        mesh.positions, mesh.normals, mesh.indices, mesh.colors = build(
            mesh.positions, idx, radius, mesh.colors)
        mesh.uv0 = mesh.uv1 = mesh.tangents = None
