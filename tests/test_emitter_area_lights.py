"""The raster lights surfaces from emissive polygons (core.area_lights, shaders/area_lights.glsl):
the baked polygons, a grey card under one emissive quad against the analytic form factor, the
raster against the tree and the path integrator on an unoccluded emitter-lit card, and no
emitters leaving the frame as it was."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_emitter_light import HEIGHT, _analytic, _card_under_emitter, _options
from test_render_physics import constant_env

from core import area_lights
from core.baked import BakedAsset, BakedMesh
from core.scene import Material
from renderer.methods.raytrace import render_raytrace
from renderer.raster import passes
from renderer.raster.render import render


def _raster(**kw):
    return dataclasses.replace(_options(**kw), method="opaque")


def test_quad_is_one_polygon_light_with_its_radiance():
    lights = area_lights.extract(_card_under_emitter().meshes, [])
    assert len(lights) == 1 and lights.dropped == 0
    assert lights.mesh.tolist() == [1]  # the glow mesh; the card does not emit
    np.testing.assert_allclose(lights.radiance[0], [4.0, 4.0, 4.0])
    np.testing.assert_allclose(lights.normal[0], [0, 0, -1], atol=1e-12)  # faces the card
    np.testing.assert_allclose(sorted(map(tuple, lights.corners[0].round(6))),
                               [(-0.5, -0.5, HEIGHT), (-0.5, 0.5, HEIGHT), (0.5, -0.5, HEIGHT),
                                (0.5, 0.5, HEIGHT)])


def test_cube_faces_merge_and_the_cap_keeps_the_brightest():
    # six cubes of rising strength, each face two triangles: 36 quads, MAX_LIGHTS (16) kept:
    # the faces of the brightest cubes
    import trimesh
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    meshes = []
    for k in range(6):
        mat = Material(name=f"e{k}", base_color=(0, 0, 0, 1), emissive=(1.0, 0.5, 0.25),
                       emissive_strength=1.0 + k)
        x = np.eye(4)
        x[0, 3] = 2.0 * k
        meshes.append(BakedMesh(f"cube{k}", np.asarray(box.vertices, np.float32),
                                np.asarray(box.vertex_normals, np.float32),
                                np.asarray(box.faces, np.uint32), mat, x[None]))
    lights = area_lights.extract(meshes, [])
    assert len(lights) == area_lights.MAX_LIGHTS == 16 and lights.dropped == 20
    assert sorted(lights.mesh.tolist()) == [3] * 4 + [4] * 6 + [5] * 6
    assert (lights.corners[:, 3] != lights.corners[:, 2]).any(axis=1).all()  # all quads
    # each normal points out of its cube, away from the cube's centre
    centre = np.array([[2.0 * k, 0, 0] for k in lights.mesh])
    assert (np.einsum("ij,ij->i", lights.corners.mean(1) - centre, lights.normal) > 0.49).all()


def test_dim_and_unlit_emitters_are_not_lights():
    dim = Material(name="dim", emissive=(0.01, 0.01, 0.01))
    unlit = Material(name="unlit", emissive=(1.0, 1.0, 1.0), unlit=True)
    assert not area_lights.radiance_of(dim, []).any()
    assert not area_lights.radiance_of(unlit, []).any()


def test_usd_stages_have_none_as_storm_lights_nothing_from_emitters():
    meshes = _card_under_emitter().meshes
    assert len(area_lights.of_format("gltf", meshes, [])) == 1
    assert all(len(area_lights.of_format(f, meshes, [])) == 0 for f in ("usd", "usda", "usdc", "USDZ"))


def test_grey_card_matches_the_form_factor():
    """Lambert (IOR 1: no specular) under a black sky: every pixel on the card within 2% of
    albedo x L x the quad's form factor (the exact polygon irradiance, nothing sampled)."""
    asset = _card_under_emitter(roughness=1.0, ior=1.0)
    frame = render(asset, constant_env(0.0), _raster())
    assert frame.plan["area_lights"] == 1
    on, exact = _analytic(_raster(), asset)
    got = frame.linear[..., :3].mean(-1)[on]
    assert np.abs(got / exact[on] - 1).max() < 0.02


@pytest.mark.parametrize("roughness, metallic", [(1.0, 0.0), (0.5, 0.0), (0.3, 0.0), (0.5, 1.0), (0.3, 1.0)])
def test_raster_agrees_with_the_tracers_on_an_unoccluded_card(roughness, metallic):
    """A card with a specular lobe (IOR 1.5, or metal) under the quad, seen at 40 degrees:
    the card's mean radiance within 4% of the tree's and of the path integrator's (64 spp),
    and per pixel within 25% of the tree's mean (the analytic lobe is no fitted GGX: it has
    no tail past 90 degrees from the lobe's axis; measured 2-24%, worst on metal at 0.3)."""
    asset = _card_under_emitter(roughness=roughness, ior=1.5)
    if metallic:
        asset.meshes[0].material = dataclasses.replace(asset.meshes[0].material, metallic=1.0,
                                                       base_color=(0.8, 0.8, 0.8, 1.0))
        asset = dataclasses.replace(asset, key=asset.key + "-metal")  # its own GPU copy
    env = constant_env(0.0)
    opts = _raster(pitch=40.0)
    on, _ = _analytic(opts, asset)
    raster = render(asset, env, opts).linear[..., :3].mean(-1)[on]
    tree = render_raytrace(asset, env, dataclasses.replace(opts, method="raytrace")).linear[..., :3].mean(-1)[on]
    path = render_raytrace(asset, env, dataclasses.replace(opts, method="raytrace", integrator="path", samples=64,
                                                           noise=0.0, bounces=2)).linear[..., :3].mean(-1)[on]
    assert abs(raster.mean() / tree.mean() - 1) < 0.04
    assert abs(raster.mean() / path.mean() - 1) < 0.04
    assert np.abs(raster - tree).mean() / tree.mean() < 0.25


