"""Subdivision surfaces: ingest keeps the cage (pxr's count), bake refines coarse cages."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.bake import build_baked
from pipeline.ingest import load_scene
from pipeline.usd.subdivision import levels_for, loop_step

CUBE = """#usda 1.0
(
    metersPerUnit = 1
)
def Mesh "Cube"
{{
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]
    point3f[] points = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1),
                        (-1, -1, -1), (1, -1, -1)]
    texCoord2f[] primvars:st = [{st}] (interpolation = "faceVarying")
    uniform token subdivisionScheme = "{scheme}"
}}
"""


def cube(tmp_path, scheme="catmullClark"):
    st = ", ".join(f"({i % 4 * 0.25}, {i // 4 * 0.1})" for i in range(24))  # every corner its own
    path = tmp_path / f"cube_{scheme}.usda"
    path.write_text(CUBE.format(scheme=scheme, st=st))
    return path


def watertight(positions, indices) -> bool:
    """Every edge of the position-welded surface is shared by exactly two triangles."""
    _, weld = np.unique(positions, axis=0, return_inverse=True)
    tri = weld.reshape(-1)[indices]
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


@pytest.mark.parametrize("scheme", ["catmullClark", "loop"])
def test_coarse_cage_is_refined_at_bake_and_stays_closed(tmp_path, scheme):
    scene = load_scene(cube(tmp_path, scheme))
    assert scene.triangle_count == 12 and scene.meshes[0].subdivision == scheme  # the cage
    baked = build_baked(scene)
    mesh = baked.meshes[0]
    assert len(mesh.indices) == 12 * 16  # two levels of a 12-triangle cage
    assert baked.manifest["stats"]["refined"] == 1
    r = np.linalg.norm(mesh.positions, axis=1)
    assert r.max() / r.min() < 1.25  # rounded (the cube's corners are sqrt(3) = 1.73 x its faces)
    assert watertight(mesh.positions, mesh.indices)  # welded across the split UV seams
    assert mesh.uv0 is not None and len(mesh.uv0) == len(mesh.positions)
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", mesh.normals, mesh.positions) > 0)  # outward


def test_open_cage_keeps_its_corners(tmp_path):
    path = tmp_path / "quad.usda"
    path.write_text(CUBE.format(scheme="catmullClark", st="(0, 0)").replace(
        "[4, 4, 4, 4, 4, 4]", "[4]").replace("[0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, "
                                             "1, 7, 5, 3, 6, 0, 2, 4]", "[0, 1, 3, 2]")
                    .replace('(interpolation = "faceVarying")', '(interpolation = "constant")'))
    mesh = build_baked(load_scene(path)).meshes[0]
    assert len(mesh.indices) == 32
    np.testing.assert_allclose(mesh.positions.min(0)[:2], (-1, -1), atol=1e-6)
    np.testing.assert_allclose(mesh.positions.max(0)[:2], (1, 1), atol=1e-6)


def test_unauthored_scheme_is_drawn_as_the_cage(tmp_path):
    path = cube(tmp_path)
    path.write_text(path.read_text().replace('uniform token subdivisionScheme = "catmullClark"', ""))
    assert load_scene(path).meshes[0].subdivision is None


def test_scheme_none_and_levels_zero_keep_the_cage(tmp_path):
    assert len(build_baked(load_scene(cube(tmp_path, "none"))).meshes[0].indices) == 12
    scene = load_scene(cube(tmp_path))
    assert len(build_baked(scene, options={"subdivision_levels": 0}).meshes[0].indices) == 12


def test_teapot_cage_refined_two_levels(assets):
    scene = load_scene(assets / "usd/Teapot/Teapot.usd")
    assert scene.triangle_count == 2472
    assert build_baked(scene).manifest["stats"]["triangles"] == 2472 * 16


def test_levels_follow_the_cage_size_and_loop_step_is_linear_in_attributes():
    assert [levels_for(n) for n in (100, 10_000, 100_000)] == [2, 1, 0]
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    new_pos, tri, attrs, _ = loop_step(pos, np.array([[0, 1, 2]]), {"uv0": pos[:, :2].copy()})
    assert len(tri) == 4 and len(new_pos) == 6
    np.testing.assert_allclose(attrs["uv0"][3:], [[0.5, 0], [0, 0.5], [0.5, 0.5]], atol=1e-12)


# The cube's 12 edges as chains of 2 points, and its 8 corners.
EDGES = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 6), (1, 7), (2, 4), (3, 5)]


def creased(tmp_path, sharpness=None, corners=None, name="creased"):
    text = cube(tmp_path).read_text()
    extra = ""
    if isinstance(sharpness, (int, float)):
        sharpness = ", ".join([str(sharpness)] * 12)  # one per chain
    if sharpness is not None:
        extra += (f"    int[] creaseIndices = [{', '.join(f'{a}, {b}' for a, b in EDGES)}]\n"
                  f"    int[] creaseLengths = [{', '.join(['2'] * 12)}]\n"
                  f"    float[] creaseSharpnesses = [{sharpness}]\n")
    if corners is not None:
        extra += f"    int[] cornerIndices = [0, 1, 2, 3, 4, 5, 6, 7]\n" \
                 f"    float[] cornerSharpnesses = [{', '.join([str(corners)] * 8)}]\n"
    path = tmp_path / f"{name}.usda"
    path.write_text(text.replace("    uniform token subdivisionScheme", extra + "    uniform token subdivisionScheme"))
    return path


def off_cube(mesh) -> float:
    """Mean distance of the refined points from the cage cube's surface (0: still a cube)."""
    return float(np.mean(1.0 - np.abs(mesh.positions).max(axis=1)))


