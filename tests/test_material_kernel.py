"""renderer.methods.material_kernel (the compiled material at the tracer's hits) against its numpy
twin trace_material.evaluate, on real textured assets: every core field the Fresnel tree reads,
hit for hit, for rays from outside and bounced rays (texture levels from the ray cone)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_raytrace_textures import _quad

from core.options import RenderOptions
from core.scene import TextureRef
from pipeline.bake import bake_asset
from renderer.methods import raytrace, trace_scene
from renderer.methods.trace_material import MIRRORED_REPEAT

CORE = ("normal", "base", "metallic", "roughness", "transmission", "emission", "occlusion",
        "specular", "specular_color")
ASSETS = ["gltf/Duck.glb", "gltf/BoxTextured.glb", "gltf/CesiumMilkTruck.glb",
          "gltf/rgb_cube_with_primitives.gltf",
          "gltf-samples/TextureSettingsTest/glTF-Binary/TextureSettingsTest.glb",
          "gltf-samples/NegativeScaleTest/glTF-Binary/NegativeScaleTest.glb",
          "gltf-samples/SpecularTest/glTF-Binary/SpecularTest.glb",
          "gltf-samples/ClearCoatTest/glTF-Binary/ClearCoatTest.glb",
          "gltf-samples/SheenCloth/glTF/SheenCloth.gltf",
          "gltf-samples/IridescenceLamp/glTF/IridescenceLamp.gltf",
          "gltf-samples/AttenuationTest/glTF-Binary/AttenuationTest.glb"]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("material_kernel")


def _rays(ts, asset, n: int, seed: int):
    """Rays from a sphere around the asset at points inside its bounds, and their Embree hits."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(asset.bounds, np.float64)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2 + 1e-6
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origins = centre + 2.5 * radius * d
    target = lo + rng.random((n, 3)) * (hi - lo)
    dirs = target - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    prim, u, v, t = trace_scene.intersect_front(ts, origins, dirs)
    return origins, dirs, prim, u, v, t


def _both(ts, origins, dirs, prim, u, v, t, monkeypatch):
    fast = trace_scene.hit_material(ts, origins, dirs, prim, u, v, t, lobes=False)
    with monkeypatch.context() as m:
        m.setattr(trace_scene, "KERNEL", False)
        slow = trace_scene.hit_material(ts, origins, dirs, prim, u, v, t, lobes=False)
    return fast, slow


def _scene(asset, size=128):
    ts = raytrace.build_scene(asset, RenderOptions(width=size, height=size))
    ts.eye = np.asarray(asset.bounds, np.float64).mean(axis=0) + 10.0
    ts.spread = 2 * math.tan(math.radians(45) / 2) / size / 3
    return ts


@pytest.mark.parametrize("path", ASSETS)
def test_compiled_material_matches_numpy(assets, cache, path, monkeypatch):
    asset = bake_asset(assets / path, cache)
    ts = _scene(asset)
    origins, dirs, prim, u, v, t = _rays(ts, asset, 6000, seed=len(path))
    assert (prim >= 0).mean() > 0.2
    fast, slow = _both(ts, origins, dirs, prim, u, v, t, monkeypatch)
    for name in CORE:
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-9, atol=1e-9,
                                   err_msg=f"{path}: {name}")
    # a second bounce: rays leaving the hits (secondary footprints, back faces, inside hits)
    hit = prim >= 0
    p = origins[hit] + dirs[hit] * t[hit, None]
    rng = np.random.default_rng(7)
    d2 = rng.normal(size=p.shape)
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    o2 = p + 1e-3 * d2
    prim2, u2, v2, t2 = trace_scene.intersect_front(ts, o2, d2)
    fast, slow = _both(ts, o2, d2, prim2, u2, v2, t2, monkeypatch)
    for name in CORE:
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-9, atol=1e-9,
                                   err_msg=f"{path} (bounce 2): {name}")


def test_the_assets_exercise_every_core_input(assets, cache):
    """Not vacuous: the assets above carry every texture slot the kernel reads, a texture
    transform, baked tangents and baked AO (UV set 1 and vertex colours: the quads below)."""
    from renderer.methods.material_kernel import SLOTS
    seen: set[str] = set()
    transform = tangents = ao = False
    for path in ASSETS:
        surf = _scene(bake_asset(assets / path, cache)).surface
        for sm in surf.materials:
            seen |= set(sm.slots) & set(SLOTS)
            transform |= any(not np.allclose(s.uvm, np.eye(3)) for s in sm.slots.values())
        tangents |= surf.tangents is not None
        ao |= surf.ao is not None
    missing = set(SLOTS) - seen - {"transmission"}  # transmission: the quads below
    assert not missing, missing
    assert transform and tangents and ao, (transform, tangents, ao)  # UV set 1: the quads


@pytest.mark.parametrize("case", ["transform", "texcoord1", "mirrored", "transmission"])
def test_compiled_material_on_sampler_quads(case, monkeypatch):
    """Texture transform, UV set 1, mirrored repeat and nearest filtering (test_raytrace_textures'
    quads, the first with vertex colours), and a transmission texture with unlit off."""
    ref = {"transform": TextureRef(0, offset=(0.25, 0.1), rotation=0.4, scale=(0.6, 0.8)),
           "texcoord1": TextureRef(0, uv_set=1),
           "mirrored": TextureRef(0, offset=(-0.5, 0.3), scale=(2.5, 2.0)),
           "transmission": TextureRef(0, scale=(1.5, 1.5))}[case]
    asset = _quad(f"mk-quad-{case}", ref, MIRRORED_REPEAT if case == "mirrored" else 10497)
    if case == "transmission":
        mat = dataclasses.replace(asset.meshes[0].material, unlit=False, transmission=1.0,
                                  transmission_texture=ref, metallic=0.0)
        asset.meshes[0] = dataclasses.replace(asset.meshes[0], material=mat)
    if case == "transform":
        colours = np.random.default_rng(5).random((4, 4)).astype(np.float32)
        asset.meshes[0] = dataclasses.replace(asset.meshes[0], colors=colours)
    ts = _scene(asset, 64)
    assert ts.surface.materials[0].slots and (case != "transform" or ts.surface.colors is not None)
    origins, dirs, prim, u, v, t = _rays(ts, asset, 4000, seed=3)
    fast, slow = _both(ts, origins, dirs, prim, u, v, t, monkeypatch)
    assert (prim >= 0).mean() > 0.1
    for name in CORE:
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-9, atol=1e-9,
                                   err_msg=f"{case}: {name}")
    # the texture is read (the unlit quads emit it)
    read = fast.transmission if case == "transmission" else fast.emission
    assert np.ptp(read[prim >= 0]) > 0.1
