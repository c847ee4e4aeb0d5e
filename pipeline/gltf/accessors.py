"""The glTF container and its data: the GLB chunks, the JSON with checked access (every error
a `MalformedAsset` naming the file), buffers, buffer views (meshopt-decoded where compressed)
and accessors sliced straight out of the buffers with numpy (strided views, no per-vertex
Python). Every index, count and offset is checked against what it points into before anything
is allocated, and every decoded byte is counted against `Limits.max_unpacked_bytes`."""
from __future__ import annotations

import base64
import binascii
import json
import math
import os
import struct
from pathlib import Path

import numpy as np

from core.errors import LimitExceeded, MalformedAsset, UnsupportedFormat
from pipeline.gltf.decode import MESHOPT_EXTENSIONS, meshopt_view
from pipeline.limits import Limits
from pipeline.paths import resolve_reference

COMPONENTS: dict[int, np.dtype] = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
                                   5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
GLB_MAGIC, CHUNK_JSON, CHUNK_BIN = b"glTF", 0x4E4F534A, 0x004E4942


def _chunk_header_at(data: bytes, pos: int, length: int) -> bool:
    """Whether a plausible chunk header (a known kind whose bytes fit) starts at `pos`."""
    if pos + 8 > length:
        return False
    size, kind = struct.unpack_from("<II", data, pos)
    return kind in (CHUNK_JSON, CHUNK_BIN) and pos + 8 + size <= length


def split_glb(path: Path, data: bytes,
              warnings: list[str] | None = None) -> tuple[memoryview, memoryview | None]:
    """The JSON text and BIN chunk of a GLB container, every length checked. A chunk length
    that is not a multiple of 4 breaks the spec's alignment but not its bytes: as glTF-Validator
    (GLB_CHUNK_LENGTH_UNALIGNED) it is a warning, and the next chunk is looked for both right
    after the chunk and after the padding the writer may have added anyway."""
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
        end = pos + 8 + size
        if size % 4:
            if warnings is not None:
                name = {CHUNK_JSON: "JSON", CHUNK_BIN: "BIN"}.get(kind, f"0x{kind:08x}")
                warnings.append(f"GLB {name} chunk length {size} is not a multiple of 4 "
                                f"(the spec requires padding); read as is")
            padded = end + (-size % 4)
            # the next header right after the bytes, else after the padding, else the end
            if not _chunk_header_at(data, end, length) and padded <= length:
                end = padded
        pos = end
    if not chunks or chunks[0][0] != CHUNK_JSON:
        raise MalformedAsset(path, "GLB file does not start with a JSON chunk")
    binary = next((c for k, c in chunks[1:] if k == CHUNK_BIN), None)
    return chunks[0][1], binary


def _kind_of(data: bytes) -> str:
    """Binary or text, in words, from the first 4 KiB (for messages, not parsing)."""
    head = bytes(data[:4096])
    if not head:
        return "the file is empty"
    if b"\0" not in head:
        try:
            head.decode("utf-8")
            return "the file is text"
        except UnicodeDecodeError as exc:
            if exc.start >= len(head) - 3 and len(data) > 4096:  # a character cut at 4 KiB
                return "the file is text"
    return "the file is binary data"


def as_values(arr: np.ndarray, acc: dict) -> np.ndarray:
    """An accessor's raw components as the values they stand for: normalized integers become
    float32 in -1..1 / 0..1, floats a contiguous float32 copy (off the file's bytes)."""
    ctype = acc.get("componentType")
    if acc.get("normalized") and ctype in NORMALIZE:
        return np.maximum(arr.astype(np.float32) / NORMALIZE[ctype], -1.0)
    if ctype == 5126:
        return np.array(arr, np.float32)
    return np.array(arr)


