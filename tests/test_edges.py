"""Edge anti-aliasing (renderer.raster.edges): which edges a view smooths, and what the smoothing
does to a frame: only pixels on an edge change, hidden edges change nothing, and frames it
cannot serve fall back to MSAA. Its quality against 16x supersampling is measured in
tests/test_antialiasing.py."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder

from core.adjacency import welded_edges
from core.cubemap import default_face_size
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment, load_baked
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from pipeline.ingest import load_scene
from renderer import render
from renderer.raster import edges

# The cube as an exporter writes it for flat shading: every face with vertices of its own.
SPLIT_POSITIONS = CUBE_POSITIONS[CUBE_INDICES.reshape(-1)]
SPLIT_INDICES = np.arange(len(SPLIT_POSITIONS), dtype=np.uint32).reshape(-1, 3)


def _keys(world: np.ndarray) -> set:
    return {tuple(sorted(map(tuple, np.round(seg, 6).tolist()))) for seg in world}


def test_adjacency_welds_split_vertices():
    adj = edges.adjacency(SPLIT_POSITIONS, SPLIT_INDICES)
    assert len(np.unique(adj.edges)) == 8  # one vertex named for each corner
    assert len(adj.edges) == 18  # 12 cube edges and 6 face diagonals
    assert (adj.faces[:, 1] >= 0).all()  # closed: no boundary


def test_a_mesh_without_faces_has_no_edges():
    for positions, indices in ((np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)),
                               (np.zeros((3, 3), np.float32), np.zeros(0, np.uint32))):
        adj = edges.adjacency(positions, indices)
        assert len(adj.edges) == 0
        assert edges.segments(adj, np.eye(4)[None], np.ones(3)).shape == (0, 2, 3)
    one = edges.adjacency(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]]))
    assert len(edges.segments(one, np.eye(4)[None], np.ones(3))) == 3  # its boundary, facing


def test_a_view_smooths_its_silhouette():
    adj = edges.adjacency(SPLIT_POSITIONS, SPLIT_INDICES)
    world = edges.segments(adj, np.eye(4)[None], np.array([5.0, 4.0, 3.0]))
    assert len(world) == 6  # the six-sided outline
    for corner in ([1.0, 1.0, 1.0], [-1.0, -1.0, -1.0]):  # nearest and farthest: inside it
        assert not any(np.any(np.all(np.isclose(s, corner), axis=1)) for s in world)
    # in front, a face-on view: the square outline alone
    assert len(edges.segments(adj, np.eye(4)[None], np.array([0.0, 0.0, 5.0]))) == 4


def test_instances_are_smoothed_where_they_stand_mirrored_or_not():
    adj = edges.adjacency(SPLIT_POSITIONS, SPLIT_INDICES)
    eye = np.array([5.0, 4.0, 3.0])
    move = np.eye(4)
    move[:3, 3] = (10.0, 0.0, 0.0)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    base = edges.segments(adj, np.eye(4)[None], eye)
    moved = edges.segments(adj, move[None], eye + move[:3, 3])
    assert _keys(moved) == _keys(base + move[:3, 3])
    mirrored = edges.segments(adj, mirror[None], eye * (-1.0, 1.0, 1.0))
    assert _keys(mirrored) == _keys(base * (-1.0, 1.0, 1.0))
    assert len(edges.segments(adj, np.stack([np.eye(4), move]), eye)) > len(base)
    flat = np.diag([1.0, 0.0, 1.0, 1.0])  # a scale-0 instance hides its mesh: no edges, no error
    assert _keys(edges.segments(adj, np.stack([flat, np.eye(4)]), eye)) == _keys(base)


def test_edges_are_clipped_to_the_view():
    """An edge through the near plane keeps its part in front; one off to the side is cut at
    the guard band; one behind the camera or wholly outside is dropped."""
    def clip(*ends):
        return edges._clip(np.array([ends], np.float64))
    inside = clip([0.2, 0.1, 0.5, 1.0], [0.4, -0.3, 0.2, 1.0])
    assert np.allclose(inside, [[[0.2, 0.1, 0.5, 1.0], [0.4, -0.3, 0.2, 1.0]]])
    through_near = clip([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, -3.0, -1.0])  # the far end behind
    assert len(through_near) == 1
    ndc = through_near[0, :, :3] / through_near[0, :, 3:]
    assert np.all(np.abs(ndc) <= 1.0 + 1e-9)
    wide = clip([0.0, 0.0, 0.0, 1.0], [1e6, 0.0, 0.0, 1.0])[0]
    assert np.isclose(wide[1, 0] / wide[1, 3], edges.GUARD)
    assert len(clip([0.0, 0.0, 2.0, -1.0], [1.0, 0.0, 2.0, -1.0])) == 0  # behind
    assert len(clip([5.0, 0.0, 0.0, 1.0], [6.0, 1.0, 0.0, 1.0])) == 0  # off to the side


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("edges")


def _cubes(tmp_path_factory, hidden: bool):
    """A dark cube, and (hidden) a small one straight behind it from the +Z camera."""
    b = Builder()
    dark = b.material(pbrMetallicRoughness={"baseColorFactor": [0.02, 0.02, 0.02, 1.0],
                                            "metallicFactor": 0.0, "roughnessFactor": 0.9})
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=dark), rotation=[0.0, 0.2588, 0.0, 0.9659])
    if hidden:
        b.node(b.mesh(CUBE_POSITIONS * 0.3, CUBE_INDICES, material=dark), translation=[0.0, 0.0, -3.0])
    return b.write(tmp_path_factory.mktemp("cubes") / f"cubes{int(hidden)}.glb")


VIEW = {"yaw": 0.0, "pitch": 10.0, "distance": 6.0, "target": (0.0, 0.0, 0.0), "shadow": 0.0,
        "background": "#ffffff"}


def _frames(asset, env, **look):
    o = RenderOptions(width=96, height=96, **{**VIEW, **look})
    return render(asset, env, o), render(asset, env, dataclasses.replace(o, msaa=0))


def test_only_pixels_on_an_edge_change(cache, tmp_path_factory):
    asset = bake_asset(_cubes(tmp_path_factory, False), cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    smooth, none = _frames(asset, env)
    assert smooth.plan["antialias"] == "edges" and none.plan["antialias"] == "none"
    a, b = smooth.rgba8[..., :3].astype(int), none.rgba8[..., :3].astype(int)
    changed = np.abs(a - b).max(axis=-1) > 0
    assert changed.sum() > 40, "the cube's outline was not smoothed"
    # Each pixel is mixed with one 4-neighbour: it moves toward that neighbour's value, by at
    # most the difference between the two (flat faces and the background stay as they were).
    pad = np.pad(b, ((1, 1), (1, 1), (0, 0)), mode="edge")
    near = [pad[1 + dy:97 + dy, 1 + dx:97 + dx] for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1))]
    reach = np.max([np.abs(n - b).max(axis=-1) for n in near], axis=0)
    moved = np.abs(a - b).max(axis=-1)
    assert (moved <= reach + 1).all(), (moved - reach).max()
    assert (moved[reach == 0] == 0).all()
    # smoothed outline pixels lie between the cube's grey and the white background
    lum = a.mean(axis=-1)
    assert ((lum[changed] > 40) & (lum[changed] < 230)).sum() > 20


def test_coverage_alpha_on_a_transparent_background(cache, tmp_path_factory):
    asset = bake_asset(_cubes(tmp_path_factory, False), cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    smooth, none = _frames(asset, env, background="transparent")
    assert set(np.unique(none.rgba8[..., 3])) <= {0, 255}
    partial = (smooth.rgba8[..., 3] > 0) & (smooth.rgba8[..., 3] < 255)
    assert partial.sum() > 40
    alpha = smooth.linear[..., 3]
    assert ((alpha > 0.01) & (alpha < 0.99)).sum() > 40  # the linear image's coverage too


def test_hidden_edges_change_nothing(cache, tmp_path_factory):
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    alone = bake_asset(_cubes(tmp_path_factory, False), cache)
    behind = bake_asset(_cubes(tmp_path_factory, True), cache)
    a, a_none = (f.rgba8.astype(int) for f in _frames(alone, env))
    b, b_none = (f.rgba8.astype(int) for f in _frames(behind, env))
    # with the hidden cube the two are one world-space batch (pipeline.batching): its bent
    # normals are rounded after the placement, not before, and the small cube occludes the
    # front cube's back faces; a level either way, and nothing of the small cube shows
    assert np.abs(a_none - b_none).max() <= 1
    # and its edges smooth nothing: the same pixels change, each by the same amount
    assert np.array_equal((a != a_none).any(axis=-1), (b != b_none).any(axis=-1))
    assert np.abs((a - a_none) - (b - b_none)).max() <= 1


def test_msaa_when_asked_for_or_when_the_frame_is_too_big(cache, assets, monkeypatch):
    asset = bake_asset(assets / "gltf/Duck.glb", cache)
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(64))
    o = RenderOptions(width=64, height=64)
    assert render(asset, env, o).plan["antialias"] == "edges"
    msaa = render(asset, env, dataclasses.replace(o, antialias="msaa"))
    assert msaa.plan["antialias"] == "msaa" and msaa.plan["msaa"] == 4
    monkeypatch.setattr(edges, "MAX_TRIANGLES", asset.triangle_count - 1)
    big = render(asset, env, o)
    assert big.plan["antialias"] == "msaa"
    assert np.array_equal(big.rgba8, msaa.rgba8)


# -- the welded edges baked with each mesh (core.adjacency) ----------------------------------

def _reference_edges(positions, indices):
    """What welded_edges says, by its definition, one Python dict at a time: points by their
    bytes, each edge's faces in the order corner pairs 01 (all faces), then 12, then 20."""
    keys = [p.tobytes() for p in np.asarray(positions)]  # welded by exact value: bytes
    point: dict = {}
    for k in keys:
        point.setdefault(k, len(point))
    pid = [point[k] for k in keys]
    first: dict = {}
    for v, p in enumerate(pid):
        first.setdefault(p, v)
    rank = {point[k]: r for r, k in enumerate(sorted(point))}  # the points in their bytes' order
    tri = np.asarray(indices).reshape(-1, 3)
    found: dict = {}
    for a, b in ((0, 1), (1, 2), (2, 0)):
        for f, t in enumerate(tri.tolist()):
            ends = sorted((pid[t[a]], pid[t[b]]), key=lambda p: rank[p])
            if ends[0] != ends[1]:
                found.setdefault(tuple(ends), []).append(f)
    out = sorted(found.items(), key=lambda kv: (rank[kv[0][0]], rank[kv[0][1]]))
    return (np.array([[first[a], first[b]] for (a, b), _ in out], np.uint32).reshape(-1, 2),
            np.array([[fs[0], fs[1] if len(fs) > 1 else -1] for _, fs in out], np.int32).reshape(-1, 2))


