"""The ray tracer reads the baked material the raster path reads: textures (with their
transform, UV set, sampler and mip level), vertex colours, normal maps, alpha."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_render_physics import _LUT, constant_env, sphere_asset

from core.baked import BakedAsset, BakedMesh
from core.mips import mip_chain
from core.options import RenderOptions
from core.scene import NEAREST, Light, Material, Sampler, Texture, TextureRef
from pipeline.bake import bake_asset, bake_environment
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from renderer import render
from renderer.methods.trace_material import CLAMP_TO_EDGE, MIRRORED_REPEAT, TextureChain

SIZE = 128


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("rt_textures")


@pytest.fixture(scope="module")
def env(cache):
    return bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=128)


def _object(frame) -> tuple[np.ndarray, np.ndarray]:
    lin = frame.linear
    return lin[..., :3], lin[..., 3] > 0.99


@pytest.mark.parametrize("name", ["BoxTextured.glb", "Duck.glb"])
def test_textured_asset_matches_the_raster_and_is_deterministic(assets, cache, env, name):
    asset = bake_asset(assets / "gltf" / name, cache)
    o = RenderOptions(width=SIZE, height=SIZE, background="transparent", shadow=0.0)
    raster = render(asset, env, dataclasses.replace(o, method="opaque"))
    traced = render(asset, env, dataclasses.replace(o, method="raytrace"))
    again = render(asset, env, dataclasses.replace(o, method="raytrace"))
    assert np.isfinite(traced.linear).all()
    assert np.array_equal(traced.linear, again.linear)  # deterministic
    a, mask_a = _object(raster)
    b, mask_b = _object(traced)
    both = mask_a & mask_b
    assert both.sum() > 0.8 * mask_a.sum()  # same framing
    la, lb = a[both] @ [0.2126, 0.7152, 0.0722], b[both] @ [0.2126, 0.7152, 0.0722]
    chroma_a, chroma_b = a[both] / (a[both].sum(1, keepdims=True) + 1e-6), b[both] / (b[both].sum(1, keepdims=True) + 1e-6)
    # texture detail: per-pixel colour follows the raster's (an untextured white object: ~0)
    corr = np.corrcoef(chroma_a.ravel(), chroma_b.ravel())[0, 1]
    assert corr > 0.8, corr
    assert np.corrcoef(la, lb)[0, 1] > 0.6


def _chain(img, wrap=(10497, 10497), mag=9729, min_=9987):
    return TextureChain(mip_chain(img, srgb=False), False, wrap, mag, min_)


def test_sampler_reads_texel_centres_and_wraps():
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (8, 16, 4), dtype=np.uint8)
    ch = _chain(img)
    j, i = np.meshgrid(np.arange(16), np.arange(8))
    uv = np.stack([(j.ravel() + 0.5) / 16, (i.ravel() + 0.5) / 8], -1)
    got = ch.sample(uv, np.zeros(len(uv)))
    assert np.allclose(got, img.reshape(-1, 4) / 255.0)
    # repeat: one period over
    assert np.allclose(ch.sample(uv + [1.0, -2.0], np.zeros(len(uv))), got)
    # mirrored repeat: u in (1, 2) reads the image flipped left-right
    m = _chain(img, (MIRRORED_REPEAT, MIRRORED_REPEAT))
    flipped = m.sample(np.stack([2.0 - uv[:, 0], uv[:, 1]], -1), np.zeros(len(uv)))
    assert np.allclose(flipped, got)
    # clamp: far outside reads the edge texel
    c = _chain(img, (CLAMP_TO_EDGE, CLAMP_TO_EDGE))
    edge = c.sample(np.array([[5.0, 0.5 / 8]]), np.zeros(1))
    assert np.allclose(edge[0], img[0, 15] / 255.0)
    # a footprint of the whole texture reads the last level: the mean
    mean = ch.sample(np.array([[0.3, 0.7]]), np.array([10.0]))
    assert np.allclose(mean[0], ch.levels[-1][0, 0] / 255.0)


@pytest.mark.parametrize("albedo", [0.25, 0.75])
def test_directional_light_by_next_event_estimation(albedo):
    """As tests/test_render_materials.py's raster check: a directional light of E lux at N = V
    = L on a rough dielectric gives E (albedo (1 - E_spec) / pi + F0 D G / 4 (1 + FmsEms /
    FssEss)); nothing where the light does not reach."""
    e = 2.0
    asset = sphere_asset(0.0, 1.0, (albedo, albedo, albedo, 1.0))
    lit = dataclasses.replace(asset, key=asset.key + "-lit",
                              lights=[Light("directional", (1.0, 1.0, 1.0), e, matrix=np.eye(4))])
    o = RenderOptions(width=64, height=64, tonemap="none", background="transparent", yaw=0.0,
                      pitch=0.0, shadow=0.0, method="raytrace")
    f = render(lit, constant_env(0.0), o)
    c = 32
    got = f.linear[c - 1:c + 1, c - 1:c + 1, :3].mean()
    a, b = _LUT[-1, -1][:2]
    fss = 0.04 * a + b
    ems = 1 - (a + b)
    favg = 0.04 + 0.96 / 21
    fms = ems * fss * favg / (1 - ems * favg)
    expected = e * (albedo * (1 - fss - fms) / math.pi + 0.04 / (4 * math.pi) * (1 + fms / fss))
    assert abs(got / expected - 1) < 0.02, (got, expected)
    assert render(lit, constant_env(0.0), dataclasses.replace(o, lights=False)).linear[..., :3].max() == 0


def test_shadow_rays_find_the_occluder():
    """A second sphere behind the first along a directional light is in its shadow: nearly
    black (the environment is black), while the first sphere's lit side is not."""
    front = sphere_asset(0.0, 1.0)
    m = front.meshes[0]
    behind = np.eye(4)
    behind[0, 3] = -3.0
    pair = dataclasses.replace(
        front, key="pair", meshes=[dataclasses.replace(m, transforms=np.stack([np.eye(4), behind]))],
        bounds=np.array([[-4.0, -1, -1], [1, 1, 1]]),
        lights=[Light("directional", (1.0, 1.0, 1.0), 2.0,
                      matrix=np.array([[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1.0]]))])
    o = RenderOptions(width=96, height=64, tonemap="none", background="transparent", yaw=0.0,
                      pitch=0.0, shadow=0.0, method="raytrace")
    f = render(pair, constant_env(0.0), o)
    lum = f.linear[..., :3].sum(-1)
    cover = f.linear[..., 3] > 0.99
    cols = np.flatnonzero(cover.any(0))
    mid = (cols[0] + cols[-1]) // 2
    lit_side = lum[:, mid + 5:][cover[:, mid + 5:]].max()
    shadowed = lum[:, :mid - 5][cover[:, :mid - 5]].max()
    # what reaches the shadowed sphere is the lit one's light reflected once (interreflection)
    assert shadowed < 0.05 * lit_side, (shadowed, lit_side)


