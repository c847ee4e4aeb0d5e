"""Static batching at bake (pipeline.batching): many small meshes placed once become one
BakedMesh per material, drawn as the separate meshes were."""
from __future__ import annotations

import numpy as np
import pytest

from core.adjacency import welded_edges
from core.hull import support_points
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment, build_baked, load_baked
from pipeline.batching import batch, merge
from pipeline.ingest import load_scene

_CUBE = ("int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n"
         "        int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]\n"
         "        point3f[] points = [(-0.5, -0.5, 0.5), (0.5, -0.5, 0.5), (-0.5, 0.5, 0.5), (0.5, 0.5, 0.5), "
         "(-0.5, 0.5, -0.5), (0.5, 0.5, -0.5), (-0.5, -0.5, -0.5), (0.5, -0.5, -0.5)]\n"
         "        uniform token subdivisionScheme = \"none\"\n")


def _look(name: str, rgb, opacity: float = 1.0) -> str:
    return (f'def Material "{name}"\n{{\n    token outputs:surface.connect = </World/{name}/S.outputs:surface>\n'
            f'    def Shader "S"\n    {{\n        uniform token info:id = "UsdPreviewSurface"\n'
            f'        color3f inputs:diffuseColor = {rgb}\n        float inputs:opacity = {opacity}\n'
            f'        token outputs:surface\n    }}\n}}\n')


def _stage(path):
    """A grid of 30 cubes, each its own Mesh, turned, moved and scaled, under two opaque
    materials; one cube mirrored, one translucent, and one cube referenced twice as an
    instance: the 30 opaque ones batch into two meshes, the rest stay as they are."""
    rng = np.random.default_rng(3)
    prims = []
    for k in range(30):
        x, z = k % 6 - 2.5, k // 6 - 2.0
        angle = float(rng.uniform(0, 90))
        s = rng.uniform(0.4, 0.8, 3)
        look = "Red" if k % 3 else "Blue"
        prims.append(f'def Mesh "C{k}" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n{{\n    {_CUBE}'
                     f'    double3 xformOp:translate = ({x * 1.2}, {s[1] / 2}, {z * 1.2})\n'
                     f'    float xformOp:rotateY = {angle:.3f}\n'
                     f'    float3 xformOp:scale = ({s[0]:.3f}, {s[1]:.3f}, {s[2]:.3f})\n'
                     f'    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY", "xformOp:scale"]\n'
                     f'    rel material:binding = </World/{look}>\n}}\n')
    prims.append(f'def Mesh "Mirrored" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n{{\n    {_CUBE}'
                 '    double3 xformOp:translate = (4.5, 0.3, 0)\n    float3 xformOp:scale = (-0.5, 0.5, 0.5)\n'
                 '    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]\n'
                 '    rel material:binding = </World/Red>\n}\n')
    prims.append(f'def Mesh "Glass" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n{{\n    {_CUBE}'
                 '    double3 xformOp:translate = (-4.5, 0.3, 0)\n    uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                 '    rel material:binding = </World/Glassy>\n}\n')
    for k, x in enumerate((-4.5, 4.5)):
        prims.append(f'def Xform "Twin{k}" ( instanceable = true\n    references = </World/Source> )\n{{\n'
                     f'    double3 xformOp:translate = ({x}, 0.3, 3)\n    uniform token[] xformOpOrder = ["xformOp:translate"]\n}}\n')
    source = (f'class Xform "Source"\n{{\n    def Mesh "Geom" ( prepend apiSchemas = ["MaterialBindingAPI"] )\n'
              f'    {{\n    {_CUBE}        rel material:binding = </World/Blue>\n    }}\n}}\n')
    body = "".join(prims) + source + _look("Red", (0.8, 0.1, 0.1)) + _look("Blue", (0.1, 0.2, 0.8)) + \
        _look("Glassy", (0.9, 0.9, 0.9), 0.4)
    text = ('#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n    defaultPrim = "World"\n)\n'
            'def Xform "World"\n{\n' + "\n".join("    " + ln for ln in body.splitlines()) + "\n}\n")
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    return _stage(tmp_path_factory.mktemp("batching") / "cubes.usda")


def test_opaque_meshes_placed_once_batch_by_material(stage):
    scene = load_scene(stage)
    plain, batched = build_baked(scene), build_baked(scene, batch=True)
    assert len(plain.meshes) == 33  # 30 + mirrored + translucent + the instanced cube
    # the 30 cubes in two batches (one per material); mirrored, translucent, instanced alone
    assert len(batched.meshes) == 5
    assert batched.manifest["stats"]["batched"] == 30
    twins = [m for m in batched.meshes if len(m.transforms) == 2]
    assert len(twins) == 1  # the instance prototype: one mesh, two placements, not batched
    assert sum(len(m.indices) * len(m.transforms) for m in batched.meshes) == \
        sum(len(m.indices) * len(m.transforms) for m in plain.meshes)
    big = [m for m in batched.meshes if "batched" in m.name]
    assert sorted(len(m.indices) for m in big) == [10 * 12, 20 * 12]
    assert all(np.array_equal(m.transforms, np.eye(4)[None]) for m in big)
    np.testing.assert_allclose(batched.bounds, plain.bounds)


