"""raytrace's in-process cache of built Embree scenes (renderer.methods.raytrace._embree_scene)."""
from __future__ import annotations

import dataclasses

import numpy as np
from test_render_physics import constant_env, sphere_asset

from core.options import RenderOptions
from renderer.methods import raytrace
from renderer.methods.raytrace import build_scene, clear_scene_cache, render_raytrace


def test_a_second_frame_reuses_the_embree_scene_and_renders_the_same():
    """The second frame of one asset traces the first frame's Embree scene (plan
    embree_cached) and gives the same pixels; a clear forgets it."""
    clear_scene_cache()
    asset = sphere_asset(0.0, 0.3)
    env = constant_env(0.7)
    options = RenderOptions(width=24, height=24, method="raytrace", background="env", tonemap="none")
    first = render_raytrace(asset, env, options)
    second = render_raytrace(asset, env, options)
    assert first.plan["embree_cached"] is False and second.plan["embree_cached"] is True
    np.testing.assert_array_equal(first.linear, second.linear)
    assert first.linear[..., :3].max() > 0.1
    clear_scene_cache()
    assert render_raytrace(asset, env, options).plan["embree_cached"] is False


def test_the_cache_is_keyed_on_triangles_not_on_the_asset_key(monkeypatch):
    """An asset with the same key but moved vertices gets its own scene (no stale geometry),
    and the cache keeps scenes up to EMBREE_CACHE_BYTES, the oldest out first."""
    clear_scene_cache()
    a = sphere_asset(0.0, 0.3)
    mesh = a.meshes[0]
    moved = dataclasses.replace(a, meshes=[dataclasses.replace(mesh, positions=mesh.positions * 0.5)])
    assert moved.key == a.key
    ts_a, ts_b = build_scene(a), build_scene(moved)
    assert not ts_a.embree_cached and not ts_b.embree_cached
    o = np.array([[0.0, 0.0, 5.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]], np.float32)
    t_a = ts_a.embree.run(o, d, output=1)["tfar"][0]
    t_b = ts_b.embree.run(o, d, output=1)["tfar"][0]
    assert abs(t_a - 4.0) < 0.01 and abs(t_b - 4.5) < 0.01  # radius 1 and 0.5
    assert build_scene(a).embree_cached
    one = raytrace.scene_bytes(len(mesh.indices))
    assert raytrace.cached_scene_bytes() == 2 * one
    monkeypatch.setattr(raytrace, "EMBREE_CACHE_BYTES", 3 * one)  # room for three spheres
    for k in range(4):
        shrunk = dataclasses.replace(mesh, positions=mesh.positions * (0.9 - 0.05 * k))
        build_scene(dataclasses.replace(a, meshes=[shrunk]))
    assert raytrace.cached_scene_bytes() == 3 * one
    assert not build_scene(a).embree_cached  # the oldest went first


def test_a_scene_over_the_byte_budget_is_used_not_kept(monkeypatch):
    clear_scene_cache()
    a = sphere_asset(0.0, 0.3)
    monkeypatch.setattr(raytrace, "EMBREE_CACHE_BYTES", raytrace.scene_bytes(len(a.meshes[0].indices)) - 1)
    ts = build_scene(a)
    assert ts.embree.run(np.array([[0.0, 0.0, 5.0]], np.float32), np.array([[0.0, 0.0, -1.0]], np.float32),
                         output=1)["tfar"][0] < 5  # it traces
    assert raytrace.cached_scene_bytes() == 0 and not build_scene(a).embree_cached