def test_infinitely_sharp_creases_keep_the_cube(tmp_path):
    mesh = build_baked(load_scene(creased(tmp_path, 10))).meshes[0]
    assert len(mesh.indices) == 12 * 16
    assert off_cube(mesh) < 1e-6  # every point on a face: edges stay sharp lines
    np.testing.assert_allclose(np.abs(mesh.positions).max(axis=0), 1.0, atol=1e-6)  # corners too
    assert watertight(mesh.positions, mesh.indices)
    # shading breaks along the crease: every normal is its face's (no soft band at the edges)
    np.testing.assert_allclose(np.abs(mesh.normals).max(axis=1), 1.0, atol=1e-5)


def test_semi_sharp_creases_round_less_as_sharpness_grows(tmp_path):
    smooth = off_cube(build_baked(load_scene(cube(tmp_path))).meshes[0])
    one = off_cube(build_baked(load_scene(creased(tmp_path, 1, name="one"))).meshes[0])
    half = off_cube(build_baked(load_scene(creased(tmp_path, 0.5, name="half"))).meshes[0])
    assert smooth > half > one > 0.0


def test_authored_corners_stay_put(tmp_path):
    mesh = build_baked(load_scene(creased(tmp_path, corners=10))).meshes[0]
    corners = np.abs(np.abs(mesh.positions) - 1).max(axis=1) < 1e-6
    assert corners.any()  # (+-1, +-1, +-1) survive
    welded = np.unique(mesh.positions[corners], axis=0)
    assert len(welded) == 8
    smooth = build_baked(load_scene(cube(tmp_path))).meshes[0]
    assert not (np.abs(np.abs(smooth.positions) - 1).max(axis=1) < 1e-6).any()


def test_mismatched_crease_arrays_are_a_warning(tmp_path):
    path = creased(tmp_path, "1, 2")  # two values for twelve chains of one edge
    scene = load_scene(path)
    assert any("creases ignored" in w for w in scene.warnings)
    assert scene.meshes[0].creases is None


def test_a_crease_chain_with_one_sharpness_per_edge(tmp_path):
    path = cube(tmp_path)
    path.write_text(path.read_text().replace("    uniform token subdivisionScheme",
                                             "    int[] creaseIndices = [0, 1, 3, 2, 0]\n"
                                             "    int[] creaseLengths = [5]\n"
                                             "    float[] creaseSharpnesses = [10, 10, 0, 2]\n"
                                             "    uniform token subdivisionScheme"))
    creases = load_scene(path).meshes[0].creases
    assert creases is not None and list(creases.edge_sharpness) == [10, 10, 2]  # the 0 is smooth
    np.testing.assert_allclose(creases.edges[0], [(-1, -1, 1), (1, -1, 1)])
