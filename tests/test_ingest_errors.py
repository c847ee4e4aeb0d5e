"""A generated corpus of broken and hostile files: each yields its documented AssetError
subclass (naming the file), within a time bound, and never anything else."""
from __future__ import annotations

import json
import os
import random
import struct
import time
import zlib

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, cube, glb, png_bytes

from core.errors import (
    AssetError,
    EmptyScene,
    IngestTimeout,
    LimitExceeded,
    MalformedAsset,
    MissingFile,
    UnsafeReference,
    UnsupportedFormat,
)
from pipeline.ingest import load_scene
from pipeline.limits import Limits

SECONDS = 10.0  # generous for 2 shared cores; every case here takes milliseconds


def rejected(path, error=AssetError, limits=None):
    """Load `path`, expecting `error`; checks the message names the file and the time taken."""
    start = time.monotonic()
    with pytest.raises(error) as info:
        load_scene(path, limits)
    assert time.monotonic() - start < SECONDS
    assert str(path) in str(info.value) or info.value.path.endswith(path.name)
    return info.value


def loaded(path, limits=None):
    start = time.monotonic()
    scene = load_scene(path, limits)
    assert time.monotonic() - start < SECONDS
    return scene


def edited(tmp_path, edit, name="x.gltf", how="gltf"):
    """A valid cube, its JSON passed through `edit(doc)` before writing."""
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES))
    edit(b.doc)
    return b.write(tmp_path / name, how)


# -- containers and JSON -------------------------------------------------------------------------

@pytest.mark.parametrize("cut", [0.0, 0.01, 0.3, 0.6, 0.95])
def test_truncated_glb(tmp_path, cut):
    data = cube(tmp_path / "full.glb").read_bytes()
    path = tmp_path / "cut.glb"
    path.write_bytes(data[: int(len(data) * cut)])
    rejected(path, MalformedAsset)


def test_flipped_bytes_never_crash(tmp_path):
    """Random byte flips anywhere in a GLB: either it still loads or an AssetError, nothing
    else (no IndexError, no numpy error, no hang)."""
    data = bytearray(cube(tmp_path / "full.glb").read_bytes())
    rng = random.Random(7)
    outcomes = set()
    for i in range(60):
        broken = bytearray(data)
        for _ in range(rng.randint(1, 6)):
            broken[rng.randrange(len(broken))] ^= 1 << rng.randrange(8)
        path = tmp_path / f"flip{i}.glb"
        path.write_bytes(bytes(broken))
        try:
            loaded(path)
            outcomes.add("loaded")
        except AssetError as exc:
            assert exc.path == str(path)
            outcomes.add(type(exc).__name__)
    assert outcomes - {"loaded"}, "no flip was detected at all"


def test_bad_magic_and_version(tmp_path):
    data = bytearray(cube(tmp_path / "ok.glb").read_bytes())
    v1 = tmp_path / "v1.glb"
    v1.write_bytes(data[:4] + struct.pack("<I", 1) + data[8:])
    rejected(v1, UnsupportedFormat)
    junk = tmp_path / "junk.glb"
    junk.write_bytes(b"not a glb file at all, just text")
    rejected(junk, MalformedAsset)


def _unaligned_glb(path, padded: bool):
    """The cube as a GLB whose JSON chunk length is not a multiple of 4: the JSON unpadded
    (and the BIN header right after it), or padded with spaces the length leaves out."""
    ok = cube(path.with_name("ok.glb")).read_bytes()
    json_len = struct.unpack_from("<I", ok, 12)[0]
    text = ok[20:20 + json_len].rstrip(b" ")
    assert len(text) % 4, "the cube's JSON happens to be aligned: pad it to make it not"
    rest = ok[20 + json_len:]
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    body += b" " * (-len(text) % 4) if padded else b""
    body += rest
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return path


@pytest.mark.parametrize("padded", [False, True])
def test_unaligned_chunk_length_is_a_warning(tmp_path, padded):
    # glTF-Validator reads these with one GLB_CHUNK_LENGTH_UNALIGNED issue; so do we
    scene = loaded(_unaligned_glb(tmp_path / "unaligned.glb", padded))
    assert scene.triangle_count == 12
    assert any("not a multiple of 4" in w and "JSON" in w for w in scene.warnings)
    # the bytes not all there: still refused, naming the file
    cut = tmp_path / "cut.glb"
    data = (tmp_path / "unaligned.glb").read_bytes()[:-40]
    cut.write_bytes(data[:8] + struct.pack("<I", len(data)) + data[12:])
    rejected(cut, MalformedAsset)


