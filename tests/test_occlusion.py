"""Baked visibility (pipeline.occlusion, issue 30): the bake's per-vertex ambient occlusion on
concave geometry, against the analytic form factor of a box's opening, and its use by the
image light: the raster's diffuse drops by the multi-bounce factor of core.lobes, its specular
by Lagarde's specular occlusion, the ray tracer's diffuse share by the same factor, and
punctual lights not at all."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from core.baked import BakedAsset, BakedMesh, dequantise_visibility, quantise_visibility
from core.lobes import ao_multibounce, specular_occlusion
from core.options import RenderOptions
from core.scene import Light, Material
from pipeline.bake import bake_asset, bake_environment, build_baked, load_baked
from pipeline.occlusion import ambient_occlusion, hemisphere_set


def _grid(size: float, n: int, y: float = 0.0, up: bool = True):
    """An n x n vertex grid of side `size` at height y, facing +y (or -y), centred on the axis."""
    s = np.linspace(-size / 2, size / 2, n)
    x, z = np.meshgrid(s, s, indexing="ij")
    pos = np.stack([x.ravel(), np.full(n * n, y), z.ravel()], 1).astype(np.float32)
    idx = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j
            idx += [[a, b, c], [a, c, d]] if up else [[a, c, b], [a, d, c]]
    nrm = np.tile([0.0, 1.0 if up else -1.0, 0.0], (n * n, 1)).astype(np.float32)
    tris = np.asarray(idx, np.uint32)
    # wind every triangle so its right-handed normal is the vertex normal
    e = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    flip = e @ nrm[0] < 0
    tris[flip] = tris[flip][:, ::-1]
    return pos, nrm, tris


def _sphere(radius: float, centre, rings: int = 16, segments: int = 24):
    th, ph = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, segments + 1), indexing="ij")
    nrm = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1).reshape(-1, 3)
    pos = (radius * nrm + np.asarray(centre)).astype(np.float32)
    idx = []
    for i in range(rings):
        for j in range(segments):
            a, b = i * (segments + 1) + j, (i + 1) * (segments + 1) + j
            idx += [[a, a + 1, b + 1], [a, b + 1, b]]
    tris = np.asarray(idx, np.uint32)
    e = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    flip = np.einsum("ij,ij->i", e, nrm[tris[:, 0]] + nrm[tris[:, 1]] + nrm[tris[:, 2]]) < 0
    tris[flip] = tris[flip][:, ::-1]
    return pos, nrm.astype(np.float32), tris


def _mesh(name, geometry, material=None, transform=None) -> BakedMesh:
    pos, nrm, tris = geometry
    return BakedMesh(name, pos, nrm, tris, material or Material(), np.eye(4)[None] if transform is None
                     else np.asarray(transform, np.float64)[None])


def _ao(result, i: int) -> np.ndarray:
    ao = result.ao[i]
    assert ao is not None, f"mesh {i} got no occlusion"
    assert ao.dtype == np.uint8  # stored compactly; readers dequantise
    return dequantise_visibility(ao)


def _bounds(meshes) -> np.ndarray:
    p = np.concatenate([m.positions for m in meshes])
    return np.array([p.min(0), p.max(0)], np.float64)


def _open_box():
    """A unit box open at the top: the floor a 9 x 9 grid facing up, four walls facing in."""
    floor = _grid(1.0, 9)
    walls = []
    for k, (axis, sign) in enumerate(((0, 1), (0, -1), (2, 1), (2, -1))):
        pos, nrm, tris = _grid(1.0, 3, y=0.0, up=True)
        # the wall: the grid turned to stand at x or z = +-0.5, its normal pointing inward
        p = pos.astype(np.float64)
        p[:, 1] += 0.5
        wall = np.zeros_like(p)
        other = 2 - axis
        wall[:, axis] = 0.5 * sign
        wall[:, other] = p[:, other if axis == 0 else 0]
        wall[:, 1] = p[:, axis if axis == 0 else 2] + 0.5
        n = np.zeros_like(p)
        n[:, axis] = -sign
        e = np.cross(wall[tris[:, 1]] - wall[tris[:, 0]], wall[tris[:, 2]] - wall[tris[:, 0]])
        flip = e @ n[0] < 0
        tris = tris.copy()
        tris[flip] = tris[flip][:, ::-1]
        walls.append(_mesh(f"wall{k}", (wall.astype(np.float32), n.astype(np.float32), tris)))
    return [_mesh("floor", floor), *walls]


def _rectangle_form_factor(x: float, y: float) -> float:
    """Form factor from a point to a parallel x by y rectangle one unit above it, with a corner
    straight above the point: the cosine-weighted share of the hemisphere it fills."""
    return (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
            + y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))) / (2 * math.pi)


def _aperture_form_factor(side: float, height: float) -> float:
    """Cosine-weighted share of the hemisphere seen through a centred square opening of
    `side` at `height` above a point (four corner rectangles)."""
    return 4 * _rectangle_form_factor(side / 2 / height, side / 2 / height)


def test_hemisphere_set_is_cosine_weighted():
    d = hemisphere_set(64)
    assert d.shape == (64, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert np.all(d[:, 2] > 0)
    # E[cos] under the cosine-weighted density is 2/3; the strata hit it closely
    assert abs(d[:, 2].mean() - 2 / 3) < 0.01


def test_open_box_floor_sees_the_sky_only_through_its_opening():
    meshes = _open_box()
    result = ambient_occlusion(meshes, _bounds(meshes))
    floor = _ao(result, 0)[:, 0].reshape(9, 9)
    # against the form factor of the opening: from the centre, the middle of an edge (at a
    # wall's foot) and a corner (two walls' feet)
    centre = _aperture_form_factor(1.0, 1.0)  # 0.239
    edge = 2 * _rectangle_form_factor(1.0, 0.5)  # 0.180
    corner = _rectangle_form_factor(1.0, 1.0)  # 0.139
    assert abs(floor[4, 4] - centre) < 0.03, (floor[4, 4], centre)
    for got in (floor[0, 4], floor[8, 4], floor[4, 0], floor[4, 8]):
        assert abs(got - edge) < 0.04, (got, edge)
    for got in (floor[0, 0], floor[0, 8], floor[8, 0], floor[8, 8]):
        assert abs(got - corner) < 0.03, (got, corner)
    # the walls' tops see more sky than their feet
    for k, wall in enumerate(meshes[1:], 1):
        ao = _ao(result, k)
        y = wall.positions[:, 1]
        assert ao[y == y.max(), 0].mean() > ao[y == y.min(), 0].mean() + 0.2
    assert result.rays_per_vertex == 64 and result.stride == 1


def test_plane_under_a_sphere():
    plane = _mesh("plane", _grid(10.0, 21))
    ball = _mesh("ball", _sphere(1.0, (0.0, 1.05, 0.0)))
    result = ambient_occlusion([plane, ball], _bounds([plane, ball]))
    ao_plane, ao_ball = _ao(result, 0)[:, 0], _ao(result, 1)[:, 0]
    centre = 10 * 21 + 10
    assert ao_plane[centre] < 0.2  # under the ball: most of the sky blocked
    corners = [0, 20, 20 * 21, 21 * 21 - 1]
    assert np.all(ao_plane[corners] > 0.97)  # far out: open
    top = np.argmax(ball.positions[:, 1])
    assert ao_ball[top] == 1.0  # nothing above the ball
    bottom = np.argmin(ball.positions[:, 1])
    assert ao_ball[bottom] < 0.2  # its underside faces the plane
    # one-sided: the plane seen from below blocks nothing (rays pass a single-sided back face)
    under = _mesh("under", _grid(2.0, 3, y=-1.0))  # facing up, at the plane's back
    result = ambient_occlusion([plane, under], _bounds([plane, under]))
    assert np.all(_ao(result, 1)[:, 0] == 1.0)
    double = dataclasses.replace(plane, material=Material(double_sided=True))
    result = ambient_occlusion([double, under], _bounds([double, under]))
    assert np.all(_ao(result, 1)[:, 0] < 0.3)
    # a double-sided receiver bakes both sides: its back faces the plane below
    sheet = _mesh("sheet", _grid(2.0, 3, y=1.0), Material(double_sided=True))
    result = ambient_occlusion([plane, sheet], _bounds([plane, sheet]))
    assert np.all(_ao(result, 1)[:, 0] == 1.0) and np.all(_ao(result, 1)[:, 1] < 0.5)


def test_glass_and_unlit_neither_receive_nor_glass_occludes():
    plane = _mesh("plane", _grid(10.0, 21))
    glass = _mesh("ball", _sphere(1.0, (0.0, 1.05, 0.0)), Material(transmission=1.0))
    result = ambient_occlusion([plane, glass], _bounds([plane, glass]))
    assert result.ao[1] is None and np.all(_ao(result, 0) == 1.0)


@pytest.mark.parametrize("emissive, strength, occludes", [
    ((0.0, 0.0, 0.0), 1.0, True), ((0.02, 0.02, 0.02), 1.0, True),  # dark: below the threshold
    ((1.0, 0.5, 0.0), 1.0, False), ((0.02, 0.0, 0.0), 10.0, False)])  # strength counts
def test_an_emitter_does_not_occlude(emissive, strength, occludes):
    # in a path tracer an emitter is light where it hides the sky: the plane under it stays open
    plane = _mesh("plane", _grid(10.0, 21))
    lamp = _mesh("lamp", _sphere(1.0, (0.0, 1.05, 0.0)), Material(emissive=emissive, emissive_strength=strength))
    result = ambient_occlusion([plane, lamp], _bounds([plane, lamp]))
    centre = 10 * 21 + 10
    under = _ao(result, 0)[centre, 0]
    assert (under < 0.2) if occludes else (under == 1.0)
    bottom = np.argmin(lamp.positions[:, 1])
    assert _ao(result, 1)[bottom, 0] < 0.2  # it still receives: its base colour is lit as before


def test_a_textured_emitter_still_occludes():
    from core.scene import TextureRef
    plane = _mesh("plane", _grid(10.0, 21))
    lamp = _mesh("lamp", _sphere(1.0, (0.0, 1.05, 0.0)),
                 Material(emissive=(1.0, 1.0, 1.0), emissive_texture=TextureRef(0)))
    result = ambient_occlusion([plane, lamp], _bounds([plane, lamp]))
    assert _ao(result, 0)[10 * 21 + 10, 0] < 0.2  # the texture says where it glows, per texel


def test_budget_caps_the_rays():
    plane = _mesh("plane", _grid(10.0, 41))  # 1681 vertices
    ball = _mesh("ball", _sphere(1.0, (0.0, 1.05, 0.0)))
    meshes = [plane, ball]
    full = ambient_occlusion(meshes, _bounds(meshes))
    vertices = len(plane.positions) + len(ball.positions)
    # the rays cast: one set per vertex, and a few go on through a single-sided back face
    assert 64 * vertices <= full.rays <= 1.05 * 64 * vertices
    capped = ambient_occlusion(meshes, _bounds(meshes), max_rays=20 * vertices)
    assert capped.rays_per_vertex == 16 and capped.rays <= 1.05 * 16 * vertices
    strided = ambient_occlusion(meshes, _bounds(meshes), max_rays=4 * vertices)
    assert strided.stride == 4 and strided.rays <= 1.05 * 4 * vertices + 16 * 4
    assert len(_ao(strided, 0)) == len(plane.positions)
    # fewer rays, the same picture: under the ball dark, far out open
    centre = 20 * 41 + 20
    for r in (capped, strided):
        assert _ao(r, 0)[centre, 0] < 0.3 and _ao(r, 0)[0, 0] > 0.9


# -- the image light ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def uniform_env(tmp_path_factory):
    return bake_environment("uniform:1,1,1", tmp_path_factory.mktemp("ao_env"), face_size=64)


def _board(material: Material, ao: float | None, key: str) -> BakedAsset:
    """A 2 x 2 board facing +z (the camera at yaw 0 looks at it along -z)."""
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    mesh = BakedMesh("board", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), material, np.eye(4)[None],
                     ao=None if ao is None else quantise_visibility(np.full((4, 2), ao)))
    return BakedAsset(key=f"ao-board-{key}-{ao}", source="board", format="test", meshes=[mesh], textures=[],
                      bounds=np.array([pos.min(0), pos.max(0)], np.float64))


def _centre(asset, env, method="opaque", **kw) -> np.ndarray:
    from renderer import render
    o = RenderOptions(width=32, height=32, tonemap="none", background="transparent", yaw=0.0, pitch=0.0,
                      fov=30.0, shadow=0.0, method=method, **kw)
    return render(asset, env, o).linear[13:19, 13:19, :3].reshape(-1, 3).mean(0)


@pytest.mark.parametrize("ao", [0.3, 0.7])
def test_raster_diffuse_drops_by_the_multibounce_factor(uniform_env, ao):
    # specular 0: no specular lobe, the board is its Lambert base alone
    m = Material(base_color=(0.8, 0.5, 0.2, 1.0), metallic=0.0, roughness=1.0, specular=0.0)
    open_ = _centre(_board(m, None, "d"), uniform_env)
    shut = _centre(_board(m, ao, "d"), uniform_env)
    np.testing.assert_allclose(open_, [0.8, 0.5, 0.2], rtol=0.02)
    stored = float(dequantise_visibility(quantise_visibility(np.array(ao))))  # as the bake keeps it
    expected = ao_multibounce(stored, np.array([0.8, 0.5, 0.2]))
    assert np.all(expected < 1) and np.all(expected >= ao)
    np.testing.assert_allclose(shut / open_, expected, rtol=0.01)


@pytest.mark.parametrize("roughness", [0.1, 0.5])
def test_raster_specular_occlusion_lowers_the_sky_reflection(uniform_env, roughness):
    m = Material(base_color=(0.9, 0.9, 0.9, 1.0), metallic=1.0, roughness=roughness)
    open_ = _centre(_board(m, None, f"s{roughness}"), uniform_env)
    shut = _centre(_board(m, 0.5, f"s{roughness}"), uniform_env)
    occluded = float(specular_occlusion(1.0, 0.5, roughness))  # N.V = 1 at the centre
    assert occluded < 1.0
    # lifted by the multi-bounce fit on F0 (the metal's colour): what its neighbours reflect
    expected = ao_multibounce(occluded, np.array([0.9, 0.9, 0.9]))
    assert np.all(expected < 1.0)
    np.testing.assert_allclose(shut / open_, expected, rtol=0.02)


def test_tree_diffuse_drops_by_the_same_factor(uniform_env):
    m = Material(base_color=(0.5, 0.5, 0.5, 1.0), metallic=0.0, roughness=1.0, specular=0.0)
    kw = {"supersample": 2}
    open_ = _centre(_board(m, None, "t"), uniform_env, "raytrace", **kw)
    shut = _centre(_board(m, 0.4, "t"), uniform_env, "raytrace", **kw)
    np.testing.assert_allclose(shut / open_, ao_multibounce(0.4, 0.5), rtol=0.01)


def test_punctual_light_is_not_occluded(tmp_path):
    dark = bake_environment("dark", tmp_path, face_size=16)
    m = Material(base_color=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=1.0, specular=0.0)
    light = Light(type="directional", color=(1.0, 1.0, 1.0), intensity=2.0,
                  matrix=np.eye(4))  # shines along -z, onto the board
    a, b = _board(m, None, "l"), _board(m, 0.2, "l")
    a, b = dataclasses.replace(a, lights=[light]), dataclasses.replace(b, lights=[light])
    lit = _centre(a, dark)
    assert lit.min() > 0.1
    np.testing.assert_allclose(_centre(b, dark), lit, rtol=1e-4)


def test_bake_round_trip(tmp_path):
    """build_baked bakes it into the meshes and the cache keeps it (format 9)."""
    from core.scene import Instance, Mesh, Scene
    plane, ball = _grid(10.0, 11), _sphere(1.0, (0.0, 1.05, 0.0))
    meshes = [Mesh("plane", *plane), Mesh("ball", *ball)]
    scene = Scene(source="test", format="test", meshes=meshes, materials=[Material()],
                  instances=[Instance(0, 0), Instance(1, 0)])
    baked = build_baked(scene)
    assert baked.manifest["stats"]["occlusion"]["rays"] > 0
    ao = baked.meshes[0].visibility()
    # the plane under the ball is split where its visibility varies (pipeline.occlusion)
    assert len(baked.meshes[0].positions) > len(plane[0])
    assert ao is not None and ao.shape == (len(baked.meshes[0].positions), 2) and ao.min() < 0.5
    off = build_baked(scene, options={"occlusion": False})
    assert all(m.ao is None for m in off.meshes)
    # USD's reference, usdview's Storm, draws no ambient occlusion: a stage bakes none unless asked
    usd = dataclasses.replace(scene, source="stage.usda", format="usd")
    assert all(m.ao is None for m in build_baked(usd).meshes)
    assert build_baked(usd, options={"occlusion": True}).meshes[0].ao is not None


def test_cache_keeps_the_occlusion(tmp_path):
    from tests.gltf_builder import cube
    baked = bake_asset(cube(tmp_path / "cube.glb"), tmp_path / "cache")
    ao = baked.meshes[0].ao
    assert ao is not None and ao.shape == (len(baked.meshes[0].positions), 2) and ao.dtype == np.uint8
    assert np.all(baked.meshes[0].visibility() == 1.0)  # a convex solid: nothing blocks its own sky
    again = load_baked(baked.key, tmp_path / "cache")
    np.testing.assert_array_equal(again.meshes[0].ao, ao)


# -- instanced meshes: a row per placement ---------------------------------------------------

def test_instances_get_a_row_each(assets, tmp_path):
    """SimpleInstancing's 125 cubes (one mesh, EXT_mesh_gpu_instancing, a 5 x 5 x 5 lattice):
    each placement keeps its own visibility, so the cube in the lattice's middle is darker
    than the corner cube at the origin, where one shared row (the mean of a few placements)
    gave every cube the same."""
    baked = bake_asset(assets / "gltf-samples" / "SimpleInstancing" / "glTF" / "SimpleInstancing.gltf", tmp_path)
    (mesh,) = baked.meshes
    k, n = len(mesh.transforms), len(mesh.positions)
    assert k == 125 and mesh.ao_per_placement and mesh.ao.shape == (k * n, 2)
    centres = mesh.transforms[:, :3, 3]
    middle = int(np.argmin(np.linalg.norm(centres - centres.mean(0), axis=1)))
    corner = int(np.argmin(np.linalg.norm(centres - centres.min(0), axis=1)))
    inner, outer = mesh.visibility(middle)[:, 0].mean(), mesh.visibility(corner)[:, 0].mean()
    assert inner < outer - 0.2, (inner, outer)


def test_shared_row_past_the_budget():
    """When every placement does not fit the budget at the fewest rays, the placements share
    one row (the mean of the first few), as before."""
    ball = _sphere(1.0, (0.0, 0.0, 0.0))
    xs = np.tile(np.eye(4), (6, 1, 1))
    xs[:, 0, 3] = np.arange(6) * 2.1
    mesh = BakedMesh("balls", *ball, Material(), xs)
    lo = (xs[:, :3, 3].min(0) - 1.0)
    bounds = np.array([lo, xs[:, :3, 3].max(0) + 1.0])
    apart = ambient_occlusion([mesh], bounds)
    assert apart.ao[0].shape == (6 * len(ball[0]), 2)
    shared = ambient_occlusion([mesh], bounds, max_rays=16 * 6 * len(ball[0]) - 1)
    assert shared.ao[0].shape == (len(ball[0]), 2)


def test_raster_reads_each_instances_row(uniform_env):
    """Three boards side by side, the middle one mirrored (drawn in the other winding's
    batch): each is shaded by its own row of the visibility."""
    m = Material(base_color=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=1.0, specular=0.0,
                 double_sided=True)
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    xs = np.tile(np.eye(4), (3, 1, 1))
    xs[:, 0, 3] = [-2.2, 0.0, 2.2]
    xs[1, 0, 0] = -1.0  # mirrored
    rows = np.repeat([0.2, 1.0, 0.6], 4)[:, None] * np.ones((1, 2))
    mesh = BakedMesh("boards", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), m, xs, ao=quantise_visibility(rows))
    assert mesh.ao_per_placement
    asset = BakedAsset(key="ao-rows-boards", source="boards", format="test", meshes=[mesh], textures=[],
                       bounds=np.array([[-3.2, -1, 0], [3.2, 1, 0]], np.float64))
    from renderer import render
    o = RenderOptions(width=96, height=32, tonemap="none", background="transparent", yaw=0.0, pitch=0.0,
                      fov=30.0, shadow=0.0, method="opaque")
    img = render(asset, uniform_env, o).linear[..., :3].mean(-1)
    cols = [img[12:20, c - 3:c + 3].mean() for c in (48 - 33, 48, 48 + 33)]
    expected = ao_multibounce(np.array([0.2, 1.0, 0.6]), 0.8) * 0.8
    assert np.all(img[16] >= 0)
    np.testing.assert_allclose(cols, expected, rtol=0.03)
