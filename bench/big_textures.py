"""A StainedGlassLamp-class asset for the benchmarks: the Duck's geometry with 8192^2 textures.

None of the shared samples carries 8k textures, so the bench builds one: the Duck's mesh and UVs
with a base colour (the Duck's own texture upscaled, plus detail at every scale down to single
texels), a metallic-roughness map and a normal map, each an 8192^2 PNG inside one .glb. Built
once per size and kept under the system temp folder (encoding 8k PNGs takes a while).
"""
from __future__ import annotations

import io
import json
import struct
import tempfile
from pathlib import Path

import numpy as np

NAME = "BigTextures8k"


def build(assets: Path, size: int = 8192) -> Path:
    """Path of the generated .glb (built on first call)."""
    out = Path(tempfile.gettempdir()) / "asset-preview-bench" / f"DuckTextures{size}.glb"
    if out.exists():
        return out
    from pipeline.ingest import load_scene
    scene = load_scene(assets / "gltf" / "Duck.glb")
    mesh = scene.meshes[0]
    world = scene.instances[0].matrix
    base = _base_color(scene.textures[0].image, size)
    height = _smooth_noise(size, 64, seed=2)
    images = [_png(base), _png(_metal_rough(height)), _png(_normals(height))]
    pos = (np.c_[mesh.positions, np.ones(len(mesh.positions))] @ np.asarray(world).T)[:, :3]
    nrm = mesh.normals @ np.linalg.inv(np.asarray(world)[:3, :3])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    assert mesh.uv0 is not None  # the Duck is textured
    arrays = [pos.astype(np.float32), nrm.astype(np.float32), mesh.uv0.astype(np.float32),
              mesh.indices.astype(np.uint32).ravel()]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_bytes(_glb(arrays, images))
    tmp.rename(out)
    return out


def _base_color(duck: np.ndarray, size: int) -> np.ndarray:
    from PIL import Image
    img = np.asarray(Image.fromarray(duck[..., :3]).resize((size, size), Image.Resampling.BICUBIC), np.float32)
    # detail the full resolution shows and a capped bake must average: a fine weave plus noise
    y, x = np.mgrid[:size, :size].astype(np.float32)
    weave = 10 * np.sin(x * 0.9) * np.sin(y * 0.7)
    img += (weave + 14 * _smooth_noise(size, 512, seed=1))[..., None]
    out = np.full((size, size, 4), 255, np.uint8)
    out[..., :3] = np.clip(img, 0, 255)
    return out


def _smooth_noise(size: int, cells: int, seed: int) -> np.ndarray:
    """Noise in [-1, 1] with `cells` features across, bicubically upsampled."""
    from PIL import Image
    g = np.random.default_rng(seed).random((cells, cells), np.float32)
    return np.asarray(Image.fromarray(g).resize((size, size), Image.Resampling.BICUBIC), np.float32) * 2 - 1


def _metal_rough(height: np.ndarray) -> np.ndarray:
    out = np.zeros(height.shape + (4,), np.uint8)
    out[..., 1] = np.clip(140 + 90 * height, 0, 255)   # roughness
    out[..., 2] = np.where(height > 0.6, 255, 0)       # metallic specks
    out[..., 3] = 255
    return out


def _normals(height: np.ndarray) -> np.ndarray:
    gy, gx = np.gradient(height * 40)
    n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    out = np.full(height.shape + (4,), 255, np.uint8)
    out[..., :3] = np.clip((n * 0.5 + 0.5) * 255 + 0.5, 0, 255)
    return out


def _png(rgba: np.ndarray) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(rgba[..., :3] if rgba[..., 3].min() == 255 else rgba).save(buf, "PNG", compress_level=6)
    return buf.getvalue()


def _glb(arrays: list[np.ndarray], images: list[bytes]) -> bytes:
    blobs = [a.tobytes() for a in arrays] + images
    views, offset, data = [], 0, b""
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(b)})
        pad = b + b"\0" * (-len(b) % 4)
        data += pad
        offset += len(pad)
    pos = arrays[0]
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
         "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
        {"bufferView": 1, "componentType": 5126, "count": len(pos), "type": "VEC3"},
        {"bufferView": 2, "componentType": 5126, "count": len(pos), "type": "VEC2"},
        {"bufferView": 3, "componentType": 5125, "count": len(arrays[3]), "type": "SCALAR"},
    ]
    doc = {
        "asset": {"version": "2.0", "generator": "asset-preview bench.big_textures"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                                    "indices": 3, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                "metallicRoughnessTexture": {"index": 1}},
                       "normalTexture": {"index": 2}}],
        "textures": [{"source": i} for i in range(3)],
        "images": [{"bufferView": 4 + i, "mimeType": "image/png"} for i in range(3)],
        "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(data)}],
    }
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(data), b"BIN\0") + data
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks
