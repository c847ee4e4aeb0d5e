"""Writing small glTF files for tests: valid ones to break on purpose, and round trips.

`Builder` collects binary data and JSON the way an exporter does; `write` saves it as .gltf
(external .bin or data: URI) or .glb. Tests then corrupt the JSON or the bytes as they need.
"""
from __future__ import annotations

import base64
import io
import json
import struct
from pathlib import Path

import numpy as np

COMPONENT = {np.dtype("int8"): 5120, np.dtype("uint8"): 5121, np.dtype("int16"): 5122,
             np.dtype("uint16"): 5123, np.dtype("uint32"): 5125, np.dtype("float32"): 5126}
TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}

CUBE_POSITIONS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                          np.float32)
CUBE_INDICES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                        np.uint16)


def png_bytes(pixels: np.ndarray) -> bytes:
    from PIL import Image
    out = io.BytesIO()
    Image.fromarray(np.asarray(pixels, np.uint8)).save(out, "PNG")
    return out.getvalue()


class Builder:
    def __init__(self):
        self.bin = bytearray()
        self.doc: dict = {"asset": {"version": "2.0"}, "buffers": [], "bufferViews": [],
                          "accessors": [], "meshes": [], "nodes": [], "scenes": [{"nodes": []}],
                          "scene": 0}

    def view(self, data: bytes, stride: int | None = None) -> int:
        self.bin += b"\0" * (-len(self.bin) % 4)
        bv = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if stride:
            bv["byteStride"] = stride
        self.bin += data
        self.doc["bufferViews"].append(bv)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array, normalized: bool = False, minmax: bool = False, **extra) -> int:
        a = np.ascontiguousarray(array)
        width = 1 if a.ndim == 1 else a.shape[1]
        acc = {"bufferView": self.view(a.tobytes()), "componentType": COMPONENT[a.dtype],
               "count": len(a), "type": TYPE[width], **extra}
        if normalized:
            acc["normalized"] = True
        if minmax:
            acc["min"] = a.reshape(len(a), -1).min(axis=0).tolist()
            acc["max"] = a.reshape(len(a), -1).max(axis=0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, positions, indices=None, material: int | None = None, mode: int | None = None,
             **attributes) -> int:
        attrs = {"POSITION": self.accessor(np.asarray(positions), minmax=True)}
        for name, value in attributes.items():
            attrs[name] = value if isinstance(value, int) else self.accessor(np.asarray(value))
        prim: dict = {"attributes": attrs}
        if indices is not None:
            prim["indices"] = self.accessor(np.asarray(indices).reshape(-1))
        if material is not None:
            prim["material"] = material
        if mode is not None:
            prim["mode"] = mode
        self.doc["meshes"].append({"primitives": [prim]})
        return len(self.doc["meshes"]) - 1

    def node(self, mesh: int | None = None, root: bool = True, **fields) -> int:
        node = dict(fields)
        if mesh is not None:
            node["mesh"] = mesh
        self.doc["nodes"].append(node)
        index = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(index)
        return index

    def image(self, data: bytes, mime: str = "image/png") -> int:
        self.doc.setdefault("images", []).append({"bufferView": self.view(data),
                                                  "mimeType": mime})
        self.doc.setdefault("textures", []).append({"source": len(self.doc["images"]) - 1})
        return len(self.doc["textures"]) - 1

    def material(self, **fields) -> int:
        self.doc.setdefault("materials", []).append(fields)
        return len(self.doc["materials"]) - 1

    def write(self, path: Path, how: str = "glb") -> Path:
        """Save as `glb`, `gltf` (with path.bin beside it) or `data` (.gltf, data: URI)."""
        path = Path(path)
        doc = json.loads(json.dumps(self.doc))
        data = bytes(self.bin)
        if data or doc["buffers"]:
            if not doc["buffers"]:
                doc["buffers"] = [{"byteLength": len(data)}]
            if how == "gltf":
                bin_path = path.with_suffix(".bin")
                bin_path.write_bytes(data)
                doc["buffers"][0].setdefault("uri", bin_path.name)
            elif how == "data":
                doc["buffers"][0].setdefault(
                    "uri", "data:application/octet-stream;base64," + base64.b64encode(data).decode())
        if how == "glb":
            path.write_bytes(glb(doc, data))
        else:
            path.write_text(json.dumps(doc))
        return path


def glb(doc: dict, data: bytes) -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    data = bytes(data) + b"\0" * (-len(data) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if data:
        chunks += struct.pack("<II", len(data), 0x004E4942) + data
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def cube(path: Path, how: str = "glb", **mesh_kwargs) -> Path:
    """A 2 m cube with one default-material primitive, written to `path`."""
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, **mesh_kwargs))
    return b.write(path, how)
