"""Directional occlusion and the split-sum's horizon (issue 30): the bake's bent normals
(pipeline.occlusion) point away from a blocker and turn the raster's irradiance lookup there,
and a rough upward face seen at a grazing angle under a sky over a black ground keeps the
sky its lobe sees (core.horizon), against our path integrator."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.baked import BakedAsset, BakedMesh, dequantise_directions, quantise_directions, quantise_visibility
from core.horizon import below_fraction, horizon_table
from core.options import RenderOptions
from core.scene import Material
from pipeline.bake import bake_environment
from pipeline.environment.panorama import write_rgbe
from pipeline.occlusion import ambient_occlusion
from tests.test_occlusion import _bounds, _grid, _mesh, _sphere


@pytest.fixture(scope="module")
def sky_over_black(tmp_path_factory):
    """Radiance 1 above the horizon, 0 below (an equirect panorama, +y up)."""
    d = tmp_path_factory.mktemp("sky_black")
    h, w = 128, 256
    rows = (np.arange(h) + 0.5) / h  # v = 0 at the top (+y)
    pixels = np.repeat((rows < 0.5).astype(np.float32)[:, None, None], w, axis=1) * np.ones(3, np.float32)
    write_rgbe(d / "sky_black.hdr", pixels)
    return bake_environment(str(d / "sky_black.hdr"), d, face_size=64)


def test_the_horizon_table():
    t = horizon_table()
    np.testing.assert_allclose(t[0], 0.5, atol=0.02)  # d on the plane: half the kernel under it
    assert np.all(t[-1] < 1e-3)  # d along n: none
    assert np.all(np.diff(t[1:], axis=0) <= 1e-9)  # less as d rises
    assert np.all(np.diff(t[1:-1], axis=1) >= -2e-3)  # more as the lobe widens (to the set's grain)
    assert below_fraction(0.3, 0.0) < 0.01 and below_fraction(0.3, 1.0) > 0.2


def test_bent_normals_point_away_from_the_blocker():
    plane = _mesh("plane", _grid(10.0, 21))
    ball = _mesh("ball", _sphere(1.0, (0.0, 1.05, 0.0)))
    result = ambient_occlusion([plane, ball], _bounds([plane, ball]))
    assert result.bent is not None
    bent_plane = dequantise_directions(result.bent[0])[:, :3]
    bent_ball = dequantise_directions(result.bent[1])[:, :3]
    np.testing.assert_allclose(np.linalg.norm(bent_plane, axis=1), 1.0, atol=0.02)
    pos = plane.positions
    # beside the ball: bent outward, away from its axis; far out: the normal
    near = (np.abs(np.linalg.norm(pos[:, [0, 2]], axis=1) - 1.0) < 0.3)
    radial = pos[near][:, [0, 2]] / np.linalg.norm(pos[near][:, [0, 2]], axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", bent_plane[near][:, [0, 2]], radial) > 0.2)
    corners = [0, 20, 20 * 21, 21 * 21 - 1]
    assert np.all(bent_plane[corners] @ [0, 1, 0] > 0.98)
    # the ball's lower half: bent up, away from the plane, from its normal (where some sky
    # is seen: a vertex whose every ray is blocked keeps its normal)
    low = (ball.normals[:, 1] < -0.3) & (ball.normals[:, 1] > -0.85)
    assert np.all(bent_ball[low, 1] > ball.normals[low, 1] + 0.2)
    top = np.argmax(ball.positions[:, 1])
    assert bent_ball[top] @ [0, 1, 0] > 0.98


def _board(bent_y: float | None, key: str) -> BakedAsset:
    """A 2 x 2 white Lambert board facing +z, visibility 0.5, its bent normal tilted toward
    +y by bent_y (None: no bent normals baked)."""
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    n = np.tile([0, 0, 1], (4, 1)).astype(np.float32)
    bent = None
    if bent_y is not None:
        b = np.array([0.0, bent_y, 1.0])
        b /= np.linalg.norm(b)
        bent = quantise_directions(np.tile(np.r_[b, -b], (4, 1)))
    m = Material(base_color=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=1.0, specular=0.0)
    mesh = BakedMesh("board", pos, n, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), m, np.eye(4)[None],
                     ao=quantise_visibility(np.full((4, 2), 0.5)), bent=bent)
    return BakedAsset(key=f"bent-board-{key}", source="board", format="test", meshes=[mesh], textures=[],
                      bounds=np.array([pos.min(0), pos.max(0)], np.float64))


def _centre(asset, env, method: str = "opaque", **kw) -> np.ndarray:
    from renderer import render
    o = RenderOptions(width=32, height=32, tonemap="none", background="transparent", yaw=0.0, pitch=0.0,
                      fov=30.0, shadow=0.0, method=method, **kw)
    return render(asset, env, o).linear[13:19, 13:19, :3].reshape(-1, 3).mean(0)


def test_the_occluded_side_darkens(sky_over_black):
    """A vertical board under a sky over a black ground: the sky is half its hemisphere. Its
    bent normal tilted down (the sky blocked, the ground open) lowers the irradiance, tilted
    up raises it, and unbent it is as without bent normals."""
    plain = _centre(_board(None, "none"), sky_over_black)
    level = _centre(_board(0.0, "level"), sky_over_black)
    down = _centre(_board(-0.8, "down"), sky_over_black)
    up = _centre(_board(0.8, "up"), sky_over_black)
    np.testing.assert_allclose(level, plain, rtol=0.02)
    assert np.all(down < 0.75 * level), (down, level)
    assert np.all(up > 1.25 * level), (up, level)


def test_uniform_light_unchanged_by_the_bend(tmp_path):
    """Under a uniform environment the bend changes nothing (every direction is the same)."""
    uniform = bake_environment("uniform:1,1,1", tmp_path, face_size=32)
    level = _centre(_board(0.0, "u-level"), uniform)
    down = _centre(_board(-0.8, "u-down"), uniform)
    np.testing.assert_allclose(down, level, rtol=0.02)


def _quad(roughness: float) -> BakedAsset:
    """A 4 x 4 white metal quad facing +y."""
    pos = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]], np.float32)
    m = Material(base_color=(1.0, 1.0, 1.0, 1.0), metallic=1.0, roughness=roughness)
    mesh = BakedMesh("quad", pos, np.tile([0, 1, 0], (4, 1)).astype(np.float32),
                     np.array([[0, 2, 1], [0, 3, 2]], np.uint32), m, np.eye(4)[None])
    return BakedAsset(key=f"horizon-quad-{roughness}", source="quad", format="test", meshes=[mesh],
                      textures=[], bounds=np.array([pos.min(0), pos.max(0)], np.float64))


@pytest.mark.parametrize("roughness", [0.5, 0.7])
def test_rough_face_at_a_grazing_view_keeps_its_sky(sky_over_black, roughness):
    """Seen 20 degrees above its plane, the face's lobe under a sky over a black ground reads
    only sky in a path tracer (light from under the surface never arrives). The raster's one
    lookup counted the kernel's part under the plane as the ground's black: 16-30% dark at
    roughness 0.5; within 8% of the path integrator now (its 256 paths' grain ~1%)."""
    asset = _quad(roughness)
    kw = dict(width=48, height=48, tonemap="none", background="transparent", yaw=0.0, pitch=20.0,
              fov=20.0, shadow=0.0, distance=6.0)
    from renderer import render
    raster = render(asset, sky_over_black, RenderOptions(method="opaque", **kw)).linear
    path = render(asset, sky_over_black, RenderOptions(method="raytrace", integrator="path", samples=256,
                                                       **kw)).linear
    window = (slice(18, 30), slice(12, 36))  # the middle of the quad
    r, p = raster[window][..., :3].mean(), path[window][..., :3].mean()
    assert p > 0.3
    assert abs(r / p - 1) < 0.08, (r, p)


def test_open_vertices_are_unchanged(sky_over_black):
    """Baked bent normals along the normal with visibility 1: the same frame as with none."""
    asset = _quad(0.5)
    mesh = asset.meshes[0]
    n = np.tile([0.0, 1.0, 0.0, 0.0, -1.0, 0.0], (4, 1))
    baked = dataclasses.replace(mesh, ao=quantise_visibility(np.ones((4, 2))), bent=quantise_directions(n))
    with_bent = dataclasses.replace(asset, key=asset.key + "-bent", meshes=[baked])
    kw = dict(width=32, height=32, tonemap="none", background="transparent", yaw=0.0, pitch=20.0,
              fov=20.0, shadow=0.0, distance=6.0, method="opaque")
    from renderer import render
    a = render(asset, sky_over_black, RenderOptions(**kw)).linear
    b = render(with_bent, sky_over_black, RenderOptions(**kw)).linear
    np.testing.assert_allclose(b, a, atol=2e-3)


def test_no_bent_normals_on_rows_per_placement():
    """A mesh whose placements keep rows of their own gets no bent normals (their mean over
    placements in other surroundings points nowhere); one shared row keeps them."""
    ball = _sphere(1.0, (0.0, 0.0, 0.0))
    xs = np.tile(np.eye(4), (6, 1, 1))
    xs[:, 0, 3] = np.arange(6) * 2.1
    mesh = BakedMesh("balls", *ball, Material(), xs)
    bounds = np.array([xs[:, :3, 3].min(0) - 1.0, xs[:, :3, 3].max(0) + 1.0])
    apart = ambient_occlusion([mesh], bounds)
    assert apart.ao[0].shape == (6 * len(ball[0]), 2) and apart.bent[0] is None
    shared = ambient_occlusion([mesh], bounds, max_rays=16 * 6 * len(ball[0]) - 1)
    assert shared.bent[0].shape == (len(ball[0]), 6)


def test_cache_keeps_the_bent_normals(tmp_path):
    from pipeline.bake import bake_asset, load_baked
    from tests.gltf_builder import cube
    baked = bake_asset(cube(tmp_path / "cube.glb"), tmp_path / "cache")
    (mesh,) = baked.meshes
    assert mesh.bent is not None and mesh.bent.shape == (len(mesh.positions), 6) and mesh.bent.dtype == np.uint8
    # a convex solid: nothing bends its sky away from the normal
    front = dequantise_directions(mesh.bent)[:, :3]
    assert np.all(np.einsum("ij,ij->i", front, mesh.normals) > 0.98)
    np.testing.assert_array_equal(load_baked(baked.key, tmp_path / "cache").meshes[0].bent, mesh.bent)


def test_the_trees_diffuse_bends_as_the_rasters(sky_over_black):
    """The ray tracer's Fresnel tree reads the irradiance about the same bent normal: under a
    sky over a black ground the board's bent-down side darkens and its bent-up side brightens
    by the raster's ratios (both read the sky's irradiance about m.bent; tree: the cube's
    texels, raster: the SH), and a level bend is the unbent frame."""
    ratios = {}
    for method in ("opaque", "raytrace"):
        plain = _centre(_board(None, "none"), sky_over_black, method=method)
        level = _centre(_board(0.0, "level"), sky_over_black, method=method)
        down = _centre(_board(-0.8, "down"), sky_over_black, method=method)
        up = _centre(_board(0.8, "up"), sky_over_black, method=method)
        np.testing.assert_allclose(level, plain, rtol=0.02)
        ratios[method] = (down / level, up / level)
    (r_down, r_up), (t_down, t_up) = ratios["opaque"], ratios["raytrace"]
    assert np.all(t_down < 0.75) and np.all(t_up > 1.25), (t_down, t_up)
    np.testing.assert_allclose(t_down, r_down, rtol=0.1)
    np.testing.assert_allclose(t_up, r_up, rtol=0.1)


def test_the_tree_without_bent_rows_is_unchanged(sky_over_black):
    """A mesh without bent normals beside one with them: its pixels are bit-identical to the
    frame where no mesh has any (the tree's old path, trace_material.bent_at None)."""
    from renderer import render

    def pair(bent_y, key):
        left, right = _board(None, key).meshes[0], _board(bent_y, key).meshes[0]
        shift = np.eye(4)
        shift[0, 3] = 1.5
        right = dataclasses.replace(right, name="right", transforms=shift[None])
        shift = shift.copy()
        shift[0, 3] = -1.5
        left = dataclasses.replace(left, transforms=shift[None])
        pos = np.array([[-2.5, -1, 0], [2.5, 1, 0]], np.float64)
        return BakedAsset(key=f"bent-pair-{key}", source="pair", format="test", meshes=[left, right],
                          textures=[], bounds=pos)
    o = RenderOptions(width=48, height=24, tonemap="none", background="transparent", yaw=0.0, pitch=0.0,
                      fov=40.0, shadow=0.0, method="raytrace")
    mixed = render(pair(-0.8, "mixed"), sky_over_black, o).linear
    none = render(pair(None, "none"), sky_over_black, o).linear
    np.testing.assert_array_equal(mixed[:, :20], none[:, :20])
    assert mixed[:, 28:, :3].sum() < 0.9 * none[:, 28:, :3].sum()  # the bent board did darken