def test_an_emitter_does_not_light_itself():
    """A two-sided emissive card folded into an L: each leg faces the other, yet both are one
    mesh, so neither is lit by the other (only its own emission shows)."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [0, 1, 1]], np.float32)
    idx = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 5], [0, 5, 4]], np.uint32)
    glow = Material(name="glow", base_color=(0.8, 0.8, 0.8, 1.0), emissive=(1.0, 1.0, 1.0),
                    emissive_strength=2.0, double_sided=True, roughness=1.0, ior=1.0)
    mesh = BakedMesh("l", pos, np.tile([0, 0, 1], (6, 1)).astype(np.float32), idx, glow, np.eye(4)[None])
    asset = BakedAsset(key="l-emitter", source="test", format="test", meshes=[mesh], textures=[],
                       bounds=np.array([[0.0, 0, 0], [1, 1, 1]]))
    assert len(area_lights.extract(asset.meshes, [])) == 2
    frame = render(asset, constant_env(0.0), _raster(yaw=30.0, pitch=30.0))
    seen = frame.linear[..., :3][frame.linear[..., 3] > 0.99]
    # lit by the other leg it would gain up to 0.8 x 2 x its form factor (tens of %);
    # smoothed edges blend in the black background, so only an upper bound per pixel
    assert seen.max() < 2.0 * 1.001 and np.median(seen) == pytest.approx(2.0, rel=1e-4)


def test_no_emitters_leaves_the_frame_as_it_was(monkeypatch):
    """Without emitters the program is the one without area lights: the frame is bit-identical
    to one drawn with AREA_LIGHT_COUNT left undefined (the shader before area lights)."""
    asset = _card_under_emitter(radiance=0.0, roughness=0.5)
    env = constant_env(0.7)
    first = render(asset, env, _raster())
    assert first.plan["area_lights"] == 0
    defines = passes.frame_defines

    def without(*args, **kw):
        d = defines(*args, **kw)
        d.pop("AREA_LIGHT_COUNT")
        return d
    monkeypatch.setattr(passes, "frame_defines", without)
    second = render(asset, env, _raster())
    assert np.array_equal(first.rgba8, second.rgba8) and np.array_equal(first.linear, second.linear)


def test_the_bake_keeps_the_emitters_and_reads_them_back(tmp_path):
    """A glTF with two emissive cubes (KHR_materials_emissive_strength 4, and 1 under a half
    white emissive texture) and a plain one: 12 quads (the cube's triangle pairs merged), the
    texture's linear mean in the radiance, stored in the cache entry and read back as baked."""
    from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, png_bytes

    from pipeline.bake import bake_asset, load_baked
    b = Builder()
    half = np.zeros((2, 2, 3), np.uint8)
    half[:, 0] = 255
    tex = b.image(png_bytes(half))
    glow = b.material(emissiveFactor=[0.1, 0.5, 0.9], extensions={"KHR_materials_emissive_strength": {
        "emissiveStrength": 4.0}}, pbrMetallicRoughness={"baseColorFactor": [0, 0, 0, 1]})
    textured = b.material(emissiveFactor=[1.0, 1.0, 1.0], emissiveTexture={"index": tex})
    plain = b.material(pbrMetallicRoughness={"baseColorFactor": [0.8, 0.8, 0.8, 1]})
    for k, mat in enumerate((glow, textured, plain)):
        b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=mat), translation=[3.0 * k, 0, 0])
    b.doc["extensionsUsed"] = ["KHR_materials_emissive_strength"]
    path = b.write(tmp_path / "glow.glb")
    fresh = bake_asset(path, tmp_path / "cache")
    lights = fresh.area_lights
    assert lights is not None and len(lights) == 12 and lights.dropped == 0
    assert (lights.corners[:, 3] != lights.corners[:, 2]).any(axis=1).all()  # quads, not triangles
    radiance = sorted(map(tuple, np.unique(lights.radiance.round(4), axis=0)))
    assert radiance == [(0.4, 2.0, 3.6), (0.5, 0.5, 0.5)]
    areas = np.linalg.norm(np.cross(lights.corners[:, 2] - lights.corners[:, 0],
                                    lights.corners[:, 3] - lights.corners[:, 1]), axis=1) / 2
    np.testing.assert_allclose(areas, 4.0)  # each face of the 2 m cube whole
    again = load_baked(fresh.key, tmp_path / "cache").area_lights
    assert again is not None
    for name, value in lights.arrays().items():
        np.testing.assert_array_equal(again.arrays()[name], value)
