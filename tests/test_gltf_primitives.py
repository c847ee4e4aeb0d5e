"""pipeline.gltf.primitives: modes into triangle lists, attributes checked, points and lines
thickened."""
from __future__ import annotations

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder

from core.errors import MalformedAsset
from core.scene import Instance, Scene
from pipeline.gltf.accessors import Document
from pipeline.gltf.primitives import (
    TRIANGLE_FAN,
    TRIANGLE_STRIP,
    TRIANGLES,
    WIRE_RADIUS,
    primitive,
    thicken,
    triangles,
)
from pipeline.limits import Limits
from pipeline.wire import POINTS


def _normal(p, tri):
    a, b, c = p[tri]
    return np.cross(b - a, c - a)


def test_strip_and_fan_keep_one_winding():
    quad = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    for mode, order in ((TRIANGLE_STRIP, [0, 1, 2, 3]), (TRIANGLE_FAN, [0, 1, 3, 2])):
        tris = triangles(np.array(order, np.uint32), mode)
        assert tris.shape == (2, 3)
        assert all(_normal(quad, t)[2] > 0 for t in tris), (mode, tris)
    assert triangles(np.arange(7, dtype=np.uint32), TRIANGLES).shape == (2, 3)  # the rest dropped
    assert triangles(np.arange(2, dtype=np.uint32), TRIANGLE_STRIP).shape == (0, 3)


def _doc(tmp_path, **mesh) -> tuple[Document, dict]:
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, **mesh))
    d = Document(b.write(tmp_path / "p.glb"), Limits())
    return d, d.item("meshes", 0)["primitives"][0]


def test_primitive_reads_attributes_and_indices(tmp_path):
    uv = np.zeros((8, 2), np.float32)
    d, prim = _doc(tmp_path, TEXCOORD_0=uv, COLOR_0=np.full((8, 3), 0.5, np.float32))
    mesh = primitive(d, 0, 0, prim)
    assert mesh is not None and mesh.name == "mesh0/0"
    assert np.array_equal(mesh.indices, CUBE_INDICES.astype(np.uint32))
    assert mesh.normals is None  # left to ingest's finishing
    assert mesh.colors is not None and mesh.colors.shape == (8, 4) and np.all(mesh.colors[:, 3] == 1)
    assert mesh.uv0 is not None and mesh.uv1 is None


def test_bad_attributes_are_refused_or_skipped(tmp_path):
    d, prim = _doc(tmp_path, TEXCOORD_0=np.zeros((7, 2), np.float32))
    with pytest.raises(MalformedAsset, match="TEXCOORD_0 has 7 x 2 values, expected 8 x 2"):
        primitive(d, 0, 0, prim)
    with pytest.raises(MalformedAsset, match="unknown mode 9"):
        primitive(d, 0, 0, {**prim, "mode": 9})
    assert primitive(d, 0, 0, {"attributes": {}}) is None
    assert "no POSITION attribute" in d.warnings[-1]


def test_points_are_thickened_to_octahedra(tmp_path):
    """Each point becomes an octahedron whose size is a fraction of the scene's diagonal."""
    d, prim = _doc(tmp_path)
    mesh = primitive(d, 0, 0, {**prim, "mode": POINTS})
    assert mesh is not None and mesh.indices.shape == (36, 1)
    scene = Scene(source="p.glb", format="glb", meshes=[mesh],
                  instances=[Instance(0, 0, np.eye(4))])
    thicken(scene, {0: POINTS})
    assert mesh.indices.shape == (36 * 8, 3) and mesh.positions.shape == (36 * 6, 3)
    assert mesh.normals is not None and mesh.uv0 is None
    centres = CUBE_POSITIONS[CUBE_INDICES.reshape(-1)]
    offsets = np.linalg.norm(mesh.positions.reshape(36, 6, 3) - centres[:, None], axis=2)
    assert np.allclose(offsets, WIRE_RADIUS[POINTS] * np.sqrt(12.0), rtol=1e-4)
