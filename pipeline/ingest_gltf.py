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
import json
import logging
import math
import os
import struct
from pathlib import Path
from typing import cast

import numpy as np

from core.errors import LimitExceeded, MalformedAsset, UnsupportedFormat
from core.scene import Instance, Light, Material, Mesh, Sampler, Scene, Texture, TextureRef, default_material

from . import deadline
from .images import DeferredTexture, probe_image
from .limits import Limits
from .paths import resolve_reference

log = logging.getLogger(__name__)

SUPPORTED_EXTENSIONS = frozenset({
    "KHR_materials_transmission", "KHR_materials_ior", "KHR_materials_volume",
    "KHR_materials_emissive_strength", "KHR_texture_transform", "KHR_mesh_quantization",
    "KHR_materials_unlit", "KHR_lights_punctual", "EXT_texture_webp",
})
COMPONENTS: dict[int, np.dtype] = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
                                   5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN = 4, 5, 6
GLB_MAGIC, CHUNK_JSON, CHUNK_BIN = b"glTF", 0x4E4F534A, 0x004E4942


def load(path: Path, limits: Limits) -> Scene:
    """Read a .gltf or .glb file (checked against `limits`) into a Scene."""
    return _Reader(Path(path), limits).scene()


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
    def __init__(self, path: Path, limits: Limits):
        self.path, self.limits = path, limits
        self.files: list[str] = []  # referenced files; load_scene adds the asset itself
        self.warnings: list[str] = []
        self._buffers: dict[int, bytes | memoryview] = {}
        self._accessor_cache: dict[int, np.ndarray] = {}
        self._texture_map: dict[int, int | None] = {}
        self._image_map: dict[tuple, int | None] = {}  # (image, sampler) -> scene texture
        self._images: dict[int, tuple | None] = {}
        self._arrays: dict[str, list] = {}  # top-level JSON arrays, type-checked once
        self._files_read: dict[str, bytes] = {}  # by resolved path
        self.textures: list[Texture] = []  # DeferredTextures
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
        unknown = sorted(set(self._list(self.doc, "extensionsRequired")) - SUPPORTED_EXTENSIONS)
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
        target = str(resolve_reference(self.path, uri))
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
        """A buffer view's bytes and its byteStride (0 when tightly packed)."""
        bv = self._get("bufferViews", index)
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
        if acc.get("normalized") and ctype in NORMALIZE:
            out = np.maximum(arr.astype(np.float32) / NORMALIZE[ctype], -1.0)
        elif ctype == 5126:
            out = np.array(arr, np.float32)  # contiguous copy, off the file's bytes
        else:
            out = np.array(arr)
        self._accessor_cache[index] = out
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
    def primitive(self, mesh_index: int, prim_index: int, prim: dict) -> Mesh | None:
        what = f"mesh {mesh_index} primitive {prim_index}"
        mode = prim.get("mode", TRIANGLES)
        if mode not in (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN):
            self.warnings.append(f"{what}: mode {mode} (points/lines) skipped: not triangles")
            return None
        attrs = self._dict(prim.get("attributes"), f"{what} attributes")
        if "POSITION" not in attrs:
            self.warnings.append(f"{what}: no POSITION attribute, skipped")
            return None
        lim = self.limits
        positions = self.accessor(attrs["POSITION"], lim.max_vertices, f"{what} POSITION")
        n = len(positions)
        if positions.shape[1] != 3:
            raise self._bad(f"{what}: POSITION is not VEC3")

        def attribute(name: str, widths: tuple[int, ...]) -> np.ndarray | None:
            if name not in attrs:
                return None
            arr = self.accessor(attrs[name], lim.max_vertices, f"{what} {name}")
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
        return Mesh(name=f"{self._name('meshes', mesh_index)}/{prim_index}",
                    positions=positions.astype(np.float32, copy=False),
                    normals=attribute("NORMAL", (3,)), indices=_triangles(idx, mode),  # type: ignore[arg-type]  # None: pipeline.ingest computes them
                    tangents=attribute("TANGENT", (4,)), uv0=attribute("TEXCOORD_0", (2,)),
                    uv1=attribute("TEXCOORD_1", (2,)), colors=colors)

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
        if "EXT_texture_webp" in ext:
            source = self._dict(ext["EXT_texture_webp"], "EXT_texture_webp").get("source", source)
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
            data, file = self._payload(img["uri"], f"image {source}")
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
        return out

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

    def scene(self) -> Scene:
        scene = Scene(source=str(self.path), format="glb" if self.glb_bin is not None or
                      self.path.suffix.lower() == ".glb" else "gltf")
        prim_meshes: dict[tuple[int, int], int | None] = {}
        materials: dict[int | None, int] = {}
        seen: set[int] = set()
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
            for child in reversed(self._list(node, "children")):
                stack.append((child, world))
            node_ext = self._dict(node.get("extensions"), f"node {index} extensions")
            if "KHR_lights_punctual" in node_ext:
                light = self._dict(node_ext["KHR_lights_punctual"], "KHR_lights_punctual")
                scene.lights.append(self.light(light.get("light"), world))
            if "mesh" not in node:
                continue
            mesh_index = self._int(node, "mesh")
            prims = self._list(self._get("meshes", mesh_index, f"node {index} mesh"), "primitives")
            for p, prim in enumerate(prims):
                deadline.check()
                prim = self._dict(prim, f"mesh {mesh_index} primitive {p}")
                key = (mesh_index, p)
                if key not in prim_meshes:
                    mesh = self.primitive(mesh_index, p, prim)
                    prim_meshes[key] = None if mesh is None else len(scene.meshes)
                    if mesh is not None:
                        scene.meshes.append(mesh)
                if prim_meshes[key] is None:
                    continue
                mat = prim.get("material")
                if mat not in materials:
                    materials[mat] = len(scene.materials)
                    scene.materials.append(default_material() if mat is None
                                           else self.material(self._int(prim, "material")))
                scene.instances.append(Instance(cast(int, prim_meshes[key]), materials[mat], world))
        scene.textures = self.textures
        scene.warnings = self.warnings
        scene.files = self.files
        return scene


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