class Document:
    """One opened .gltf/.glb: its JSON (`doc`), the files it read (`files`), the warnings
    gathered while reading (`warnings`), and checked access to its JSON and binary data."""

    def __init__(self, path: Path, limits: Limits, root: Path | None = None):
        self.path, self.limits, self.root = path, limits, root
        self.files: list[str] = []  # referenced files; load_scene adds the asset itself
        self.warnings: list[str] = []
        self._buffers: dict[int, bytes | memoryview] = {}
        self._accessors: dict[int, np.ndarray] = {}
        self._decoded_views: dict[int, memoryview] = {}  # meshopt bufferViews, decoded
        self._arrays: dict[str, list] = {}  # top-level JSON arrays, type-checked once
        self._files_read: dict[str, bytes] = {}  # by resolved path
        self._unpacked = 0  # bytes of referenced files and decoded arrays, against the limit
        data = path.read_bytes()
        text: bytes | memoryview
        if data[:4] == GLB_MAGIC:
            text, self.glb_bin = split_glb(path, data, self.warnings)
        elif path.suffix.lower() == ".glb":
            raise MalformedAsset(path, f"not a GLB file: it starts with {bytes(data[:4])!r}, "
                                       f"not b'glTF' ({_kind_of(data)})")
        else:
            text, self.glb_bin = data, None
        try:
            self.doc = json.loads(bytes(text))
        except UnicodeDecodeError:
            raise MalformedAsset(path, "glTF JSON is not UTF-8 text: "
                                       f"{_kind_of(bytes(text))}") from None
        except (ValueError, RecursionError) as exc:
            raise MalformedAsset(path, f"invalid glTF JSON: {exc}") from None
        if not isinstance(self.doc, dict):
            raise MalformedAsset(path, "glTF JSON is not an object")
        version = str(self.obj(self.doc.get("asset"), "asset").get("version", ""))
        if not version.startswith("2."):
            raise UnsupportedFormat(path, f"glTF version {version or '(missing)'}; only 2.x is read")

    # -- JSON access with errors that name the file -------------------------------------------
    def bad(self, reason: str) -> MalformedAsset:
        """The error to raise for malformed content: it names the file."""
        return MalformedAsset(self.path, reason)

    def obj(self, value, what: str) -> dict:
        """`value` as a JSON object ({} for None)."""
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise self.bad(f"{what} is not a JSON object")
        return value

    def array(self, obj: dict, key: str) -> list:
        """`obj[key]` as a JSON array ([] when absent)."""
        value = obj.get(key, [])
        if not isinstance(value, list):
            raise self.bad(f"{key} is not a JSON array")
        return value

    def item(self, key: str, index, what: str | None = None) -> dict:
        """Entry `index` of the top-level array `key` (nodes, meshes, ...), range-checked."""
        items = self._arrays.get(key)
        if items is None:
            items = self._arrays[key] = self.array(self.doc, key)
        if type(index) is not int or not 0 <= index < len(items):
            raise self.bad(f"{what or key} index {index!r} out of range ({len(items)} {key})")
        entry = items[index]
        return entry if type(entry) is dict else self.obj(entry, f"{key}[{index}]")

    def name(self, key: str, index: int, kind: str) -> str:
        """The name of entry `index` of `key`, else `kind` and the index (`mesh3`)."""
        name = self.array(self.doc, key)[index].get("name")
        return str(name) if name else f"{kind}{index}"

    def integer(self, obj: dict, key: str, default=None, lo: int = 0) -> int:
        value = obj.get(key, default)
        if type(value) is not int or value < lo:
            raise self.bad(f"{key} = {value!r} is not an integer >= {lo}")
        return value

    def numbers(self, obj: dict, key: str, default: tuple) -> tuple:
        """A list of finite numbers as long as `default`."""
        value = obj.get(key, default)
        try:
            out = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise self.bad(f"{key} = {value!r} is not a list of numbers") from None
        if len(out) != len(default) or not all(math.isfinite(v) for v in out):
            raise self.bad(f"{key} = {value!r} must be {len(default)} finite numbers")
        return out

    def number(self, obj: dict, key: str, default: float, lo: float = -math.inf,
               hi: float = math.inf) -> float:
        """A number from the JSON, finite unless its default is infinite, clamped to lo..hi."""
        value = obj.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value) \
                or (math.isinf(value) and not math.isinf(default)):
            raise self.bad(f"{key} = {value!r} is not a finite number")
        return min(max(float(value), lo), hi)

    # -- buffers and accessors ------------------------------------------------------------------
    def account(self, nbytes: int, what: str) -> None:
        """Count `nbytes` of decoded data against the limit."""
        self._unpacked += nbytes
        if self._unpacked > self.limits.max_unpacked_bytes:
            raise LimitExceeded(self.path, f"{what}: decoded data would exceed "
                                           f"{self.limits.max_unpacked_bytes} bytes")

    def payload(self, uri, what: str) -> tuple[bytes, str | None]:
        """Bytes named by a buffer or image URI (a data: URI or a file beside the asset), and
        the file they were read from (None for a data: URI)."""
        if not isinstance(uri, str):
            raise self.bad(f"{what} uri is not a string")
        if uri.startswith("data:"):
            head, sep, body = uri.partition(",")
            if not sep or not head.endswith(";base64"):
                raise self.bad(f"{what} data: URI is not base64")
            if len(body) * 3 // 4 > self.limits.max_file_bytes:
                raise LimitExceeded(self.path, f"{what} data: URI is over "
                                               f"{self.limits.max_file_bytes} bytes")
            try:
                return base64.b64decode(body, validate=True), None
            except (binascii.Error, ValueError) as exc:
                raise self.bad(f"{what} data: URI is not valid base64: {exc}") from None
        target = str(resolve_reference(self.path, uri, root=self.root))
        if target not in self._files_read:  # many buffers may name one file: read it once
            size = os.stat(target).st_size
            if size > self.limits.max_file_bytes:
                raise LimitExceeded(self.path, f"{what} {uri!r} is {size} bytes, over the limit "
                                               f"of {self.limits.max_file_bytes}")
            self.account(size, f"{what} {uri!r}")
            self.files.append(target)
            with open(target, "rb") as f:
                self._files_read[target] = f.read()
        return self._files_read[target], target

    def _buffer(self, index: int) -> bytes | memoryview:
        if index not in self._buffers:
            buf = self.item("buffers", index)
            declared = self.integer(buf, "byteLength", lo=1)
            data: bytes | memoryview
            if "uri" in buf:
                data = self.payload(buf["uri"], f"buffer {index}")[0]
            elif index == 0 and self.glb_bin is not None:
                data = self.glb_bin
            else:
                raise self.bad(f"buffer {index} has no uri and there is no GLB binary chunk")
            if len(data) < declared:
                raise self.bad(f"buffer {index} is truncated: {len(data)} bytes, "
                               f"byteLength says {declared}")
            self._buffers[index] = data
        return self._buffers[index]

    def view(self, index: int) -> tuple[memoryview, int]:
        """A buffer view's bytes and its byteStride (0 when tightly packed); a meshopt-compressed
        view is decoded (once) from the bytes its extension points at."""
        bv = self.item("bufferViews", index)
        ext = self.obj(bv.get("extensions"), f"bufferView {index} extensions")
        meshopt = next((ext[k] for k in MESHOPT_EXTENSIONS if k in ext), None)
        if meshopt is not None:
            if index not in self._decoded_views:
                spec = self.obj(meshopt, f"bufferView {index} meshopt")
                data = self._buffer(self.integer(spec, "buffer"))
                offset, length = self.integer(spec, "byteOffset", 0), self.integer(spec, "byteLength", lo=1)
                if offset + length > len(data):
                    raise self.bad(f"bufferView {index}: meshopt stream (bytes {offset}.."
                                   f"{offset + length}) runs past its {len(data)}-byte buffer")
                self._decoded_views[index] = memoryview(meshopt_view(  # type: ignore[arg-type]  # uint8 ndarray
                    self.path, index, spec, memoryview(data)[offset: offset + length],
                    self.limits, self.account))
            return self._decoded_views[index], self.integer(meshopt, "byteStride", lo=1)
        data = self._buffer(self.integer(bv, "buffer"))
        offset, length = self.integer(bv, "byteOffset", 0), self.integer(bv, "byteLength", lo=1)
        if offset + length > len(data):
            raise self.bad(f"bufferView {index} (bytes {offset}..{offset + length}) runs past "
                           f"the end of its {len(data)}-byte buffer")
        stride = self.integer(bv, "byteStride", 0)
        if stride and not 4 <= stride <= 252:
            raise self.bad(f"bufferView {index} byteStride {stride} outside 4..252")
        return memoryview(data)[offset: offset + length], stride

    def _strided(self, view_index: int, offset: int, count: int, dtype: np.dtype, width: int,
                 what: str) -> np.ndarray:
        data, stride = self.view(view_index)
        elem = dtype.itemsize * width
        stride = stride or elem
        if stride < elem:
            raise self.bad(f"{what}: byteStride {stride} is smaller than one element ({elem})")
        end = offset + stride * (count - 1) + elem
        if end > len(data):
            raise self.bad(f"{what} needs bytes {offset}..{end} of bufferView {view_index}, "
                           f"which holds {len(data)}")
        return np.ndarray((count, width), dtype, buffer=data, offset=offset,
                          strides=(stride, dtype.itemsize))

    def accessor(self, index: int, max_count: int, role: str) -> np.ndarray:
        """Accessor `index` as a (count, width) array; normalized integers become float32."""
        if index in self._accessors:
            return self._accessors[index]
        acc = self.item("accessors", index, role)
        what = f"accessor {index} ({role})"
        ctype = acc.get("componentType")
        if ctype not in COMPONENTS:
            raise self.bad(f"{what} has unknown componentType {ctype!r}")
        if acc.get("type") not in WIDTH:
            raise self.bad(f"{what} has unknown type {acc.get('type')!r}")
        dtype, width = COMPONENTS[ctype], WIDTH[acc["type"]]
        count = self.integer(acc, "count", lo=1)
        if count > max_count:
            raise LimitExceeded(self.path, f"{what} has {count} elements, over the limit of "
                                           f"{max_count}")
        self.account(count * width * 4, what)
        if "bufferView" in acc:
            offset = self.integer(acc, "byteOffset", 0)
            if offset % dtype.itemsize:
                raise self.bad(f"{what} byteOffset {offset} is not aligned to its component")
            arr = self._strided(acc["bufferView"], offset, count, dtype, width, what)
        else:
            arr = np.zeros((count, width), dtype)
        if "sparse" in acc:
            arr = self._apply_sparse(arr, self.obj(acc["sparse"], f"{what} sparse"), what)
        out = self._accessors[index] = as_values(arr, acc)
        return out

    def has_accessor(self, index: int) -> bool:
        """Whether accessor `index` was read (or decoded, see `set_accessor`) already."""
        return index in self._accessors

    def set_accessor(self, index: int, values: np.ndarray) -> None:
        """Give accessor `index` its values from elsewhere (a Draco primitive's accessors have
        no bufferView of their own): `accessor(index, ...)` then returns them."""
        self._accessors[index] = values

    def _apply_sparse(self, arr: np.ndarray, sparse: dict, what: str) -> np.ndarray:
        count = self.integer(sparse, "count", lo=1)
        if count > len(arr):
            raise self.bad(f"{what}: sparse count {count} exceeds the accessor's {len(arr)}")
        ind = self.obj(sparse.get("indices"), f"{what} sparse.indices")
        val = self.obj(sparse.get("values"), f"{what} sparse.values")
        itype = ind.get("componentType")
        if itype not in (5121, 5123, 5125):
            raise self.bad(f"{what}: sparse indices componentType {itype!r} is not unsigned")
        idx = self._strided(self.integer(ind, "bufferView"), self.integer(ind, "byteOffset", 0),
                            count, COMPONENTS[itype], 1, f"{what} sparse indices")[:, 0]
        values = self._strided(self.integer(val, "bufferView"), self.integer(val, "byteOffset", 0),
                               count, arr.dtype, arr.shape[1], f"{what} sparse values")
        if idx.max() >= len(arr):
            raise self.bad(f"{what}: sparse index {int(idx.max())} past the count {len(arr)}")
        arr = np.array(arr)
        arr[idx.astype(np.int64)] = values
        return arr
