"""glTF 2.0 (.gltf, .glb) into a Scene.

The JSON is read with the standard library and accessors are sliced straight out of the
buffers with numpy (strided views, no per-vertex Python). pygltflib's object model costs
10-20x trimesh's whole load to build, so it is used to write glTF (tests), not to read it.
Every index, count and offset is checked against what it points into before anything is
allocated. Flat normals and tangents, when missing, are left to ingest's shared finishing.
"""
from __future__ import annotations

import base64
import binascii
import dataclasses
import json
import logging
import math
import os
import struct
from pathlib import Path
from typing import cast

import numpy as np

from core.animation import Moment, seconds, select
from core.errors import LimitExceeded, MalformedAsset, MissingFile, UnsupportedFormat
from core.scene import (
    Instance,
    Light,
    Material,
    Mesh,
    Sampler,
    Scene,
    SceneCamera,
    Texture,
    TextureRef,
    default_material,
)
from pipeline import deadline
from pipeline.gltf.animation import read_animations
from pipeline.gltf.decode import MESHOPT_EXTENSIONS, draco_primitive, meshopt_view
from pipeline.gltf.materials import MATERIAL_EXTENSIONS, read_lobes
from pipeline.gltf.skin import morph
from pipeline.gltf.skin import skin as skin_vertices
from pipeline.gltf.specgloss import conversion_textures, convert_factors
from pipeline.images import DeferredTexture, probe_image
from pipeline.limits import Limits
from pipeline.paths import resolve_reference
from pipeline.wire import LINE_LOOP, LINE_STRIP, LINES, POINTS, octahedra, segments, tubes

log = logging.getLogger(__name__)

SUPPORTED_EXTENSIONS = frozenset({
    "KHR_materials_transmission", "KHR_materials_ior", "KHR_materials_volume",
    "KHR_materials_emissive_strength", "KHR_texture_transform", "KHR_mesh_quantization",
    "KHR_materials_unlit", "KHR_lights_punctual", "EXT_texture_webp",
    "KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression",
    "KHR_texture_basisu", "EXT_mesh_gpu_instancing", "KHR_materials_variants",
}) | MATERIAL_EXTENSIONS
# Read, with a documented approximation (README, "glTF extensions").
PARTIAL_EXTENSIONS = frozenset({
    "KHR_materials_pbrSpecularGlossiness",  # converted to metallic-roughness at ingest
})
COMPONENTS: dict[int, np.dtype] = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
                                   5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN = 4, 5, 6
WIRE_RADIUS = {POINTS: 0.012, LINES: 0.006}  # x the scene diagonal: a few pixels at 512 px
GLB_MAGIC, CHUNK_JSON, CHUNK_BIN = b"glTF", 0x4E4F534A, 0x004E4942


def load(path: Path, limits: Limits, root: Path | None = None,
         moment: Moment | None = None) -> Scene:
    """Read a .gltf or .glb file (checked against `limits`) into a Scene; its URIs must lie
    inside `root` (default: its folder; `paths.sandbox_root`). With a `moment`, nodes, skins
    and morph weights are posed by that animation at that time (pipeline.gltf.animation)."""
    return _Reader(Path(path), limits, root).scene(moment)


def _split_glb(path: Path, data: bytes) -> tuple[memoryview, memoryview | None]:
    """The JSON text and BIN chunk of a GLB container, every length checked."""
    if len(data) < 20:
        raise MalformedAsset(path, f"GLB file is truncated ({len(data)} bytes)")
    magic, version, length = struct.unpack_from("<4sII", data)
    if magic != GLB_MAGIC:
        raise MalformedAsset(path, "not a GLB file (bad magic)")
    if version != 2:
        raise UnsupportedFormat(path, f"GLB version {version}; only glTF 2.0 is read")
    if length > len(data):
        raise MalformedAsset(path, f"GLB file is truncated: header says {length} bytes, "
                                   f"file has {len(data)}")
    pos, chunks = 12, []
    while pos + 8 <= length:
        size, kind = struct.unpack_from("<II", data, pos)
        if pos + 8 + size > length:
            raise MalformedAsset(path, f"GLB chunk at byte {pos} runs past the end of the file")
        chunks.append((kind, memoryview(data)[pos + 8: pos + 8 + size]))
        pos += 8 + size + (-size % 4 if pos + 8 + size + (-size % 4) <= length else 0)
    if not chunks or chunks[0][0] != CHUNK_JSON:
        raise MalformedAsset(path, "GLB file does not start with a JSON chunk")
    binary = next((c for k, c in chunks[1:] if k == CHUNK_BIN), None)
    return chunks[0][1], binary