def test_binary_garbage_is_called_binary(tmp_path):
    junk = tmp_path / "garbage.glb"
    junk.write_bytes(np.random.default_rng(3).bytes(4096))
    err = rejected(junk, MalformedAsset)
    assert "binary" in err.reason and "codec" not in err.reason
    text = tmp_path / "text.glb"
    text.write_bytes(b'{"asset": {"version": "2.0"}}')
    err = rejected(text, MalformedAsset)
    assert "not a GLB file" in err.reason and "text" in err.reason
    gltf = tmp_path / "garbage.gltf"
    gltf.write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR" + bytes(range(256)))
    err = rejected(gltf, MalformedAsset)
    assert "binary" in err.reason and "codec" not in err.reason


@pytest.mark.parametrize("text", ['{"asset": {"version": "2.0"', "[1, 2, 3]", "\xff\xfe",
                                  '{"asset": {"version": "1.0"}}', "[" * 100000 + "]" * 100000])
def test_invalid_json(tmp_path, text):
    path = tmp_path / "bad.gltf"
    path.write_text(text, encoding="utf-8", errors="surrogateescape")
    rejected(path, (MalformedAsset, UnsupportedFormat))


def test_unknown_required_extension(tmp_path):
    path = edited(tmp_path, lambda d: d.update(extensionsRequired=["EXT_unknown_compression"]))
    err = rejected(path, UnsupportedFormat)
    assert "EXT_unknown_compression" in err.reason
    # merely used (with a fallback), an unknown extension is fine
    ok = edited(tmp_path, lambda d: d.update(extensionsUsed=["EXT_unknown"]), "ok.gltf")
    assert loaded(ok).triangle_count == 12


# -- accessors and buffers -----------------------------------------------------------------------

@pytest.mark.parametrize("edit,error", [
    (lambda d: d["accessors"][0].update(count=9), MalformedAsset),            # past its view
    (lambda d: d["accessors"][0].update(byteOffset=64), MalformedAsset),
    (lambda d: d["bufferViews"][0].update(byteLength=10**6), MalformedAsset),  # past the buffer
    (lambda d: d["bufferViews"][0].update(buffer=5), MalformedAsset),
    (lambda d: d["meshes"][0]["primitives"][0].update(indices=99), MalformedAsset),
    (lambda d: d["accessors"][0].update(componentType=1234), MalformedAsset),
    (lambda d: d["accessors"][1].update(count=-1), MalformedAsset),
    (lambda d: d["accessors"][0].update(count=10**12), LimitExceeded),        # huge counts
    (lambda d: d["accessors"][1].update(count=2**31), LimitExceeded),
    (lambda d: d["nodes"][0].update(mesh=7), MalformedAsset),
    (lambda d: d.update(scene=3), MalformedAsset),
    (lambda d: d["nodes"][0].update(children=[0]), MalformedAsset),           # a cycle
    (lambda d: d["nodes"][0].update(matrix=[1] * 15), MalformedAsset),
    (lambda d: d["nodes"][0].update(rotation=[0, 0, 0, 0]), MalformedAsset),
    (lambda d: d["bufferViews"][0].update(byteStride=3), MalformedAsset),
    (lambda d: d["buffers"][0].update(byteLength=10**9), MalformedAsset),     # declared > data
], ids=["accessor-past-view", "accessor-offset", "view-past-buffer", "no-such-buffer",
        "no-such-accessor", "component-type", "negative-count", "huge-count", "huge-index-count",
        "no-such-mesh", "no-such-scene", "node-cycle", "bad-matrix", "zero-quaternion",
        "bad-stride", "buffer-short"])
def test_accessor_and_graph_errors(tmp_path, edit, error):
    path = edited(tmp_path, lambda d: None, "x.glb", "glb")
    doc, data = _split(path.read_bytes())
    edit(doc)
    path.write_bytes(glb(doc, data))
    rejected(path, error)


def _split(data: bytes) -> tuple[dict, bytes]:
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20: 20 + n]), data[28 + n:]


def test_index_past_vertex_count(tmp_path):
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, np.array([0, 1, 8], np.uint16)))
    err = rejected(b.write(tmp_path / "i.glb"), MalformedAsset)
    assert "past the vertex count" in err.reason


