"""The Fresnel tree's diffuse share (method=raytrace, integrator=tree) against the raster and
the path integrator on Lambert quads under coloured environments (issue 26).

The tree once read the roughest GGX mip along the normal for its diffuse share. That lobe is
not the cosine lobe, so under a blue sky a white board facing the horizon came out bluer than
the raster's SH irradiance and the path tracer's cosine-sampled integral (blue +13% on
footprint_court). Now the tree reads the same baked SH as the raster: the same mean per
channel within 1% (1.5% textured). The path integrator integrates the environment itself; order-2 SH truncates
the irradiance by up to 3% per channel on footprint_court (its sun: measured 1.032 in blue
for a board facing +z against quadrature of the panorama) and by about 1% on the smooth studio.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from core.baked import BakedAsset, BakedMesh
from core.cubemap import equirect_direction
from core.options import RenderOptions
from core.scene import NEAREST, Material, Sampler, Texture, TextureRef
from pipeline.bake import bake_environment
from pipeline.environment.panorama import load_panorama, write_rgbe
from renderer import render

# per-channel relative tolerance of the path integrator against the SH (the truncation above
# plus 32 samples' noise over the quad; tinted_studio, +y: the path 1.2% to 1.5% over the tree
# at 512 passes; at 32 with the Sobol streams 1.7% to 2.1% white, 1.8% to 2.7% textured)
PATH_TOLERANCE = {"tinted_studio": 0.03, "footprint_court": 0.045}


@pytest.fixture(scope="module", params=["tinted_studio", "footprint_court"])
def coloured_env(request, tmp_path_factory):
    cache = tmp_path_factory.mktemp("diffuse_env")
    source = request.param
    if source == "tinted_studio":
        # the bundled studio, its upper half blue and its lower half warm: a coloured studio
        pixels = load_panorama("studio").pixels
        h, w = pixels.shape[:2]
        uu, vv = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
        up = equirect_direction(uu, vv)[..., 1:2] > 0
        tinted = pixels * np.where(up, [0.55, 0.75, 1.6], [1.5, 0.9, 0.45])
        source = str(cache / "tinted_studio.hdr")
        write_rgbe(source, tinted.astype(np.float32))
    return request.param, bake_environment(source, cache, face_size=128)


def _quad(normal: str, textured: bool) -> BakedAsset:
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float32)
    if normal == "+z":  # a board facing the horizon
        pos = np.stack([corners[:, 0], corners[:, 1], np.zeros(4, np.float32)], -1)
    else:  # a floor facing the sky
        pos = np.stack([corners[:, 0], np.zeros(4, np.float32), -corners[:, 1]], -1)
    n = np.array([0, 0, 1] if normal == "+z" else [0, 1, 0], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    textures: list[Any] = []  # a plain Texture: BakedAsset accepts it as tests elsewhere do
    # IOR 1: no specular layer, so all three integrate the Lambert lobe alone
    mat = Material(base_color=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=1.0, ior=1.0)
    if textured:
        rng = np.random.default_rng(5)
        img = rng.integers(40, 256, (4, 4, 4), dtype=np.uint8)  # coarse: texel edges move the mean little
        img[..., 3] = 255
        textures = [Texture("random", img, Sampler(mag_filter=NEAREST, min_filter=NEAREST))]
        mat = dataclasses.replace(mat, base_color=(1.0, 1.0, 1.0, 1.0), base_color_texture=TextureRef(0))
    mesh = BakedMesh("quad", pos, np.tile(n, (4, 1)), np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                     mat, np.eye(4)[None], uv0=uv)
    lo, hi = pos.min(0), pos.max(0)
    return BakedAsset(key=f"diffuse-quad-{normal}-{textured}", source="quad", format="test",
                      meshes=[mesh], textures=textures, bounds=np.array([lo, hi], np.float64))


@pytest.mark.parametrize("textured", [False, True], ids=["white", "textured"])
@pytest.mark.parametrize("normal", ["+z", "+y"])
def test_tree_diffuse_matches_raster_and_path(coloured_env, normal, textured):
    name, env = coloured_env
    asset = _quad(normal, textured)
    o = RenderOptions(width=48, height=48, tonemap="none", background="transparent", yaw=35.0,
                      pitch=25.0 if normal == "+z" else 60.0, shadow=0.0, samples=32, noise=0.0)
    options = {"raster": dataclasses.replace(o, method="opaque"),
               "tree": dataclasses.replace(o, method="raytrace"),
               "path": dataclasses.replace(o, method="raytrace", integrator="path")}
    frames = {k: render(asset, env, ok).linear for k, ok in options.items()}
    covered = np.logical_and.reduce([f[..., 3] > 0.99 for f in frames.values()])
    assert covered.sum() > 0.2 * covered.size
    mean = {k: f[covered, :3].mean(0) for k, f in frames.items()}
    assert mean["raster"].max() > 1.2 * mean["raster"].min()  # a coloured light
    # textured: the raster's MSAA and the tree's supersampling split edge pixels between
    # texels a little differently
    limit = 0.015 if textured else 0.01
    assert np.all(np.abs(mean["tree"] / mean["raster"] - 1) < limit), (name, mean)
    assert np.all(np.abs(mean["tree"] / mean["path"] - 1) < PATH_TOLERANCE[name]), (name, mean)
    if textured:  # same texels
        assert np.corrcoef(frames["raster"][covered, :3].ravel(),
                           frames["tree"][covered, :3].ravel())[0, 1] > 0.95


def _plain_quad(key: str, **material) -> BakedAsset:
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    mesh = BakedMesh("quad", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                     Material(metallic=0.0, roughness=0.3, **material), np.eye(4)[None])
    return BakedAsset(key=key, source="quad", format="test", meshes=[mesh], textures=[],
                      bounds=np.array([[-1.0, -1, 0], [1, 1, 0]]))


def test_tree_reads_khr_materials_specular(tmp_path):
    """KHR_materials_specular in the tree (optics.specular_tint): specular 0 leaves the Lambert
    base alone (as IOR 1 does), and a red specular colour over a black base reflects red."""
    env = bake_environment("footprint_court", tmp_path, face_size=128)
    o = RenderOptions(width=48, height=48, tonemap="none", background="transparent", yaw=35.0,
                      pitch=25.0, shadow=0.0, samples=32, noise=0.0)

    def mean(asset, **kw) -> np.ndarray:
        f = render(asset, env, dataclasses.replace(o, **kw)).linear
        return f[f[..., 3] > 0.99, :3].mean(0)

    grey = (0.8, 0.8, 0.8, 1.0)
    no_spec = mean(_plain_quad("spec0", base_color=grey, specular=0.0), method="raytrace")
    ior_one = mean(_plain_quad("ior1", base_color=grey, ior=1.0), method="raytrace")
    plain = mean(_plain_quad("plain", base_color=grey), method="raytrace")
    assert np.all(np.abs(no_spec / ior_one - 1) < 0.005), (no_spec, ior_one)
    assert np.all(no_spec > plain * 1.005)  # the specular layer's share went to the base
    red = _plain_quad("red-spec", base_color=(0.0, 0.0, 0.0, 1.0), specular_color=(1.0, 0.2, 0.2))
    tree, path = mean(red, method="raytrace"), mean(red, method="raytrace", integrator="path")
    assert tree[0] > 3 * tree[1] and tree[0] > 3 * tree[2], tree  # untinted: grey
    # measured 0.0062 against the path's 0.0050: the tree keeps the mirror direction of a
    # rough lobe and reads the prefiltered mip (see renderer/methods/raytrace.py)
    assert abs(tree[0] / path[0] - 1) < 0.3, (tree, path)