def test_a_batch_is_its_parts_in_world_space(stage):
    scene = load_scene(stage)
    plain = build_baked(scene)
    parts = [m for m in plain.meshes if m.material.name.endswith("Red") and len(m.transforms) == 1
             and np.linalg.det(m.transforms[0][:3, :3]) > 0]
    one = merge(parts)
    offset = 0
    edges, faces, support = [], [], []
    tri_offset = 0
    for p in parts:
        m = p.transforms[0]
        n = len(p.positions)
        np.testing.assert_allclose(one.positions[offset:offset + n], p.positions @ m[:3, :3].T + m[:3, 3],
                                   rtol=1e-6, atol=1e-6)
        e, f = welded_edges(p.positions, p.indices)
        edges.append(e + offset)
        faces.append(np.where(f >= 0, f + tri_offset, -1))
        support.append(support_points(p.positions) @ m[:3, :3].T + m[:3, 3])
        offset += n
        tri_offset += len(p.indices)
    # the welded edges each part has (never welded across parts), renumbered, in part order
    np.testing.assert_array_equal(one.edges, np.concatenate(edges))
    np.testing.assert_array_equal(one.edge_faces, np.concatenate(faces))
    np.testing.assert_allclose(one.support, np.concatenate(support))
    assert one.edge_order is not None and len(one.edge_order) == len(one.edges)


def test_left_alone_without_a_group():
    """One mesh of a material: nothing to batch, nothing changed."""
    from core.baked import BakedMesh
    from core.scene import Material
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    m = BakedMesh("t", pos, np.tile([0, 0, 1], (3, 1)).astype(np.float32), np.array([[0, 1, 2]], np.uint32),
                  Material(), np.eye(4)[None])
    out, members = batch([m], [False])
    assert out == [m] and members == [[0]] and m.edge_order is None


def test_batched_bake_renders_as_the_separate_meshes(stage, tmp_path):
    """The stored bake batches; its frame is the unbatched one's (edges drawn in the order the
    separate meshes had): only float rounding of the moved vertices may differ, on edge pixels."""
    from renderer import render
    env = bake_environment("neutral", tmp_path / "env", face_size=32)
    baked = bake_asset(stage, tmp_path / "cache")
    assert baked.manifest["stats"]["batched"] == 30
    cached = load_baked(baked.key, tmp_path / "cache")  # the batch and its edge order stored
    assert len(cached.meshes) == 5 and any(m.edge_order is not None for m in cached.meshes)
    plain = build_baked(load_scene(stage), "plain-" + baked.key)
    o = RenderOptions(width=96, height=96, shadow=0.0)
    a = render(plain, env, o).rgba8.astype(int)
    b = render(cached, env, o).rgba8.astype(int)
    differ = np.abs(a - b).max(-1) > 2
    assert differ.mean() < 0.002, f"{differ.sum()} pixels differ"


def test_meshes_of_one_connectivity_keep_their_own_points_and_uvs(tmp_path):
    """The stage reader shares a small mesh's triangulation and vertex split by connectivity
    (pipeline.usd.stage._split): each mesh still gets its own points and st."""
    quads = []
    for k in range(3):
        pts = ", ".join(f"({x + 3 * k}, {y * (k + 1)}, 0)" for y in range(2) for x in range(3))
        st = ", ".join(f"({0.1 * k + 0.2 * i}, {0.3 * i})" for i in range(8))
        quads.append(f'def Mesh "Q{k}"\n{{\n    int[] faceVertexCounts = [4, 4]\n'
                     f'    int[] faceVertexIndices = [0, 1, 4, 3, 1, 2, 5, 4]\n    point3f[] points = [{pts}]\n'
                     f'    texCoord2f[] primvars:st = [{st}] ( interpolation = "faceVarying" )\n'
                     f'    uniform token subdivisionScheme = "none"\n}}\n')
    path = tmp_path / "quads.usda"
    path.write_text('#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n' + "".join(quads))
    scene = load_scene(path)
    assert len(scene.meshes) == 3
    for k, mesh in enumerate(sorted(scene.meshes, key=lambda m: m.name)):
        world = mesh.positions[mesh.indices]  # T x 3 x 3
        assert world[..., 0].min() == 3 * k and world[..., 0].max() == 3 * k + 2
        assert world[..., 1].max() == k + 1
        assert mesh.uv0 is not None
        # (flat normals unweld the corners: each value appears once per triangle using it)
        np.testing.assert_allclose(np.unique(np.round(mesh.uv0[:, 0], 5)), 0.1 * k + 0.2 * np.arange(8), atol=1e-5)