def test_sparse_index_out_of_range(tmp_path):
    b = Builder()
    idx = b.view(np.array([40], np.uint16).tobytes())
    val = b.view(np.zeros(3, np.float32).tobytes())
    b.doc["accessors"].append({"componentType": 5126, "count": 3, "type": "VEC3", "sparse": {
        "count": 1, "indices": {"bufferView": idx, "componentType": 5123},
        "values": {"bufferView": val}}})
    b.doc["meshes"].append({"primitives": [{"attributes": {"POSITION": 0}}]})
    b.node(0)
    rejected(b.write(tmp_path / "s.glb"), MalformedAsset)


def test_total_size_limit_checked_before_allocating(tmp_path):
    path = cube(tmp_path / "c.glb")
    rejected(path, LimitExceeded, Limits(max_vertices=4))
    rejected(path, LimitExceeded, Limits(max_file_bytes=100))


# -- references --------------------------------------------------------------------------------

@pytest.mark.parametrize("uri,error", [
    ("http://example.com/c.bin", UnsafeReference),
    ("https://example.com/c.bin", UnsafeReference),
    ("ftp://example.com/c.bin", UnsafeReference),
    ("file:///etc/passwd", UnsafeReference),
    ("/etc/passwd", UnsafeReference),
    ("../outside.bin", UnsafeReference),
    ("sub/../../outside.bin", UnsafeReference),
    ("%2e%2e/outside.bin", UnsafeReference),
    ("missing.bin", MissingFile),
    ("data:application/octet-stream;base64,@@@", MalformedAsset),
])
def test_hostile_buffer_uris(tmp_path, uri, error):
    (tmp_path / "outside.bin").write_bytes(b"\0" * 4096)
    folder = tmp_path / "asset"
    folder.mkdir()
    path = edited(folder, lambda d: d.update(buffers=[{"uri": uri, "byteLength": 168}]))
    err = rejected(path, error)
    assert uri.split("/")[0] in str(err) or error is MalformedAsset


def test_symlink_out_is_refused(tmp_path):
    folder = tmp_path / "asset"
    folder.mkdir()
    path = cube(folder / "c.gltf", "gltf")
    outside = tmp_path / "secret.bin"
    os.replace(folder / "c.bin", outside)
    (folder / "c.bin").symlink_to(outside)
    rejected(path, UnsafeReference)
    # a link that stays inside the folder is fine
    os.replace(outside, folder / "real.bin")
    (folder / "c.bin").unlink()
    (folder / "c.bin").symlink_to("real.bin")
    assert loaded(path).triangle_count == 12


def test_http_image_is_refused(tmp_path):
    def edit(doc):
        doc["images"] = [{"uri": "https://example.com/t.png"}]
        doc["textures"] = [{"source": 0}]
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
    rejected(edited(tmp_path, edit), UnsafeReference)


# -- geometry ----------------------------------------------------------------------------------

def test_nan_positions(tmp_path):
    p = CUBE_POSITIONS.copy()
    p[3, 1] = np.nan
    b = Builder()
    b.node(b.mesh(p, CUBE_INDICES))
    rejected(b.write(tmp_path / "n.glb"), MalformedAsset)
    p[3, 1] = np.inf
    b = Builder()
    b.node(b.mesh(p, CUBE_INDICES))
    rejected(b.write(tmp_path / "i.glb"), MalformedAsset)


def test_degenerate_triangles_dropped_with_a_count(tmp_path):
    extra = np.array([[0, 0, 1], [2, 2, 2], [0, 1, 2]], np.uint16)  # repeated, repeated, collinear
    line = np.vstack([CUBE_POSITIONS, [[0, 0, 0], [1, 0, 0], [2, 0, 0]]]).astype(np.float32)
    extra[2] += 8
    b = Builder()
    b.node(b.mesh(line, np.vstack([CUBE_INDICES, extra])))
    scene = loaded(b.write(tmp_path / "d.glb"))
    assert scene.triangle_count == 12
    assert "dropped 3 degenerate triangles" in scene.warnings


def test_tiny_triangles_get_finite_normals(tmp_path):
    """A valid but tiny mesh without normals: its flat normals must not underflow to NaN."""
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS * np.float32(1e-12), CUBE_INDICES))
    scene = loaded(b.write(tmp_path / "tiny.glb"))
    normals = scene.meshes[0].normals
    assert np.isfinite(normals).all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-5)


