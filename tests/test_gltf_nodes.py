"""pipeline.gltf.nodes: node matrices, the tree check, instancing, cameras and lights."""
from __future__ import annotations

import math

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder

from core.errors import MalformedAsset
from pipeline.gltf.accessors import Document
from pipeline.gltf.nodes import NodeGraph, camera, light, trs
from pipeline.limits import Limits

QUARTER_Z = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]  # 90 degrees about +Z


def test_trs_composes_translation_rotation_scale():
    m = trs(np.array([[1.0, 2.0, 3.0]]), np.array([QUARTER_Z]), np.array([[2.0, 2.0, 2.0]]))[0]
    assert np.allclose(m @ [1, 0, 0, 1], [1, 4, 3, 1])  # x scaled to 2, turned to +y, moved


def test_world_matrices_compose_parents_first(tmp_path):
    b = Builder()
    child = b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES), root=False, translation=[1, 0, 0])
    b.node(rotation=QUARTER_Z, children=[child])
    graph = NodeGraph(Document(b.write(tmp_path / "n.glb"), Limits()))
    placed = graph.world_matrices()
    assert [i for i, _ in placed] == [1, 0]
    assert np.allclose(dict(placed)[0] @ [0, 0, 0, 1], [0, 1, 0, 1])


def test_a_node_reached_twice_is_refused(tmp_path):
    b = Builder()
    shared = b.node(root=False)
    b.node(children=[shared])
    b.node(children=[shared])
    graph = NodeGraph(Document(b.write(tmp_path / "dag.glb"), Limits()))
    with pytest.raises(MalformedAsset, match="reached twice"):
        graph.world_matrices()


def test_gpu_instancing_gives_one_matrix_per_instance(tmp_path):
    b = Builder()
    t = b.accessor(np.array([[0, 0, 0], [5, 0, 0], [0, 5, 0]], np.float32))
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES),
           extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": t}}})
    d = Document(b.write(tmp_path / "i.glb"), Limits())
    node = d.item("nodes", 0)
    placements = NodeGraph(d).instancing(node, 0, np.eye(4))
    assert placements.shape == (3, 4, 4) and np.allclose(placements[:, :3, 3], [[0, 0, 0], [5, 0, 0], [0, 5, 0]])
    assert NodeGraph(d).instancing({}, 0, np.eye(4)).shape == (1, 4, 4)


def test_cameras_and_lights(tmp_path):
    b = Builder()
    b.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}},
                        {"type": "fisheye"}]
    b.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "spot", "intensity": 3, "spot": {"outerConeAngle": 0.3}}]}}
    b.node(name="cam", camera=0)
    d = Document(b.write(tmp_path / "c.gltf", "data"), Limits())
    cam = camera(d, 0, 0, np.eye(4))
    assert cam.name == "cam" and cam.yfov == 0.5 and cam.znear == 0.1 and cam.aspect is None
    with pytest.raises(MalformedAsset, match="'fisheye' is not perspective or orthographic"):
        camera(d, 1, 0, np.eye(4))
    spot = light(d, 0, np.eye(4))
    assert spot.type == "spot" and spot.intensity == 3.0 and spot.outer_cone == 0.3
    with pytest.raises(MalformedAsset, match="light index 4 out of range"):
        light(d, 4, np.eye(4))
