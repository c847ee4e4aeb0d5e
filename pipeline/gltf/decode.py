"""Compressed glTF payloads, decoded with the field's own decoders.

- KHR_draco_mesh_compression: a primitive's attributes and indices from one Draco stream
  (DracoPy, Google's decoder).
- EXT_meshopt_compression / KHR_meshopt_compression: a bufferView's bytes from a meshopt stream
  (meshopt's `decode_gltf_buffer`, with its OCTAHEDRAL / QUATERNION / EXPONENTIAL / COLOR filters).
- KHR_texture_basisu: KTX2 images are read in pipeline.images (opengl_basisu).

Sizes the file declares are checked against the limits before a decoder allocates anything,
and every decoder failure becomes a MalformedAsset naming the file and the buffer view.
"""
from __future__ import annotations

import numpy as np

from core.errors import LimitExceeded, MalformedAsset
from pipeline.limits import Limits

MESHOPT_EXTENSIONS = ("EXT_meshopt_compression", "KHR_meshopt_compression")
MESHOPT_MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
MESHOPT_FILTERS = ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL", "COLOR")
# A meshopt stream cannot expand beyond this ratio in practice (the ATTRIBUTES codec stores at
# least one bit per byte plus headers, the index codecs at least a byte a triangle); a larger
# declared size is a decompression bomb, refused before the decoder allocates it.
MESHOPT_MAX_RATIO = 512
DRACO_MAX_RATIO = 4096


def meshopt_view(path, index: int, spec: dict, source: memoryview | bytes, limits: Limits,
                 account) -> np.ndarray:
    """The decoded bytes (uint8, count*byteStride) of bufferView `index` whose meshopt
    extension is `spec`, from the compressed `source` bytes it points at."""
    import meshopt  # only meshopt-compressed files need it

    what = f"bufferView {index} ({'/'.join(MESHOPT_EXTENSIONS[:1])})"
    count, stride = spec.get("count"), spec.get("byteStride")
    mode, filt = spec.get("mode"), spec.get("filter", "NONE")
    if type(count) is not int or count < 1 or type(stride) is not int or stride < 1:
        raise MalformedAsset(path, f"{what}: count {count!r} / byteStride {stride!r} are not "
                                   "positive integers")
    if mode not in MESHOPT_MODES or filt not in MESHOPT_FILTERS:
        raise MalformedAsset(path, f"{what}: unknown mode {mode!r} or filter {filt!r}")
    if mode == "ATTRIBUTES" and (stride % 4 or stride > 256):
        raise MalformedAsset(path, f"{what}: ATTRIBUTES byteStride {stride} is not 4..256 in fours")
    if mode != "ATTRIBUTES" and stride not in (2, 4):
        raise MalformedAsset(path, f"{what}: {mode} byteStride {stride} is not 2 or 4")
    if mode == "TRIANGLES" and count % 3:
        raise MalformedAsset(path, f"{what}: TRIANGLES count {count} is not a multiple of 3")
    size = count * stride
    if size > limits.max_file_bytes:
        raise LimitExceeded(path, f"{what} declares {size} decoded bytes, over the limit of "
                                  f"{limits.max_file_bytes}")
    if size > MESHOPT_MAX_RATIO * max(len(source), 1):
        raise LimitExceeded(path, f"{what} declares {size} decoded bytes from {len(source)} "
                                  f"compressed: more than {MESHOPT_MAX_RATIO}x (a decompression bomb?)")
    account(size, what)
    try:
        out = meshopt.decode_gltf_buffer(bytes(source), count, stride, mode,
                                         None if filt == "NONE" else filt)
    except (ValueError, RuntimeError) as exc:
        raise MalformedAsset(path, f"{what}: meshopt stream does not decode: {exc}") from None
    return np.ascontiguousarray(out).view(np.uint8).reshape(-1)


def draco_primitive(path, what: str, data: memoryview | bytes, attribute_ids: dict,
                    expected: dict[str, tuple[int, np.dtype, int]], limits: Limits,
                    account) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Decode one KHR_draco_mesh_compression stream.

    `attribute_ids` maps glTF attribute names to Draco unique ids (the extension's
    `attributes`); `expected` gives, per attribute and for "indices", the accessor's
    (count, component dtype, width). Returns ({name: (count, width) array}, flat indices),
    each checked against its accessor."""
    import DracoPy  # heavy, and only Draco-compressed files need it

    total = sum(c * np.dtype(d).itemsize * w for c, d, w in expected.values())
    if total > DRACO_MAX_RATIO * max(len(data), 1):
        raise LimitExceeded(path, f"{what}: accessors declare {total} bytes from a {len(data)}-byte "
                                  f"Draco stream: more than {DRACO_MAX_RATIO}x (a decompression bomb?)")
    account(total, what)
    try:
        mesh = DracoPy.decode(bytes(data))
    except Exception as exc:  # DracoPy raises bare Exceptions and its own types for bad input
        raise MalformedAsset(path, f"{what}: Draco stream does not decode: {exc}") from None
    if not hasattr(mesh, "faces"):
        raise MalformedAsset(path, f"{what}: Draco stream holds a point cloud, not a mesh")
    by_id = {a["unique_id"]: a for a in mesh.attributes}
    out = {}
    for name, uid in attribute_ids.items():
        if name not in expected:
            continue  # an attribute the primitive does not list: the spec says to ignore it
        if uid not in by_id:
            raise MalformedAsset(path, f"{what}: Draco stream has no attribute id {uid!r} ({name})")
        count, dtype, width = expected[name]
        arr = np.asarray(by_id[uid]["data"])
        arr = arr.reshape(len(arr), -1) if arr.ndim != 2 else arr
        if arr.shape != (count, width):
            raise MalformedAsset(path, f"{what}: Draco {name} is {arr.shape[0]} x {arr.shape[1]}, "
                                       f"its accessor says {count} x {width}")
        out[name] = arr.astype(dtype, copy=False)
    faces = np.asarray(mesh.faces).reshape(-1)
    if "indices" in expected and len(faces) != expected["indices"][0]:
        raise MalformedAsset(path, f"{what}: Draco stream has {len(faces)} indices, the accessor "
                                   f"says {expected['indices'][0]}")
    n = len(np.asarray(mesh.points))
    if len(faces) and int(faces.max()) >= n:
        raise MalformedAsset(path, f"{what}: Draco index {int(faces.max())} past its {n} points")
    return out, faces.astype(np.uint32, copy=False)
