"""The final pass drawn in regions (renderer.view.regions) writes exactly the pixels of one
full-screen pass doing all the work, and its regions hold every pixel the object reaches."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core import hull
from core.cubemap import default_face_size
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment, load_baked
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from renderer import render
from renderer.view import framing, regions
from renderer.view.framing import request_camera

SAMPLES = ["gltf/Duck.glb", "gltf-samples/SheenCloth/glTF/SheenCloth.gltf",
           "gltf-samples/SimpleInstancing/glTF/SimpleInstancing.gltf",
           "gltf-samples/NegativeScaleTest/glTF-Binary/NegativeScaleTest.glb",
           "gltf-samples/AttenuationTest/glTF/AttenuationTest.gltf"]  # refraction (wyman)
LOOKS = [{}, {"background": "transparent"}, {"background": "env"}, {"alpha": "coverage"},
         {"distance": 0.5, "background": "#203040"},  # close: the camera may be inside the hull
         {"yaw": 200.0, "pitch": -10.0, "shadow": 0.0}]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("regions")


def _one_pass(monkeypatch):
    """The final pass as a single full-screen draw with every piece of work in it."""
    monkeypatch.setattr(regions, "object_polygon", lambda *a: None)
    monkeypatch.setattr(regions, "object_rect", lambda *a: None)
    monkeypatch.setattr(regions, "screen_rect", lambda camera, points, w, h, pad=2: (0, 0, w, h))


@pytest.mark.parametrize("rel", SAMPLES)
def test_regions_write_the_pixels_of_one_full_screen_pass(assets, cache, rel, monkeypatch):
    asset = bake_asset(assets / rel, cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    base = RenderOptions(width=96, height=80)
    for look in LOOKS:
        o = dataclasses.replace(base, **look)
        split = render(asset, env, o)
        with monkeypatch.context() as m:
            _one_pass(m)
            whole = render(asset, env, o)
        assert np.array_equal(split.rgba8, whole.rgba8), (rel, look)
        assert np.array_equal(split.linear, whole.linear), (rel, look)


def test_object_polygon_holds_every_covered_pixel(assets, cache):
    """Every pixel with any coverage lies inside the silhouette bound, which is much
    smaller than the frame for the Duck (the work it saves)."""
    asset = bake_asset(assets / "gltf/Duck.glb", cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(128))
    o = RenderOptions(width=128, height=128, background="transparent", shadow=0.0)
    frame = render(asset, env, o)
    poly = regions.object_polygon(request_camera(asset, o), regions.hull_points(asset), 128, 128)
    assert poly is not None and len(poly) >= 3
    from matplotlib.path import Path as PolyPath
    ys, xs = np.nonzero(frame.linear[..., 3] > 0)
    inside = PolyPath(poly).contains_points(np.c_[xs + 0.5, ys + 0.5])
    assert inside.all(), f"{(~inside).sum()} covered pixels outside the bound"
    x, y = poly[:, 0], poly[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
    assert area < 0.6 * 128 * 128


@pytest.mark.parametrize("rel", SAMPLES[:3])
def test_object_rect_holds_every_covered_pixel(assets, cache, rel):
    """The edge-smoothed frame's bound (a rectangle) holds every pixel with any coverage,
    smoothed edges included, and is the polygon's bounding rectangle."""
    asset = bake_asset(assets / rel, cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(128))
    o = RenderOptions(width=128, height=112, background="transparent", shadow=0.0)
    frame = render(asset, env, o)
    assert frame.plan["antialias"] == "edges"
    camera = request_camera(asset, o)
    x, y, w, h = regions.object_rect(camera, regions.hull_points(asset), 128, 112)
    ys, xs = np.nonzero(frame.linear[..., 3] > 0)
    assert len(xs) and xs.min() >= x and xs.max() < x + w and ys.min() >= y and ys.max() < y + h
    poly = regions.object_polygon(camera, regions.hull_points(asset), 128, 112)
    assert (x, y, w, h) == regions.bounding_rect(poly, 128, 112)


def test_polygon_is_none_when_the_camera_is_among_the_points():
    from renderer.view.camera import Camera
    cam = Camera(np.zeros(3), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0]), 40.0,
                 64, 64, 0.01, 100.0)
    hull = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    assert regions.object_polygon(cam, hull, 64, 64) is None
    assert regions.object_rect(cam, hull, 64, 64) is None
    assert regions.screen_rect(cam, hull, 64, 64) == (0, 0, 64, 64)
    ahead = hull + [0.0, 0.0, -10.0]
    poly = regions.object_polygon(cam, ahead, 64, 64)
    assert poly is not None and 3 <= len(poly) <= 20
    assert (poly[:, 0].min() > 0) and (poly[:, 0].max() < 64)


def test_rect_subtraction_tiles_the_rest():
    a, b = (0, 0, 10, 8), (3, 2, 4, 3)
    parts = regions.subtract(a, b)
    cover = np.zeros((8, 10), int)
    for x, y, w, h in parts + [b]:
        cover[y:y + h, x:x + w] += 1
    assert (cover == 1).all()
    assert regions.subtract(a, (20, 20, 2, 2)) == [a]
    assert regions.intersect(a, (20, 20, 2, 2)) is None


def _unbaked(asset):
    """The asset without its baked hull and support points (and edges): the renderer computes
    them (core.hull, core.adjacency)."""
    meshes = [dataclasses.replace(m, support=None, edges=None, edge_faces=None) for m in asset.meshes]
    return dataclasses.replace(asset, key=asset.key + "#unbaked", hull=None, meshes=meshes)