def test_welded_edges_by_their_definition(assets):
    """Non-manifold edges keep their first two faces, collapsed edges are dropped, points are
    welded by value; and on a real mesh, the same as the definition edge for edge."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [1, 0, 0]], np.float32)
    tri = np.array([[0, 1, 2], [1, 0, 3], [0, 5, 4], [0, 1, 1], [2, 2, 2]], np.uint32)
    e, f = welded_edges(pos, tri)
    ref = _reference_edges(pos, tri)
    np.testing.assert_array_equal(e, ref[0])
    np.testing.assert_array_equal(f, ref[1])
    shared = np.flatnonzero((np.sort(pos[e], axis=1) == np.sort(pos[[0, 1]], axis=0)).all(axis=(1, 2)))
    assert len(shared) == 1 and f[shared[0]].tolist() == [0, 1]  # four faces on it: the first two
    assert len(e) == 7  # 01 12 20, 03 31, 14 40: the collapsed 11 and the point 2 2 2 add none
    duck = load_scene(assets / "gltf/Duck.glb").meshes[0]
    e, f = welded_edges(duck.positions, duck.indices)
    ref = _reference_edges(duck.positions, duck.indices)
    np.testing.assert_array_equal(e, ref[0])
    np.testing.assert_array_equal(f, ref[1])


@pytest.mark.parametrize("name", ["usd/Teapot/Teapot.usd", "gltf/CesiumMilkTruck.glb", "gltf/Duck.glb"])
def test_baked_edges_are_those_a_render_would_build(name, assets, tmp_path):
    baked = bake_asset(assets / name, tmp_path)
    again = load_baked(baked.key, tmp_path)  # the cache round trip
    assert again.manifest["timings"]["adjacency_s"] >= 0
    for mesh in again.meshes:
        assert mesh.edges is not None and mesh.edge_faces is not None
        assert mesh.edges.dtype == np.uint32 and mesh.edge_faces.dtype == np.int32
        built = edges.adjacency(mesh.positions, mesh.indices)
        used = edges.of_mesh(mesh)
        for field in ("points", "edges", "faces", "normal", "offset"):
            np.testing.assert_array_equal(getattr(used, field), getattr(built, field))


def test_a_render_reads_the_baked_edges_and_matches_one_without(cache, assets, tmp_path, monkeypatch):
    """From a cache entry with edges the render computes none, and its pixels are those of a
    render from an entry baked without them (over the cap), which computes them."""
    from pipeline import bake
    from renderer.raster import gpu
    env = bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(96))
    with_edges = load_baked(bake_asset(assets / "gltf/Duck.glb", tmp_path / "a").key,
                                     tmp_path / "a")
    monkeypatch.setattr(bake, "MAX_TRIANGLES", 100)
    without = load_baked(bake_asset(assets / "gltf/Duck.glb", tmp_path / "b").key,
                                  tmp_path / "b")
    monkeypatch.undo()
    assert all(m.edges is None and m.edge_faces is None for m in without.meshes)
    o = RenderOptions(width=96, height=96)
    gpu.clear()  # the same key: each must be uploaded from its own entry
    with monkeypatch.context() as m:
        m.setattr(edges, "welded_edges", None)  # computing them would fail
        a = render(with_edges, env, o)
    gpu.clear()
    b = render(without, env, o)
    gpu.clear()
    assert a.plan["antialias"] == b.plan["antialias"] == "edges"
    assert np.array_equal(a.rgba8, b.rgba8)
