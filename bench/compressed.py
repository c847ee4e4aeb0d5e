"""Compressed glTF files made from an uncompressed sample with the field's own encoders, for
the ingest bench and the round-trip tests: meshopt (the `meshopt` wheel's encode_gltf_buffer,
normals through its OCTAHEDRAL filter) and KTX2 / Basis Universal textures (`alktx2`, a
basisu build). The input is a .gltf with one external buffer, as the shared samples' glTF/.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Literal

import numpy as np

WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
DTYPE = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}


def _read(path: Path) -> tuple[dict, bytes]:
    doc = json.loads(path.read_text())
    return doc, (path.parent / doc["buffers"][0]["uri"]).read_bytes()


def _copy_images(doc: dict, src: Path, out_dir: Path) -> None:
    for img in doc.get("images", []):
        if "uri" in img and not img["uri"].startswith("data:"):
            (out_dir / img["uri"]).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src.parent / img["uri"], out_dir / img["uri"])


def meshopt_variant(src: Path, out_dir: Path, extension: str = "EXT_meshopt_compression",
                    octahedral: bool = True) -> Path:
    """`src` with every accessor's data meshopt-compressed (one bufferView each; indices as
    TRIANGLES, normals OCTAHEDRAL-filtered to 8 bits when `octahedral`), the original buffer
    kept only as the extension's fallback (no bytes)."""
    import meshopt

    doc, data = _read(src)
    normals = {p["attributes"].get("NORMAL") for m in doc["meshes"] for p in m["primitives"]}
    packed, views = bytearray(), []
    for i, acc in enumerate(doc["accessors"]):
        bv = doc["bufferViews"][acc["bufferView"]]
        width, dtype = WIDTH[acc["type"]], DTYPE[acc["componentType"]]
        elem = np.dtype(dtype).itemsize * width
        stride = bv.get("byteStride", elem)
        raw = np.frombuffer(data, np.uint8, acc["count"] * stride - (stride - elem),
                            bv.get("byteOffset", 0) + acc.get("byteOffset", 0))
        rows = np.lib.stride_tricks.as_strided(raw, (acc["count"], elem), (stride, 1)).copy()
        values = rows.view(dtype).reshape(acc["count"], width)
        spec: dict = {"count": acc["count"]}
        if width == 1:  # indices
            stream = meshopt.encode_gltf_buffer(values.astype(np.uint32).reshape(-1), "TRIANGLES")
            spec.update(mode="TRIANGLES", byteStride=elem)
        elif i in normals and octahedral:
            four = np.concatenate([values, np.zeros((len(values), 1), np.float32)], axis=1)
            stream = meshopt.encode_gltf_buffer(meshopt.encode_filter_oct(four, 4, 8), "ATTRIBUTES")
            spec.update(mode="ATTRIBUTES", byteStride=4, filter="OCTAHEDRAL")
            acc.update(componentType=5120, normalized=True)
            acc.pop("min", None), acc.pop("max", None)
        else:
            stream = meshopt.encode_gltf_buffer(values, "ATTRIBUTES")
            spec.update(mode="ATTRIBUTES", byteStride=elem)
        packed += b"\0" * (-len(packed) % 4)
        spec.update(buffer=1, byteOffset=len(packed), byteLength=len(stream))
        packed += stream
        view = {"buffer": 0, "byteLength": spec["count"] * spec["byteStride"],
                "extensions": {extension: spec}}
        if width > 1:
            view["byteStride"] = spec["byteStride"]
        views.append(view)
        acc.update(bufferView=len(views) - 1, byteOffset=0)
    doc["bufferViews"] = views
    doc["buffers"] = [{"byteLength": len(data), "extensions": {extension: {"fallback": True}}},
                      {"byteLength": len(packed), "uri": src.stem + ".meshopt.bin"}]
    doc["extensionsUsed"] = sorted({*doc.get("extensionsUsed", []), extension})
    doc["extensionsRequired"] = sorted({*doc.get("extensionsRequired", []), extension})
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / (src.stem + ".meshopt.bin")).write_bytes(bytes(packed))
    _copy_images(doc, src, out_dir)
    out = out_dir / f"{src.stem}-meshopt.gltf"
    out.write_text(json.dumps(doc))
    return out


def ktx2_variant(src: Path, out_dir: Path, codec: Literal["etc1s", "uastc"] = "uastc") -> Path:
    """`src` with every image re-encoded as KTX2 (Basis Universal `codec`), referenced through
    KHR_texture_basisu with no fallback (so the extension is required)."""
    import alktx2

    doc = json.loads(src.read_text())
    out_dir.mkdir(parents=True, exist_ok=True)
    for f in src.parent.iterdir():
        if f.is_file():
            shutil.copy(f, out_dir / f.name)
    for i, img in enumerate(doc.get("images", [])):
        data = (src.parent / img["uri"]).read_bytes()
        mime = "png" if data[:4] == b"\x89PNG" else "jpg"
        name = f"{Path(img['uri']).stem}-{i}.ktx2"
        (out_dir / name).write_bytes(alktx2.encode_bytes_to_ktx2(data, mime=mime, codec=codec,
                                                                 quality=80))
        doc["images"][i] = {"uri": name, "mimeType": "image/ktx2"}
    for t in doc.get("textures", []):
        t["extensions"] = {"KHR_texture_basisu": {"source": t.pop("source")}}
    doc["extensionsUsed"] = sorted({*doc.get("extensionsUsed", []), "KHR_texture_basisu"})
    doc["extensionsRequired"] = sorted({*doc.get("extensionsRequired", []), "KHR_texture_basisu"})
    out = out_dir / f"{src.stem}-ktx2.gltf"
    out.write_text(json.dumps(doc))
    return out
