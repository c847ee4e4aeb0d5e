"""Material features: texture orientation and transform, alpha modes, double-sided, lights."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_render_physics import _LUT, constant_env, sphere_asset

from core.baked import BakedAsset, BakedMesh
from core.options import RenderOptions
from core.scene import NEAREST, Light, Material, Sampler, Texture, TextureRef
from renderer.raster.render import render

S = 96
RED, GREEN, BLUE, WHITE = (255, 0, 0, 255), (0, 255, 0, 255), (0, 0, 255, 255), (255, 255, 255, 255)


def quadrant_texture() -> Texture:
    """4 x 4 image, row 0 at the top: red | green over blue | white."""
    img = np.zeros((4, 4, 4), np.uint8)
    img[:2, :2], img[:2, 2:], img[2:, :2], img[2:, 2:] = RED, GREEN, BLUE, WHITE
    return Texture("quadrants", img, Sampler(mag_filter=NEAREST, min_filter=NEAREST))


def quad_asset(key: str, material: Material) -> BakedAsset:
    """A unit quad in the XY plane facing +Z, glTF UVs: (0, 0) at its top-left corner."""
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    mesh = BakedMesh("quad", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), material, np.eye(4)[None], uv0=uv)
    return BakedAsset(key=key, source="quad", format="test", meshes=[mesh],
                      textures=[quadrant_texture()], bounds=np.array([[-1.0, -1, 0], [1, 1, 0]]))


def opts(**kw) -> RenderOptions:
    # Seen straight on (yaw 0, pitch 0), no ground shadow: the tests read pixels at known places.
    return RenderOptions(**{"width": S, "height": S, "tonemap": "none", "background": "transparent",
                            "yaw": 0.0, "pitch": 0.0, "shadow": 0.0, **kw})


def unlit(**kw) -> Material:
    return Material(**{"base_color_texture": TextureRef(0), "unlit": True, **kw})


def quadrants(frame) -> list[tuple]:
    """Colour at the centre of each image quadrant: TL, TR, BL, BR (linear, rounded)."""
    q = S // 4
    return [tuple(np.round(frame.linear[y, x, :3], 2)) for y, x in ((q, q), (q, 3 * q), (3 * q, q), (3 * q, 3 * q))]


def test_textures_are_the_right_way_up():
    f = render(quad_asset("quad-unlit", unlit()), constant_env(0.0), opts())
    assert quadrants(f) == [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)]


def test_texture_transform_selects_the_top_right_quadrant():
    ref = TextureRef(0, offset=(0.5, 0.0), scale=(0.5, 0.5))
    f = render(quad_asset("quad-transform", unlit(base_color_texture=ref)), constant_env(0.0), opts())
    assert quadrants(f) == [(0, 1, 0)] * 4


def test_single_sided_is_culled_from_behind_and_double_sided_is_not():
    env = constant_env(0.0)
    back = opts(yaw=180)
    single = render(quad_asset("quad-single", unlit()), env, back)
    assert single.linear[..., 3].max() == 0
    double = render(quad_asset("quad-double", unlit(double_sided=True)), env, back)
    # Seen from behind, left and right swap.
    assert quadrants(double) == [(0, 1, 0), (1, 0, 0), (1, 1, 1), (0, 0, 1)]


def test_alpha_mask_and_blend():
    env = constant_env(1.0)
    c = S // 2
    masked = dataclasses.replace(sphere_asset(0.0, 1.0, (1, 1, 1, 0.3)), key="mask-0.3")
    masked.meshes[0].material = dataclasses.replace(masked.meshes[0].material, alpha_mode="MASK", alpha_cutoff=0.5)
    assert render(masked, env, opts()).linear[..., 3].max() == 0
    kept = dataclasses.replace(sphere_asset(0.0, 1.0, (1, 1, 1, 0.7)), key="mask-0.7")
    kept.meshes[0].material = dataclasses.replace(kept.meshes[0].material, alpha_mode="MASK", alpha_cutoff=0.5)
    assert render(kept, env, opts()).linear[c, c, 3] == 1
    glass = dataclasses.replace(sphere_asset(0.0, 1.0, (1, 1, 1, 0.5)), key="blend-0.5")
    glass.meshes[0].material = dataclasses.replace(glass.meshes[0].material, alpha_mode="BLEND")
    f = render(glass, env, opts())
    assert abs(f.linear[c, c, 3] - 0.5) < 0.01
    assert f.rgba8[c, c, 3] in (127, 128)


@pytest.mark.parametrize("albedo", [0.25, 0.75])
def test_directional_light_on_a_rough_dielectric(albedo):
    """KHR_lights_punctual directional light of E lux straight at the camera-facing point
    (N = V = L): radiance = E (albedo (1 - E_spec) / pi + F0 D G / 4 x (1 + FmsEms / FssEss))
    with D = 1/pi, G = 1 at roughness 1: the diffuse base gets what the specular lobe's
    directional albedo E_spec = FssEss + FmsEms leaves (glTF's energy-conserving layering; the
    split-sum LUT at N.V = 1, roughness 1), and the lobe carries its multiple scattering."""
    E = 2.0
    asset = sphere_asset(0.0, 1.0, (albedo, albedo, albedo, 1.0))
    lit = dataclasses.replace(asset, key=asset.key + "-lit",
                              lights=[Light("directional", (1.0, 1.0, 1.0), E, matrix=np.eye(4))])
    f = render(lit, constant_env(0.0), opts())
    c = S // 2
    got = f.linear[c - 1:c + 2, c - 1:c + 2, :3].mean()
    a, b = _LUT[-1, -1][:2]
    fss = 0.04 * a + b
    ems = 1 - (a + b)
    favg = 0.04 + 0.96 / 21
    fms = ems * fss * favg / (1 - ems * favg)
    expected = E * (albedo * (1 - fss - fms) / math.pi + 0.04 / (4 * math.pi) * (1 + fms / fss))
    assert abs(got / expected - 1) < 0.01
    assert render(lit, constant_env(0.0), opts(lights=False)).linear[c, c, :3].max() == 0