@pytest.mark.parametrize("edit", [
    lambda d: d.update(scenes=[{"nodes": []}]),
    lambda d: d["nodes"][0].pop("mesh"),
    lambda d: d["meshes"][0]["primitives"][0]["attributes"].pop("POSITION"),
], ids=["no-nodes", "no-mesh", "no-position"])
def test_empty_scene(tmp_path, edit):
    rejected(edited(tmp_path, edit), EmptyScene)


def test_all_degenerate_is_empty(tmp_path):
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, np.zeros(6, np.uint16)))
    rejected(b.write(tmp_path / "z.glb"), EmptyScene)


# -- images: a broken one is a warning, the material keeps its factor -------------------------

def _bomb_png(width: int, height: int) -> bytes:
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) \
        + chunk(b"IEND", b"")


@pytest.mark.parametrize("image", [b"this is not an image", png_bytes(np.zeros((8, 8, 4)))[:60],
                                   _bomb_png(100_000, 100_000)],
                         ids=["garbage", "truncated-png", "decompression-bomb"])
def test_undecodable_image_is_a_warning(tmp_path, image):
    b = Builder()
    tex = b.image(image)
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": {"index": tex},
                                           "baseColorFactor": [0.2, 0.4, 0.6, 1.0]})
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=mat))
    scene = loaded(b.write(tmp_path / "img.glb"))
    assert scene.textures == [] and scene.materials[0].base_color_texture is None
    assert scene.materials[0].base_color == (0.2, 0.4, 0.6, 1.0)
    assert any("image 0" in w for w in scene.warnings)


def test_missing_image_file_is_a_warning(tmp_path):
    """A missing texture drops the texture, not the asset: the material keeps its factors
    (missing geometry buffers stay a refusal: test_hostile_buffer_uris)."""
    def edit(doc):
        doc["images"] = [{"uri": "textures/none.png"}]
        doc["textures"] = [{"source": 0}]
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                      "baseColorFactor": [0.2, 0.4, 0.6, 1]}}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
    scene = loaded(edited(tmp_path, edit))
    assert scene.textures == [] and scene.materials[0].base_color_texture is None
    assert scene.materials[0].base_color == (0.2, 0.4, 0.6, 1.0)
    assert any("image 0" in w and "not found" in w for w in scene.warnings)
    # an image URI that leaves the folder is still refused, not skipped
    rejected(edited(tmp_path, lambda d: (edit(d), d["images"][0].update(uri="../x.png")),
                    "out.gltf"), UnsafeReference)


# -- files in general, plain meshes, the time bound ----------------------------------------------

def test_file_level_errors(tmp_path):
    rejected(tmp_path / "absent.glb", MissingFile)
    (tmp_path / "model.fbx").write_bytes(b"Kaydara FBX Binary")
    rejected(tmp_path / "model.fbx", UnsupportedFormat)
    (tmp_path / "empty.glb").write_bytes(b"")
    rejected(tmp_path / "empty.glb", MalformedAsset)


@pytest.mark.parametrize("name,data", [
    ("garbage.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999\n"
                    b"property float x\nend_header\n\x00\x01"),
    ("garbage.stl", b"\x00" * 80 + struct.pack("<I", 10**8) + b"\x00" * 50),
    ("garbage.obj", b"v 1 2\nf 1 2 3 4\nvt\n"),
])
def test_broken_plain_meshes(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    rejected(path, (MalformedAsset, EmptyScene, LimitExceeded))


def test_ingest_time_bound(assets):
    path = assets / "gltf" / "CesiumMilkTruck.glb"
    err = rejected(path, IngestTimeout, Limits(ingest_seconds=0.0))
    assert "time bound" in err.reason


def test_obj_references_are_not_followed(tmp_path):
    """trimesh gets the OBJ's bytes, not its path: an `mtllib ../` escape is never read."""
    (tmp_path / "secret.mtl").write_text("newmtl x\nKd 1 0 0\nmap_Kd secret.png\n")
    folder = tmp_path / "asset"
    folder.mkdir()
    path = folder / "m.obj"
    path.write_text("mtllib ../secret.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                    "usemtl x\nf 1/1 2/2 3/3\n")
    scene = loaded(path)
    assert scene.files == [str(path.resolve())]
    assert [m.name for m in scene.materials] == ["default"] and scene.textures == []
    # OBJ's v=0 is the image bottom; the scene holds glTF's convention (v=0 at the top)
    np.testing.assert_allclose(scene.meshes[0].uv0[:, 1], [1, 1, 0])