def _quad(key: str, ref: TextureRef, wrap: int = 10497) -> BakedAsset:
    """A unit quad facing +Z (keys start "rt-": the GPU cache holds uploads by key, and other test
    files make quads of other textures) with an 8 x 8 random texture (nearest), UV set 1 = set 0 flipped."""
    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (8, 8, 4), dtype=np.uint8)
    img[..., 3] = 255
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    mat = Material(base_color_texture=ref, unlit=True)
    mesh = BakedMesh("quad", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), mat, np.eye(4)[None], uv0=uv,
                     uv1=1.0 - uv)
    tex = Texture("random", img, Sampler(mag_filter=NEAREST, min_filter=NEAREST, wrap_s=wrap, wrap_t=wrap))
    return BakedAsset(key=key, source="quad", format="test", meshes=[mesh], textures=[tex],
                      bounds=np.array([[-1.0, -1, 0], [1, 1, 0]]))


@pytest.mark.parametrize("case", ["transform", "texcoord1", "mirrored"])
def test_texture_transform_uv_set_and_wrap_match_the_raster(case):
    ref = {"transform": TextureRef(0, offset=(0.25, 0.1), rotation=0.4, scale=(0.6, 0.8)),
           "texcoord1": TextureRef(0, uv_set=1),
           "mirrored": TextureRef(0, offset=(-0.5, 0.3), scale=(2.5, 2.0))}[case]
    asset = _quad(f"rt-quad-{case}", ref, MIRRORED_REPEAT if case == "mirrored" else 10497)
    o = RenderOptions(width=64, height=64, tonemap="none", background="transparent", yaw=0.0,
                      pitch=0.0, shadow=0.0)
    raster = render(asset, constant_env(0.0), dataclasses.replace(o, method="opaque")).linear
    traced = render(asset, constant_env(0.0), dataclasses.replace(o, method="raytrace")).linear
    both = (raster[..., 3] > 0.99) & (traced[..., 3] > 0.99)
    assert both.sum() > 0.3 * both.size
    diff = np.abs(raster[both, :3] - traced[both, :3])
    # texel edges differ where the tracer's 4 x 4 rays per pixel straddle them
    assert np.median(diff) < 0.01 and diff.mean() < 0.05, (np.median(diff), diff.mean())


def test_alpha_mask_and_blend_let_rays_through():
    ref = TextureRef(0)
    asset = _quad("rt-quad-alpha", ref)
    img = asset.textures[0].image.copy()
    img[..., 3] = np.where(np.indices((8, 8)).sum(0) % 2 == 0, 255, 0).astype(np.uint8)  # checker
    tex = Texture("checker", img, Sampler(mag_filter=NEAREST, min_filter=NEAREST))
    mesh = asset.meshes[0]
    o = RenderOptions(width=64, height=64, tonemap="none", background="transparent", yaw=0.0,
                      pitch=0.0, shadow=0.0)
    masked = dataclasses.replace(asset, key="rt-quad-mask", textures=[tex], meshes=[dataclasses.replace(
        mesh, material=dataclasses.replace(mesh.material, alpha_mode="MASK"))])
    raster = render(masked, constant_env(0.0), dataclasses.replace(o, method="opaque")).linear[..., 3]
    traced = render(masked, constant_env(0.0), dataclasses.replace(o, method="raytrace")).linear[..., 3]
    quad = render(asset, constant_env(0.0), dataclasses.replace(o, method="opaque")).linear[..., 3]
    assert 0.45 < traced.sum() / quad.sum() < 0.55               # half the texels are cut
    on = quad > 0.99
    assert np.corrcoef(raster[on], traced[on])[0, 1] > 0.9      # the same ones as the raster
    half = dataclasses.replace(asset, key="rt-quad-blend", meshes=[dataclasses.replace(
        mesh, material=dataclasses.replace(mesh.material, alpha_mode="BLEND",
                                           base_color=(1.0, 1.0, 1.0, 0.5)))])
    cover = render(half, constant_env(0.0), dataclasses.replace(o, method="raytrace")).linear[..., 3]
    inside = cover[24:40, 24:40]
    assert np.abs(inside - 0.5).max() <= 1 / 16 + 1e-6        # 4 x 4 stratified rays a pixel