class _Reader:
    def __init__(self, path: Path, limits: Limits, root: Path | None = None):
        self.path, self.limits, self.root = path, limits, root
        self.files: list[str] = []  # referenced files; load_scene adds the asset itself
        self.warnings: list[str] = []
        self._buffers: dict[int, bytes | memoryview] = {}
        self._accessor_cache: dict[int, np.ndarray] = {}
        self._decoded_views: dict[int, memoryview] = {}  # meshopt bufferViews, decoded
        self._parents: dict[int, int] | None = None  # node -> parent, built when needed
        self._texture_map: dict[int, int | None] = {}
        self._image_map: dict[tuple, int | None] = {}  # (image, sampler) -> scene texture
        self._images: dict[int, tuple | None] = {}
        self._arrays: dict[str, list] = {}  # top-level JSON arrays, type-checked once
        self._files_read: dict[str, bytes] = {}  # by resolved path
        self.textures: list[Texture] = []  # DeferredTextures
        self._pose: dict[int, dict[str, np.ndarray]] = {}  # node -> animated TRS / weights
        self._unpacked = 0  # bytes of referenced files and decoded arrays, against the limit
        data = path.read_bytes()
        text: bytes | memoryview
        if data[:4] == GLB_MAGIC:
            text, self.glb_bin = _split_glb(path, data)
        else:
            text, self.glb_bin = data, None
        try:
            self.doc = json.loads(bytes(text))
        except (ValueError, UnicodeDecodeError, RecursionError) as exc:
            raise MalformedAsset(path, f"invalid glTF JSON: {exc}") from None
        if not isinstance(self.doc, dict):
            raise MalformedAsset(path, "glTF JSON is not an object")
        version = str(self._dict(self.doc.get("asset"), "asset").get("version", ""))
        if not version.startswith("2."):
            raise UnsupportedFormat(path, f"glTF version {version or '(missing)'}; only 2.x is read")
        unknown = sorted(set(self._list(self.doc, "extensionsRequired")) - SUPPORTED_EXTENSIONS
                         - PARTIAL_EXTENSIONS)
        if unknown:
            raise UnsupportedFormat(path, f"requires glTF extension(s) we do not support: "
                                          f"{', '.join(map(str, unknown))}")

    # -- JSON access with errors that name the file -------------------------------------------
    def _bad(self, reason: str) -> MalformedAsset:
        return MalformedAsset(self.path, reason)

    def _dict(self, value, what: str) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise self._bad(f"{what} is not a JSON object")
        return value

    def _list(self, obj: dict, key: str) -> list:
        value = obj.get(key, [])
        if not isinstance(value, list):
            raise self._bad(f"{key} is not a JSON array")
        return value

    def _get(self, key: str, index, what: str | None = None) -> dict:
        items = self._arrays.get(key)
        if items is None:
            items = self._arrays[key] = self._list(self.doc, key)
        if type(index) is not int or not 0 <= index < len(items):
            raise self._bad(f"{what or key} index {index!r} out of range ({len(items)} {key})")
        item = items[index]
        return item if type(item) is dict else self._dict(item, f"{key}[{index}]")

    def _int(self, obj: dict, key: str, default=None, lo: int = 0) -> int:
        value = obj.get(key, default)
        if type(value) is not int or value < lo:
            raise self._bad(f"{key} = {value!r} is not an integer >= {lo}")
        return value

    def _floats(self, obj: dict, key: str, default: tuple) -> tuple:
        value = obj.get(key, default)
        try:
            out = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise self._bad(f"{key} = {value!r} is not a list of numbers") from None
        if len(out) != len(default) or not all(math.isfinite(v) for v in out):
            raise self._bad(f"{key} = {value!r} must be {len(default)} finite numbers")
        return out

    def _float(self, obj: dict, key: str, default: float, lo: float = -math.inf,
               hi: float = math.inf) -> float:
        """A number from the JSON, finite unless its default is infinite, clamped to lo..hi."""
        value = obj.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value) \
                or (math.isinf(value) and not math.isinf(default)):
            raise self._bad(f"{key} = {value!r} is not a finite number")
        return min(max(float(value), lo), hi)

    # -- buffers and accessors ------------------------------------------------------------------
    def _payload(self, uri, what: str) -> tuple[bytes, str | None]:
        """Bytes named by a buffer or image URI (a data: URI or a file beside the asset), and
        the file they were read from (None for a data: URI)."""
        if not isinstance(uri, str):
            raise self._bad(f"{what} uri is not a string")
        if uri.startswith("data:"):
            head, sep, body = uri.partition(",")
            if not sep or not head.endswith(";base64"):
                raise self._bad(f"{what} data: URI is not base64")
            if len(body) * 3 // 4 > self.limits.max_file_bytes:
                raise LimitExceeded(self.path, f"{what} data: URI is over "
                                               f"{self.limits.max_file_bytes} bytes")
            try:
                return base64.b64decode(body, validate=True), None
            except (binascii.Error, ValueError) as exc:
                raise self._bad(f"{what} data: URI is not valid base64: {exc}") from None
        target = str(resolve_reference(self.path, uri, root=self.root))
        if target not in self._files_read:  # many buffers may name one file: read it once
            size = os.stat(target).st_size
            if size > self.limits.max_file_bytes:
                raise LimitExceeded(self.path, f"{what} {uri!r} is {size} bytes, over the limit "
                                               f"of {self.limits.max_file_bytes}")
            self._account(size, f"{what} {uri!r}")
            self.files.append(target)
            with open(target, "rb") as f:
                self._files_read[target] = f.read()
        return self._files_read[target], target

    def _buffer(self, index: int) -> bytes | memoryview:
        if index not in self._buffers:
            buf = self._get("buffers", index)
            declared = self._int(buf, "byteLength", lo=1)
            data: bytes | memoryview
            if "uri" in buf:
                data = self._payload(buf["uri"], f"buffer {index}")[0]
            elif index == 0 and self.glb_bin is not None:
                data = self.glb_bin
            else:
                raise self._bad(f"buffer {index} has no uri and there is no GLB binary chunk")
            if len(data) < declared:
                raise self._bad(f"buffer {index} is truncated: {len(data)} bytes, "
                                f"byteLength says {declared}")
            self._buffers[index] = data
        return self._buffers[index]

    def _view(self, index: int) -> tuple[memoryview, int]:
        """A buffer view's bytes and its byteStride (0 when tightly packed); a meshopt-compressed
        view is decoded (once) from the bytes its extension points at."""
        bv = self._get("bufferViews", index)
        ext = self._dict(bv.get("extensions"), f"bufferView {index} extensions")
        meshopt = next((ext[k] for k in MESHOPT_EXTENSIONS if k in ext), None)
        if meshopt is not None:
            if index not in self._decoded_views:
                spec = self._dict(meshopt, f"bufferView {index} meshopt")
                data = self._buffer(self._int(spec, "buffer"))
                offset, length = self._int(spec, "byteOffset", 0), self._int(spec, "byteLength", lo=1)
                if offset + length > len(data):
                    raise self._bad(f"bufferView {index}: meshopt stream (bytes {offset}.."
                                    f"{offset + length}) runs past its {len(data)}-byte buffer")
                self._decoded_views[index] = memoryview(meshopt_view(  # type: ignore[arg-type]  # uint8 ndarray
                    self.path, index, spec, memoryview(data)[offset: offset + length],
                    self.limits, self._account))
            return self._decoded_views[index], self._int(meshopt, "byteStride", lo=1)
        data = self._buffer(self._int(bv, "buffer"))
        offset, length = self._int(bv, "byteOffset", 0), self._int(bv, "byteLength", lo=1)
        if offset + length > len(data):
            raise self._bad(f"bufferView {index} (bytes {offset}..{offset + length}) runs past "
                            f"the end of its {len(data)}-byte buffer")
        stride = self._int(bv, "byteStride", 0)
        if stride and not 4 <= stride <= 252:
            raise self._bad(f"bufferView {index} byteStride {stride} outside 4..252")
        return memoryview(data)[offset: offset + length], stride

    def _strided(self, view_index: int, offset: int, count: int, dtype: np.dtype, width: int,
                 what: str) -> np.ndarray:
        data, stride = self._view(view_index)
        elem = dtype.itemsize * width
        stride = stride or elem
        if stride < elem:
            raise self._bad(f"{what}: byteStride {stride} is smaller than one element ({elem})")
        end = offset + stride * (count - 1) + elem
        if end > len(data):
            raise self._bad(f"{what} needs bytes {offset}..{end} of bufferView {view_index}, "
                            f"which holds {len(data)}")
        return np.ndarray((count, width), dtype, buffer=data, offset=offset,
                          strides=(stride, dtype.itemsize))

    def accessor(self, index: int, max_count: int, role: str) -> np.ndarray:
        """Accessor `index` as a (count, width) array; normalized integers become float32."""
        if index in self._accessor_cache:
            return self._accessor_cache[index]
        acc = self._get("accessors", index, role)
        what = f"accessor {index} ({role})"
        ctype = acc.get("componentType")
        if ctype not in COMPONENTS:
            raise self._bad(f"{what} has unknown componentType {ctype!r}")
        if acc.get("type") not in WIDTH:
            raise self._bad(f"{what} has unknown type {acc.get('type')!r}")
        dtype, width = COMPONENTS[ctype], WIDTH[acc["type"]]
        count = self._int(acc, "count", lo=1)
        if count > max_count:
            raise LimitExceeded(self.path, f"{what} has {count} elements, over the limit of "
                                           f"{max_count}")
        self._account(count * width * 4, what)
        if "bufferView" in acc:
            offset = self._int(acc, "byteOffset", 0)
            if offset % dtype.itemsize:
                raise self._bad(f"{what} byteOffset {offset} is not aligned to its component")
            arr = self._strided(acc["bufferView"], offset, count, dtype, width, what)
        else:
            arr = np.zeros((count, width), dtype)
        if "sparse" in acc:
            arr = self._apply_sparse(arr, self._dict(acc["sparse"], f"{what} sparse"), what)
        out = self._accessor_cache[index] = _as_values(arr, acc)
        return out

    def _apply_sparse(self, arr: np.ndarray, sparse: dict, what: str) -> np.ndarray:
        count = self._int(sparse, "count", lo=1)
        if count > len(arr):
            raise self._bad(f"{what}: sparse count {count} exceeds the accessor's {len(arr)}")
        ind = self._dict(sparse.get("indices"), f"{what} sparse.indices")
        val = self._dict(sparse.get("values"), f"{what} sparse.values")
        itype = ind.get("componentType")
        if itype not in (5121, 5123, 5125):
            raise self._bad(f"{what}: sparse indices componentType {itype!r} is not unsigned")
        idx = self._strided(self._int(ind, "bufferView"), self._int(ind, "byteOffset", 0), count,
                            COMPONENTS[itype], 1, f"{what} sparse indices")[:, 0]
        values = self._strided(self._int(val, "bufferView"), self._int(val, "byteOffset", 0),
                               count, arr.dtype, arr.shape[1], f"{what} sparse values")
        if idx.max() >= len(arr):
            raise self._bad(f"{what}: sparse index {int(idx.max())} past the count {len(arr)}")
        arr = np.array(arr)
        arr[idx.astype(np.int64)] = values
        return arr

    def _account(self, nbytes: int, what: str) -> None:
        self._unpacked += nbytes
        if self._unpacked > self.limits.max_unpacked_bytes:
            raise LimitExceeded(self.path, f"{what}: decoded data would exceed "
                                           f"{self.limits.max_unpacked_bytes} bytes")

    # -- geometry -------------------------------------------------------------------------------
    def primitive(self, mesh_index: int, prim_index: int, prim: dict, weights=(),
                  skin: np.ndarray | None = None) -> Mesh | None:
        """One primitive as a Mesh, its morph targets applied at `weights` and, given the
        skin's joint matrices, posed by them (positions then in world space). Points and lines
        come back with `indices` holding their vertex indices (1 or 2 per row), to be turned
        into thin geometry once the scene's size is known (see scene())."""
        what = f"mesh {mesh_index} primitive {prim_index}"
        mode = prim.get("mode", TRIANGLES)
        if mode not in (POINTS, LINES, LINE_LOOP, LINE_STRIP, TRIANGLES, TRIANGLE_STRIP,
                        TRIANGLE_FAN):
            raise self._bad(f"{what}: unknown mode {mode!r}")
        attrs = self._dict(prim.get("attributes"), f"{what} attributes")
        if "POSITION" not in attrs:
            self.warnings.append(f"{what}: no POSITION attribute, skipped")
            return None
        lim = self.limits
        draco = self._dict(prim.get("extensions"), f"{what} extensions").get(
            "KHR_draco_mesh_compression")
        if draco is not None:
            self._decode_draco(what, prim, attrs, self._dict(draco, f"{what} Draco"))
        positions = self.accessor(attrs["POSITION"], lim.max_vertices, f"{what} POSITION")
        n = len(positions)
        if positions.shape[1] != 3:
            raise self._bad(f"{what}: POSITION is not VEC3")

        def attribute(name: str, widths: tuple[int, ...], source: dict = attrs) -> np.ndarray | None:
            if name not in source:
                return None
            arr = self.accessor(source[name], lim.max_vertices, f"{what} {name}")
            if arr.shape[1] not in widths or len(arr) != n:
                raise self._bad(f"{what}: {name} has {len(arr)} x {arr.shape[1]} values, "
                                f"expected {n} x {widths[0]}")
            return arr.astype(np.float32, copy=False)

        colors = attribute("COLOR_0", (4, 3))
        if colors is not None and colors.shape[1] == 3:
            colors = np.concatenate([colors, np.ones((n, 1), np.float32)], axis=1)
        if "indices" in prim:
            idx = self.accessor(prim["indices"], 3 * lim.max_triangles, f"{what} indices")
            if idx.dtype.kind not in "u" or idx.shape[1] != 1:
                raise self._bad(f"{what}: indices must be unsigned integer scalars")
            idx = idx[:, 0].astype(np.uint32)
        else:
            idx = np.arange(n, dtype=np.uint32)
        positions = positions.astype(np.float32, copy=False)
        normals, tangents = attribute("NORMAL", (3,)), attribute("TANGENT", (4,))
        targets = self._list(prim, "targets")
        if targets and any(weights):
            deltas: dict[str, list[np.ndarray | None]] = {k: [] for k in ("POSITION", "NORMAL", "TANGENT")}
            for t, target in enumerate(targets[:len(weights)]):
                target = self._dict(target, f"{what} target {t}")
                for k, arr in deltas.items():
                    arr.append(attribute(k, (3,), target))
            positions = morph(positions, deltas["POSITION"], weights)
            if normals is not None:
                normals = morph(normals, deltas["NORMAL"], weights)
            if tangents is not None:
                tangents = morph(tangents, deltas["TANGENT"], weights)
        if skin is not None:
            sets = [(attrs[f"JOINTS_{k}"], attrs[f"WEIGHTS_{k}"]) for k in range(8)
                    if f"JOINTS_{k}" in attrs and f"WEIGHTS_{k}" in attrs]
            if sets:
                joints = [self.accessor(j, lim.max_vertices, f"{what} JOINTS") for j, _ in sets]
                weights4 = [cast(np.ndarray, attribute(f"WEIGHTS_{k}", (4,))) for k in range(len(sets))]
                if any(j.shape != (n, 4) or j.dtype.kind != "u" for j in joints):
                    raise self._bad(f"{what}: JOINTS_n must be {n} x 4 unsigned integers")
                top = max(int(j.max()) for j in joints)
                if top >= len(skin):
                    raise self._bad(f"{what}: joint {top} is past the skin's {len(skin)} joints")
                positions, normals, tangents = skin_vertices(skin, joints, weights4, positions,
                                                             normals, tangents)
        if mode == POINTS:
            faces = idx.reshape(-1, 1)
        elif mode in (LINES, LINE_LOOP, LINE_STRIP):
            faces = segments(idx, mode)
        else:
            faces = _triangles(idx, mode)
        return Mesh(name=f"{self._name('meshes', mesh_index)}/{prim_index}",
                    positions=positions, normals=normals,  # type: ignore[arg-type]  # None: pipeline.ingest computes them
                    indices=faces, tangents=tangents,
                    uv0=attribute("TEXCOORD_0", (2,)), uv1=attribute("TEXCOORD_1", (2,)),
                    colors=colors)

    def _decode_draco(self, what: str, prim: dict, attrs: dict, draco: dict) -> None:
        """Decode a Draco primitive and put its arrays in the accessor cache, where the
        accessors (which have no bufferView of their own) are then read from."""
        ids = self._dict(draco.get("attributes"), f"{what} Draco attributes")
        targets = {name: attrs[name] for name in ids if name in attrs}
        if "indices" in prim:
            targets["indices"] = prim["indices"]
        if all(acc in self._accessor_cache for acc in targets.values()):
            return  # another primitive shared these accessors
        expected = {}
        for name, acc_index in targets.items():
            acc = self._get("accessors", acc_index, f"{what} {name}")
            ctype, kind = acc.get("componentType"), acc.get("type")
            if ctype not in COMPONENTS or kind not in WIDTH:
                raise self._bad(f"{what}: accessor {acc_index} ({name}) has an unknown type")
            count = self._int(acc, "count", lo=1)
            if count > (3 * self.limits.max_triangles if name == "indices" else self.limits.max_vertices):
                raise LimitExceeded(self.path, f"{what}: accessor {acc_index} ({name}) has {count} "
                                               "elements, over the limit")
            expected[name] = (count, COMPONENTS[ctype], WIDTH[kind])
        view = self._int(draco, "bufferView")
        arrays, faces = draco_primitive(self.path, f"{what} (Draco, bufferView {view})",
                                        self._view(view)[0], ids, expected, self.limits,
                                        self._account)
        for name, arr in arrays.items():
            self._accessor_cache[targets[name]] = _as_values(arr, self._get("accessors", targets[name]))
        if "indices" in targets:
            self._accessor_cache[targets["indices"]] = faces.reshape(-1, 1)

    def _name(self, key: str, index: int) -> str:
        name = self._list(self.doc, key)[index].get("name")
        return str(name) if name else f"{key[:-1]}{index}"

    # -- materials and textures -----------------------------------------------------------------
    def texture_ref(self, info, slot: str) -> TextureRef | None:
        if info is None:
            return None
        info = self._dict(info, slot)
        tex = self._texture(self._int(info, "index"))
        if tex is None:
            return None
        uv_set = self._int(info, "texCoord", 0)
        ref = TextureRef(texture=tex, uv_set=uv_set)
        tt = self._dict(info.get("extensions"), f"{slot} extensions").get("KHR_texture_transform")
        if tt is not None:
            tt = self._dict(tt, f"{slot} KHR_texture_transform")
            ref.offset = self._floats(tt, "offset", (0.0, 0.0))
            ref.rotation = self._float(tt, "rotation", 0.0)
            ref.scale = self._floats(tt, "scale", (1.0, 1.0))
            ref.uv_set = self._int(tt, "texCoord", uv_set)
        if ref.uv_set > 1:
            self.warnings.append(f"{slot}: TEXCOORD_{ref.uv_set} is not read; texture ignored")
            return None
        return ref

    def _texture(self, index: int) -> int | None:
        """Scene texture index for glTF texture `index`; None (with a warning) if unusable."""
        if index in self._texture_map:
            return self._texture_map[index]
        deadline.check()
        tex = self._get("textures", index, "texture")
        source = tex.get("source")
        ext = self._dict(tex.get("extensions"), f"texture {index} extensions")
        for name in ("KHR_texture_basisu", "EXT_texture_webp"):  # what a viewer would pick
            if name in ext:
                source = self._dict(ext[name], name).get("source", source)
                break
        if not isinstance(source, (int, type(None))) or not isinstance(tex.get("sampler"), (int, type(None))):
            raise self._bad(f"texture {index}: source/sampler are not indices")
        result = None
        if (source, tex.get("sampler")) in self._image_map:
            result = self._image_map[source, tex.get("sampler")]
        elif source is None:
            self.warnings.append(f"texture {index}: no image source we can read "
                                 f"(extensions: {', '.join(ext) or 'none'}); factor only")
        elif len(self.textures) >= self.limits.max_textures:
            raise LimitExceeded(self.path, f"more than {self.limits.max_textures} textures")
        else:
            img = self._get("images", source, f"texture {index} source")
            probed = self._image(source, img)
            if probed is not None:
                data, size, label = probed
                self.textures.append(DeferredTexture(
                    name=str(img.get("name") or tex.get("name") or f"image{source}"), data=data,
                    size=size, limits=self.limits, sampler=self._sampler(tex.get("sampler")),
                    source=label))
                result = len(self.textures) - 1
            self._image_map[source, tex.get("sampler")] = result
        self._texture_map[index] = result
        return result

    def _image(self, source: int, img: dict) -> tuple[bytes | memoryview, tuple[int, int], str] | None:
        """An image's encoded bytes, size and label, probed once; None (warned) if unusable."""
        if source in self._images:
            return self._images[source]
        data: bytes | memoryview
        if "bufferView" in img:
            data = self._view(self._int(img, "bufferView"))[0]  # no copy: decoded later
            label = f"{self.path} image {source}"
        elif "uri" in img:
            try:
                data, file = self._payload(img["uri"], f"image {source}")
            except MissingFile as exc:  # the material keeps its factors; unsafe URIs still refuse
                self.warnings.append(f"image {source}: {exc.reason}; its textures are dropped "
                                     "(factor only)")
                log.warning("%s: image %d dropped: %s", self.path, source, exc.reason)
                self._images[source] = None
                return None
            label = file or f"{self.path} image {source}"
        else:
            raise self._bad(f"image {source} has neither uri nor bufferView")
        try:
            size = probe_image(data, label, self.limits)
        except (MalformedAsset, LimitExceeded) as exc:
            self.warnings.append(f"image {source}: {exc.reason}; its textures are dropped "
                                 "(factor only)")
            log.warning("%s: image %d dropped: %s", self.path, source, exc.reason)
            self._images[source] = None
        else:
            self._account(size[0] * size[1] * 4, f"image {source}")
            self._images[source] = (data, size, label)
        return self._images[source]

    def _sampler(self, index) -> Sampler:
        if index is None:
            return Sampler()
        s = self._get("samplers", index, "sampler")
        out = Sampler()
        for key, attr in (("magFilter", "mag_filter"), ("minFilter", "min_filter"),
                          ("wrapS", "wrap_s"), ("wrapT", "wrap_t")):
            if key in s:
                setattr(out, attr, self._int(s, key))
        return out

    def material(self, index: int) -> Material:
        m = self._get("materials", index, "material")
        slot = f"material {index}"
        pbr = self._dict(m.get("pbrMetallicRoughness"), f"{slot} pbrMetallicRoughness")
        ext = self._dict(m.get("extensions"), f"{slot} extensions")
        out = Material(name=str(m.get("name") or f"material{index}"))
        out.base_color = self._floats(pbr, "baseColorFactor", (1.0, 1.0, 1.0, 1.0))
        out.base_color_texture = self.texture_ref(pbr.get("baseColorTexture"), f"{slot} baseColor")
        out.metallic = self._float(pbr, "metallicFactor", 1.0, 0.0, 1.0)
        out.roughness = self._float(pbr, "roughnessFactor", 1.0, 0.0, 1.0)
        out.metallic_roughness_texture = self.texture_ref(pbr.get("metallicRoughnessTexture"),
                                                          f"{slot} metallicRoughness")
        normal = self._dict(m.get("normalTexture"), f"{slot} normalTexture")
        out.normal_texture = self.texture_ref(m.get("normalTexture"), f"{slot} normal")
        out.normal_scale = self._float(normal, "scale", 1.0)
        occlusion = self._dict(m.get("occlusionTexture"), f"{slot} occlusionTexture")
        out.occlusion_texture = self.texture_ref(m.get("occlusionTexture"), f"{slot} occlusion")
        out.occlusion_strength = self._float(occlusion, "strength", 1.0, 0.0, 1.0)
        out.emissive = self._floats(m, "emissiveFactor", (0.0, 0.0, 0.0))
        out.emissive_texture = self.texture_ref(m.get("emissiveTexture"), f"{slot} emissive")
        if "KHR_materials_pbrSpecularGlossiness" in ext:
            self._spec_gloss(out, self._dict(ext["KHR_materials_pbrSpecularGlossiness"],
                                             f"{slot} pbrSpecularGlossiness"), slot)
        alpha_mode = m.get("alphaMode", "OPAQUE")
        if alpha_mode not in ("OPAQUE", "MASK", "BLEND"):
            raise self._bad(f"{slot}: alphaMode {alpha_mode!r} is not OPAQUE, MASK or BLEND")
        out.alpha_mode = alpha_mode
        out.alpha_cutoff = self._float(m, "alphaCutoff", 0.5, 0.0)
        out.double_sided = bool(m.get("doubleSided", False))
        out.unlit = "KHR_materials_unlit" in ext
        if "KHR_materials_emissive_strength" in ext:
            e = self._dict(ext["KHR_materials_emissive_strength"], "emissive_strength")
            out.emissive_strength = self._float(e, "emissiveStrength", 1.0, 0.0)
        if "KHR_materials_transmission" in ext:
            t = self._dict(ext["KHR_materials_transmission"], "transmission")
            out.transmission = self._float(t, "transmissionFactor", 0.0, 0.0, 1.0)
            out.transmission_texture = self.texture_ref(t.get("transmissionTexture"),
                                                        f"{slot} transmission")
        if "KHR_materials_ior" in ext:
            out.ior = self._float(self._dict(ext["KHR_materials_ior"], "ior"), "ior", 1.5, 1.0)
        if "KHR_materials_volume" in ext:
            v = self._dict(ext["KHR_materials_volume"], "volume")
            out.thickness = self._float(v, "thicknessFactor", 0.0, 0.0)
            out.thickness_texture = self.texture_ref(v.get("thicknessTexture"), f"{slot} thickness")
            out.attenuation_color = self._floats(v, "attenuationColor", (1.0, 1.0, 1.0))
            out.attenuation_distance = self._float(v, "attenuationDistance", math.inf, 1e-9)
        read_lobes(self, ext, out, slot)
        return out

    def _spec_gloss(self, out: Material, sg: dict, slot: str) -> None:
        """KHR_materials_pbrSpecularGlossiness as metallic-roughness (pipeline.gltf.specgloss);
        it replaces the material's pbrMetallicRoughness values, as the extension says."""
        diffuse = self._floats(sg, "diffuseFactor", (1.0, 1.0, 1.0, 1.0))
        specular = self._floats(sg, "specularFactor", (1.0, 1.0, 1.0))
        gloss = self._float(sg, "glossinessFactor", 1.0, 0.0, 1.0)
        d_ref = self.texture_ref(sg.get("diffuseTexture"), f"{slot} diffuse")
        s_ref = self.texture_ref(sg.get("specularGlossinessTexture"), f"{slot} specularGlossiness")
        out.base_color, out.metallic, out.roughness = convert_factors(diffuse, specular, gloss)
        out.base_color_texture = out.metallic_roughness_texture = None
        if d_ref is None and s_ref is None:
            return
        if d_ref is not None and s_ref is not None and (d_ref.uv_set, d_ref.uv_matrix().tolist()) \
                != (s_ref.uv_set, s_ref.uv_matrix().tolist()):
            self.warnings.append(f"{slot}: diffuse and specularGlossiness textures use different "
                                 "UVs; converted with the diffuse texture's")
        if len(self.textures) + 2 > self.limits.max_textures:
            raise LimitExceeded(self.path, f"more than {self.limits.max_textures} textures")
        base, mr = conversion_textures(
            None if d_ref is None else self.textures[d_ref.texture],
            None if s_ref is None else self.textures[s_ref.texture], diffuse, specular, gloss)
        ref = d_ref or s_ref
        assert ref is not None  # one of them, by the return above
        w, h = cast(DeferredTexture, self.textures[ref.texture]).size
        self._account(2 * 4 * w * h, f"{slot} converted textures")
        for tex, attr in ((base, "base_color_texture"), (mr, "metallic_roughness_texture")):
            self.textures.append(tex)
            setattr(out, attr, dataclasses.replace(ref, texture=len(self.textures) - 1))
        out.base_color, out.metallic, out.roughness = (1.0, 1.0, 1.0, 1.0), 1.0, 1.0

    def light(self, index: object, matrix: np.ndarray) -> Light:  # index from the JSON: checked here
        lights = self._list(self._dict(self._dict(self.doc.get("extensions"), "extensions")
                                       .get("KHR_lights_punctual"), "KHR_lights_punctual"), "lights")
        if not isinstance(index, int) or not 0 <= index < len(lights):
            raise self._bad(f"KHR_lights_punctual light index {index!r} out of range")
        spec = self._dict(lights[index], f"light {index}")
        kind = spec.get("type")
        if kind not in ("directional", "point", "spot"):
            raise self._bad(f"light {index}: unknown type {kind!r}")
        spot = self._dict(spec.get("spot"), f"light {index} spot")
        return Light(type=kind, color=self._floats(spec, "color", (1.0, 1.0, 1.0)),
                     intensity=self._float(spec, "intensity", 1.0, 0.0),
                     range=self._float(spec, "range", math.inf),
                     inner_cone=self._float(spot, "innerConeAngle", 0.0),
                     outer_cone=self._float(spot, "outerConeAngle", math.pi / 4), matrix=matrix)

    def camera(self, index: int, node: int, world: np.ndarray) -> SceneCamera:
        spec = self._get("cameras", index, f"node {node} camera")
        kind = spec.get("type")
        if kind not in ("perspective", "orthographic"):
            raise self._bad(f"camera {index}: type {kind!r} is not perspective or orthographic")
        p = self._dict(spec.get(kind), f"camera {index} {kind}")
        name = str(spec.get("name") or self._list(self.doc, "nodes")[node].get("name")
                   or f"camera{index}")
        out = SceneCamera(name=name, type=kind, matrix=world,
                          znear=self._float(p, "znear", 0.01, 0.0),
                          zfar=self._float(p, "zfar", math.inf, 0.0))
        if kind == "perspective":
            out.yfov = self._float(p, "yfov", 0.8, 1e-4, math.pi - 1e-4)
            aspect = p.get("aspectRatio")
            out.aspect = None if aspect is None else self._float(p, "aspectRatio", 1.0, 1e-4)
        else:
            out.xmag = abs(self._float(p, "xmag", 1.0)) or 1.0
            out.ymag = abs(self._float(p, "ymag", 1.0)) or 1.0
        return out

    def variant_names(self) -> list[str]:
        """KHR_materials_variants: the asset's variant names, in index order."""
        ext = self._dict(self.doc.get("extensions"), "extensions").get("KHR_materials_variants")
        variants = self._list(self._dict(ext, "KHR_materials_variants"), "variants")
        return [str(self._dict(v, f"variant {i}").get("name") or f"variant{i}")
                for i, v in enumerate(variants)]

    def _variant_materials(self, prim: dict, materials: dict, scene: Scene) -> dict[int, int]:
        """{variant index: scene material} from a primitive's KHR_materials_variants mappings."""
        ext = self._dict(prim.get("extensions"), "primitive extensions").get("KHR_materials_variants")
        if ext is None:
            return {}
        count = len(self.variant_names())
        out = {}
        for m in self._list(self._dict(ext, "KHR_materials_variants"), "mappings"):
            m = self._dict(m, "variant mapping")
            mat = self._int(m, "material")
            if mat not in materials:
                materials[mat] = len(scene.materials)
                scene.materials.append(self.material(mat))
            for v in self._list(m, "variants"):
                if type(v) is not int or not 0 <= v < count:
                    raise self._bad(f"KHR_materials_variants mapping names variant {v!r} of {count}")
                out[v] = materials[mat]
        return out

    def extension_report(self) -> dict[str, str]:
        """Each extension in extensionsUsed: supported, partial or ignored. An ignored one
        (not required: required ones were refused at open) is also a warning."""
        report = {}
        for name in map(str, self._list(self.doc, "extensionsUsed")):
            status = ("supported" if name in SUPPORTED_EXTENSIONS else
                      "partial" if name in PARTIAL_EXTENSIONS else "ignored")
            report[name] = status
            if status == "ignored":
                self.warnings.append(f"extension {name} is not supported: ignored (the file "
                                     "renders without it)")
        return report

    # -- scene graph ----------------------------------------------------------------------------
    def _roots(self) -> list:
        scenes = self._list(self.doc, "scenes")
        if scenes:
            index = self.doc.get("scene", 0)
            return self._list(self._get("scenes", index, "default scene"), "nodes")
        # No scenes: every node that is nobody's child is a root.
        nodes = self._list(self.doc, "nodes")
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])
                    if isinstance(c, int)}
        return [i for i in range(len(nodes)) if i not in children]

    def _local(self, node: dict, index: int) -> np.ndarray:
        if index in self._pose:  # animated: the channels' values replace the node's own
            node = {k: v for k, v in node.items() if k != "matrix"}
            node.update({k: [float(x) for x in v] for k, v in self._pose[index].items()})
        if "matrix" in node:
            m = np.array(self._floats(node, "matrix", (0.0,) * 16), np.float64)
            return m.reshape(4, 4).T  # glTF stores column-major
        t = self._floats(node, "translation", (0.0, 0.0, 0.0))
        x, y, z, w = self._floats(node, "rotation", (0.0, 0.0, 0.0, 1.0))
        s = self._floats(node, "scale", (1.0, 1.0, 1.0))
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        if norm == 0.0:
            raise self._bad(f"node {index}: rotation quaternion is zero")
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = r * np.array(s)
        m[:3, 3] = t
        return m

    def _world_matrices(self) -> list[tuple[int, np.ndarray]]:
        """(node, world matrix) for every node of the default scene, parents before children;
        the node graph checked to be a tree."""
        out, seen = [], set()
        stack = [(r, np.eye(4)) for r in reversed(self._roots())]
        while stack:
            deadline.check()
            index, parent = stack.pop()
            node = self._get("nodes", index, "node")
            if index in seen:
                raise self._bad(f"node {index} is reached twice: the node graph is not a tree")
            seen.add(index)
            if len(seen) > self.limits.max_nodes:
                raise LimitExceeded(self.path, f"more than {self.limits.max_nodes} nodes")
            world = parent @ self._local(node, index)
            out.append((index, world))
            for child in reversed(self._list(node, "children")):
                stack.append((child, world))
        return out

    def _world_of(self, index: int, worlds: dict[int, np.ndarray]) -> np.ndarray:
        """World matrix of node `index`, also for a node outside the default scene (a skin's
        joints may be): composed down its parent chain, which is remembered in `worlds`."""
        nodes = self._list(self.doc, "nodes")
        if self._parents is None:
            self._parents = {c: i for i, n in enumerate(nodes) if isinstance(n, dict)
                             for c in n.get("children", []) if isinstance(c, int)}
        chain, j = [], index
        while j not in worlds:
            chain.append(j)
            if len(chain) > len(nodes):
                raise self._bad("node hierarchy has a cycle")
            if j not in self._parents:
                break
            j = self._parents[j]
        m = worlds[j] if j in worlds else np.eye(4)
        for node in reversed(chain):
            m = m @ self._local(self._get("nodes", node, "node"), node)
            worlds[node] = m
        return worlds[index]

    def _joint_matrices(self, skin_index: int, worlds: dict) -> np.ndarray:
        """J_i = world(joint_i) @ inverseBindMatrix_i for skin `skin_index` (K x 4 x 4)."""
        skin = self._get("skins", skin_index, "skin")
        joints = self._list(skin, "joints")
        if not joints or len(joints) > self.limits.max_nodes:
            raise self._bad(f"skin {skin_index} has {len(joints)} joints")
        if "inverseBindMatrices" in skin:
            ibm = self.accessor(skin["inverseBindMatrices"], len(joints), f"skin {skin_index} IBM")
            if ibm.shape != (len(joints), 16) or ibm.dtype != np.float32:
                raise self._bad(f"skin {skin_index}: inverseBindMatrices is not {len(joints)} MAT4")
            ibm = ibm.astype(np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
        else:
            ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
        out = np.empty((len(joints), 4, 4))
        for k, j in enumerate(joints):
            self._get("nodes", j, f"skin {skin_index} joint")
            out[k] = self._world_of(j, worlds) @ ibm[k]
        return out

    def _instancing(self, node: dict, index: int, world: np.ndarray) -> np.ndarray:
        """World matrices of a node's EXT_mesh_gpu_instancing instances (K x 4 x 4), or its
        own world matrix alone."""
        ext = self._dict(node.get("extensions"), f"node {index} extensions")
        spec = ext.get("EXT_mesh_gpu_instancing")
        if spec is None:
            return world[None]
        attrs = self._dict(self._dict(spec, "EXT_mesh_gpu_instancing").get("attributes"),
                           f"node {index} instancing attributes")
        what = f"node {index} EXT_mesh_gpu_instancing"
        arrays = {k: self.accessor(attrs[k], self.limits.max_nodes, f"{what} {k}")
                  for k in ("TRANSLATION", "ROTATION", "SCALE") if k in attrs}
        counts = {len(a) for a in arrays.values()}
        if len(counts) != 1:
            raise self._bad(f"{what}: attributes missing or of different counts {sorted(counts)}")
        count = counts.pop()
        t = arrays.get("TRANSLATION", np.zeros((count, 3)))
        q = arrays.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (count, 1)))
        k = arrays.get("SCALE", np.ones((count, 3)))
        if t.shape[1] != 3 or q.shape[1] != 4 or k.shape[1] != 3:
            raise self._bad(f"{what}: TRANSLATION/SCALE must be VEC3 and ROTATION VEC4")
        return world @ _trs(t.astype(np.float64), q.astype(np.float64), k.astype(np.float64))

    def scene(self, moment: Moment | None = None) -> Scene:
        scene = Scene(source=str(self.path), format="glb" if self.glb_bin is not None or
                      self.path.suffix.lower() == ".glb" else "gltf")
        animations = read_animations(self)
        scene.animations = [a.summary() for a in animations]
        if moment is not None:
            anim = select(animations, moment.animation, str(self.path))
            t = seconds(moment, anim)
            self._pose = anim.pose(t)
            scene.moment = {"animation": anim.name, "time": round(t, 6)}
        prim_meshes: dict[tuple, int | None] = {}
        materials: dict[int | None, int] = {}
        wire: dict[int, int] = {}  # scene mesh -> primitive mode, for points and lines
        placed = self._world_matrices()
        worlds = dict(placed)
        skins: dict[int, np.ndarray] = {}
        for index, world in placed:
            node = self._get("nodes", index, "node")
            node_ext = self._dict(node.get("extensions"), f"node {index} extensions")
            if "KHR_lights_punctual" in node_ext:
                light = self._dict(node_ext["KHR_lights_punctual"], "KHR_lights_punctual")
                scene.lights.append(self.light(light.get("light"), world))
            if "camera" in node:
                scene.cameras.append(self.camera(self._int(node, "camera"), index, world))
            if "mesh" not in node:
                continue
            mesh_index = self._int(node, "mesh")
            mesh_def = self._get("meshes", mesh_index, f"node {index} mesh")
            prims = self._list(mesh_def, "primitives")
            weights = node.get("weights", mesh_def.get("weights", ()))
            if "weights" in self._pose.get(index, {}):
                weights = [float(w) for w in self._pose[index]["weights"]]
            weights = self._floats({"w": weights}, "w", (0.0,) * len(weights)) if weights else ()
            skin = node.get("skin")
            if skin is not None and skin not in skins:
                skins[skin] = self._joint_matrices(self._int(node, "skin"), worlds)
            # A skinned mesh ignores its node's transform: the joints place it (glTF 2.0 spec).
            placements = self._instancing(node, index, np.eye(4) if skin is not None else world)
            for p, prim in enumerate(prims):
                deadline.check()
                prim = self._dict(prim, f"mesh {mesh_index} primitive {p}")
                key = (mesh_index, p, skin, weights)
                if key not in prim_meshes:
                    mesh = self.primitive(mesh_index, p, prim, weights,
                                          None if skin is None else skins[skin])
                    prim_meshes[key] = None if mesh is None else len(scene.meshes)
                    if mesh is not None:
                        if mesh.indices.shape[1] != 3:
                            wire[len(scene.meshes)] = int(prim.get("mode", TRIANGLES))
                        scene.meshes.append(mesh)
                if prim_meshes[key] is None:
                    continue
                mat = prim.get("material")
                if mat not in materials:
                    materials[mat] = len(scene.materials)
                    scene.materials.append(default_material() if mat is None
                                           else self.material(self._int(prim, "material")))
                variants = self._variant_materials(prim, materials, scene)
                for matrix in placements:
                    scene.instances.append(Instance(cast(int, prim_meshes[key]), materials[mat], matrix,
                                                    variants=variants))
        if wire:
            self._thicken(scene, wire)
        scene.variants = self.variant_names()
        scene.textures = self.textures
        scene.warnings = self.warnings
        scene.files = self.files
        scene.extensions = self.extension_report()
        return scene

    def _thicken(self, scene: Scene, wire: dict[int, int]) -> None:
        """Points and lines as octahedra and tubes a few pixels wide at the default framing:
        radii are a fraction of the scene's diagonal, in each mesh's own units."""
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

def _trs(t: np.ndarray, q: np.ndarray, k: np.ndarray) -> np.ndarray:
    """4x4 matrices T @ R @ S from K translations, unit quaternions (x, y, z, w) and scales."""
    q = q / np.where((n := np.linalg.norm(q, axis=1, keepdims=True)) > 0, n, 1.0)
    x, y, z, w = q.T
    r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                  2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                  2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1)
    m = np.tile(np.eye(4), (len(t), 1, 1))
    m[:, :3, :3] = r.reshape(-1, 3, 3) * k[:, None, :]
    m[:, :3, 3] = t
    return m


def _as_values(arr: np.ndarray, acc: dict) -> np.ndarray:
    """An accessor's raw components as the values they stand for: normalized integers become
    float32 in -1..1 / 0..1, floats a contiguous float32 copy (off the file's bytes)."""
    ctype = acc.get("componentType")
    if acc.get("normalized") and ctype in NORMALIZE:
        return np.maximum(arr.astype(np.float32) / NORMALIZE[ctype], -1.0)
    if ctype == 5126:
        return np.array(arr, np.float32)
    return np.array(arr)


def _triangles(idx: np.ndarray, mode: int) -> np.ndarray:
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