def test_small_meshes_are_bounded_by_their_points_without_scipy(assets, cache, monkeypatch):
    """Up to DIRECT_POINTS the points bound the object as they are: no qhull (nor scipy's
    import, a quarter second of a cold render) and the same pixels as the hull's bound."""
    import sys
    from collections import OrderedDict
    asset = _unbaked(bake_asset(assets / "gltf/Duck.glb", cache))
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    o = RenderOptions(width=96, height=96)
    monkeypatch.setattr(regions, "_hulls", OrderedDict())
    monkeypatch.setitem(sys.modules, "scipy.spatial", None)  # importing it now fails
    direct = render(asset, env, o)
    assert len(regions.hull_points(asset)) == sum(len(m.positions) for m in asset.meshes)
    monkeypatch.undo()
    monkeypatch.setattr(hull, "DIRECT_POINTS", 4)
    monkeypatch.setattr(regions, "_hulls", OrderedDict())
    hulled = render(asset, env, o)
    assert len(regions.hull_points(asset)) < len(asset.meshes[0].positions)
    assert np.array_equal(direct.rgba8, hulled.rgba8) and np.array_equal(direct.linear, hulled.linear)


def test_big_meshes_are_bounded_by_their_boxes(assets, cache, monkeypatch):
    """Past MAX_HULL_MESH vertices a mesh is bounded by its box's corners (qhull's cost and
    the hull's size grow with the mesh): still every covered pixel inside, same pixels."""
    from collections import OrderedDict
    asset = _unbaked(bake_asset(assets / "gltf/Duck.glb", cache))
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    o = RenderOptions(width=96, height=96)
    exact = render(asset, env, o)
    monkeypatch.setattr(hull, "MAX_HULL_MESH", 10)
    monkeypatch.setattr(hull, "DIRECT_POINTS", 4)
    monkeypatch.setattr(regions, "_hulls", OrderedDict())
    assert len(regions.hull_points(asset)) == 8
    boxed = render(asset, env, o)
    assert np.array_equal(exact.rgba8, boxed.rgba8) and np.array_equal(exact.linear, boxed.linear)


@pytest.mark.parametrize("name", ["usd/Teapot/Teapot.usd", "mesh/bunny.ply", "gltf/CesiumMilkTruck.glb"])
def test_baked_hull_and_support_points_are_those_a_render_would_take(name, assets, cache, monkeypatch):
    """The bake stores the hull points and each mesh's support points (core.hull) a render
    would compute, read back from the cache; a render from them has the camera and draws the
    pixels of one that computes them."""
    baked = bake_asset(assets / name, cache)
    again = load_baked(baked.key, cache)
    assert again.hull is not None and len(again.hull) >= 4
    np.testing.assert_array_equal(again.hull, hull.hull_points(again.meshes))
    for m in again.meshes:
        assert m.support is not None and 4 <= len(m.support) <= max(256, len(m.positions))
        np.testing.assert_array_equal(m.support, hull.support_points(m.positions))
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    sizes: list[int] = []  # the framing takes the baked points, not every vertex
    monkeypatch.setattr(framing, "_framing_points", {})
    monkeypatch.setattr(framing, "support_points", lambda p: sizes.append(len(p)) or hull.support_points(p))
    request_camera(again, RenderOptions(width=96, height=96))
    assert sizes and max(sizes) <= sum(len(m.support) * len(m.transforms) for m in again.meshes)
    monkeypatch.undo()
    for o in (RenderOptions(width=96, height=96), RenderOptions(width=96, height=96, antialias="msaa")):
        a, b = render(again, env, o), render(_unbaked(again), env, o)
        assert a.plan["view"] == b.plan["view"]
        assert np.array_equal(a.rgba8, b.rgba8)


def test_a_cold_render_from_the_cache_imports_neither_scipy_nor_numba(assets, cache):
    """The Teapot's 30900 vertices are bounded by qhull at bake; a new process rendering it
    from the cache never imports scipy.spatial (0.25-0.45 s of a cold thumbnail), nor numba
    (0.25 s: the interior pass's kernels are for bakes)."""
    import subprocess
    import sys
    key = bake_asset(assets / "usd/Teapot/Teapot.usd", cache).key
    code = (f"import sys; from pipeline.bake import bake_environment, load_baked; from core.options import RenderOptions; from renderer import render; "
            f"from pipeline.environment.panorama import DEFAULT_ENVIRONMENT; from core.cubemap import default_face_size; "
            f"a = load_baked({key!r}, {str(cache)!r}); "
            f"e = bake_environment(DEFAULT_ENVIRONMENT, {str(cache)!r}, face_size=default_face_size(96)); "
            f"f = render(a, e, RenderOptions(width=96, height=96)); "
            f"print(f.plan['antialias'], sorted(m for m in sys.modules if m.startswith(('scipy.spatial', 'numba'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-2:] == ["edges", "[]"], out.stdout


def test_support_points_over_blocks_are_the_whole_products_extremes():
    """support_points works over blocks of points (the whole N x 256 product of a million-vertex
    mesh was the bake's multi-gigabyte peak); across blocks it keeps the same points."""
    rng = np.random.default_rng(5)
    points = rng.normal(size=(3 * hull.SUPPORT_BLOCK + 17, 3))
    points[-1] = points[0] * 3  # an extreme in the last, short block
    i = np.arange(256) + 0.5
    z = 1 - 2 * i / 256
    phi = np.pi * (1 + 5 ** 0.5) * i
    d = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    keep = np.zeros(len(points), bool)
    keep[np.argmax(points @ d.T, axis=0)] = True
    got = hull.support_points(points)
    assert np.array_equal(got, points[keep])
    assert any(np.array_equal(p, points[-1]) for p in got)
