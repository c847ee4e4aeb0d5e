"""pipeline.gltf.accessors: the GLB container, checked JSON access and accessors, on files
written by tests/gltf_builder.py."""
from __future__ import annotations

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, cube

from core.errors import LimitExceeded, MalformedAsset, UnsupportedFormat
from pipeline.gltf.accessors import Document, split_glb
from pipeline.limits import Limits


def test_split_glb_returns_json_and_bin_chunks(tmp_path):
    path = cube(tmp_path / "c.glb")
    text, binary = split_glb(path, path.read_bytes())
    assert bytes(text).lstrip().startswith(b"{")
    assert binary is not None and len(binary) >= CUBE_POSITIONS.nbytes + CUBE_INDICES.nbytes
    with pytest.raises(MalformedAsset, match="truncated") as err:
        split_glb(path, path.read_bytes()[:-8])
    assert err.value.path == str(path) or str(path) in str(err.value)


@pytest.mark.parametrize("how", ["glb", "gltf", "data"])
def test_accessors_read_back_what_was_written(tmp_path, how):
    d = Document(cube(tmp_path / f"c.{'glb' if how == 'glb' else 'gltf'}", how), Limits())
    prim = d.item("meshes", 0)["primitives"][0]
    positions = d.accessor(prim["attributes"]["POSITION"], 100, "POSITION")
    assert positions.dtype == np.float32 and np.array_equal(positions, CUBE_POSITIONS)
    indices = d.accessor(prim["indices"], 100, "indices")
    assert np.array_equal(indices[:, 0], CUBE_INDICES.reshape(-1))
    assert d.files == ([str(tmp_path / "c.bin")] if how == "gltf" else [])


def test_normalized_strided_and_sparse(tmp_path):
    b = Builder()
    rows = np.array([[0, 255], [128, 64], [255, 0]], np.uint8)
    normalized = b.accessor(rows, normalized=True)
    # Two float VEC2s interleaved in one 16-byte stride: the second is at byte 8.
    pairs = np.arange(12, dtype=np.float32).reshape(3, 4)
    view = b.view(pairs.tobytes(), stride=16)
    b.doc["accessors"].append({"bufferView": view, "byteOffset": 8, "componentType": 5126,
                               "count": 3, "type": "VEC2"})
    strided = len(b.doc["accessors"]) - 1
    idx, val = b.view(np.array([1], np.uint16).tobytes()), b.view(np.float32([9, 9]).tobytes())
    b.doc["accessors"].append({"componentType": 5126, "count": 3, "type": "VEC2", "sparse": {
        "count": 1, "indices": {"bufferView": idx, "componentType": 5123},
        "values": {"bufferView": val}}})
    sparse = len(b.doc["accessors"]) - 1
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES))
    d = Document(b.write(tmp_path / "a.glb"), Limits())
    assert np.allclose(d.accessor(normalized, 10, "n"), rows / 255.0)
    assert np.array_equal(d.accessor(strided, 10, "s"), pairs[:, 2:])
    assert np.array_equal(d.accessor(sparse, 10, "sp"), [[0, 0], [9, 9], [0, 0]])


def test_checked_access_names_the_file_and_reason(tmp_path):
    path = cube(tmp_path / "c.glb")
    d = Document(path, Limits())
    with pytest.raises(MalformedAsset, match=r"nodes index 7 out of range \(1 nodes\)") as err:
        d.item("nodes", 7)
    assert str(path) in str(err.value)
    with pytest.raises(MalformedAsset, match="is not a finite number"):
        d.number({"x": float("nan")}, "x", 1.0)
    assert d.number({"x": 5.0}, "x", 1.0, 0.0, 1.0) == 1.0  # clamped
    with pytest.raises(MalformedAsset, match="must be 3 finite numbers"):
        d.numbers({"t": [1, 2]}, "t", (0.0, 0.0, 0.0))
    with pytest.raises(MalformedAsset, match="is not an integer >= 1"):
        d.integer({"count": 0}, "count", lo=1)
    with pytest.raises(MalformedAsset, match="is not a JSON object"):
        d.obj([1], "extensions")


def test_limits_are_checked_before_allocating(tmp_path):
    path = cube(tmp_path / "c.glb")
    d = Document(path, Limits(max_unpacked_bytes=50))
    prim = d.item("meshes", 0)["primitives"][0]
    with pytest.raises(LimitExceeded, match="decoded data would exceed 50 bytes"):
        d.accessor(prim["attributes"]["POSITION"], 100, "POSITION")
    with pytest.raises(LimitExceeded, match="over the limit of 4"):
        Document(path, Limits()).accessor(prim["attributes"]["POSITION"], 4, "POSITION")


def test_set_accessor_supplies_values_without_a_buffer_view(tmp_path):
    d = Document(cube(tmp_path / "c.glb"), Limits())
    assert not d.has_accessor(0)
    values = np.ones((8, 3), np.float32)
    d.set_accessor(0, values)
    assert d.has_accessor(0) and d.accessor(0, 1, "POSITION") is values


def test_version_is_checked_at_open(tmp_path):
    b = Builder()
    b.doc["asset"]["version"] = "1.0"
    with pytest.raises(UnsupportedFormat, match="only 2.x is read"):
        Document(b.write(tmp_path / "old.gltf", "data"), Limits())
