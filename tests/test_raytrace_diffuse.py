"""The Fresnel tree's diffuse share (method=raytrace, integrator=tree) and the raster's (its
baked irradiance cube) against the exact integral of the environment, and the path integrator,
on Lambert quads under coloured environments (issues 26 and 30).

The tree once read the roughest GGX mip along the normal for its diffuse share. That lobe is
not the cosine lobe, so under a blue sky a white board facing the horizon came out bluer than
the raster's SH irradiance and the path tracer's cosine-sampled integral (blue +13% on
footprint_court). It then read the bake's order-2 SH, as the raster does; that truncation is a
bias: on tinted_studio the floor read 1.2-1.5% under the exact integral of the cube's texels and
the board facing the horizon 0.9-1.3% over it (up to 3% per channel on footprint_court), which
is what the path integrator "read above the tree" (bench/RESULTS.md, "Path integrator against
the tree": the path and Mitsuba agree with the integral within their confidence intervals).
Now the tree integrates the texels (renderer.methods.env_irradiance) and the raster reads
the bake's irradiance cube, the same integral (core.irradiance) at 24 x 24 texels a face.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from core import irradiance
from core.baked import BakedAsset, BakedMesh
from core.cubemap import equirect_direction, face_directions
from core.options import RenderOptions
from core.scene import NEAREST, Material, Sampler, Texture, TextureRef
from pipeline.bake import bake_environment
from pipeline.environment.panorama import load_panorama, write_rgbe
from renderer import render
from renderer.methods import env_irradiance

# per-channel relative tolerances: the tree against the exact integral (measured within 0.1%);
# the path integrator against the tree and the integral (32 passes' noise over the quad:
# measured 0.2-0.6% white, up to 1.2% textured); the raster against the tree (its MSAA and
# texel edges: 1.5% textured); the raster's white board against the integral (the cube's
# bilinear reads)
TREE_EXACT = 0.003
PATH_TOLERANCE = 0.02
RASTER_TREE = 0.01
RASTER_EXACT = 0.005


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


def texel_irradiance(env, normal) -> np.ndarray:
    """E(n) / pi of the bake's sharpest cube level, summed over its texels (solid angle
    (2/S)^2 / (1 + s^2 + t^2)^1.5 each): what a white Lambert card facing `normal` reflects."""
    faces = np.asarray(env.specular[0], np.float64)
    s = faces.shape[1]
    c = (np.arange(s) + 0.5) / s * 2 - 1
    tc, sc = np.meshgrid(c, c, indexing="ij")
    domega = (2.0 / s) ** 2 / (1 + sc * sc + tc * tc) ** 1.5
    cos = np.maximum(face_directions(s) @ np.asarray(normal, np.float64), 0.0) * domega[None]
    return (faces * cos[..., None]).sum(axis=(0, 1, 2)) / np.pi


NORMALS = {"+z": (0.0, 0.0, 1.0), "+y": (0.0, 1.0, 0.0)}


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
    exact = texel_irradiance(env, NORMALS[normal])
    if not textured:  # 0.8 grey: the card reflects 0.8 E / pi (before: the SH, -1.5% on +y)
        assert np.all(np.abs(mean["tree"] / (0.8 * exact) - 1) < TREE_EXACT), (name, mean, 0.8 * exact)
        assert np.all(np.abs(mean["path"] / (0.8 * exact) - 1) < PATH_TOLERANCE), (name, mean, 0.8 * exact)
    assert np.all(np.abs(mean["tree"] / mean["path"] - 1) < PATH_TOLERANCE), (name, mean)
    # the raster reads the same integral from its irradiance cube
    limit = RASTER_TREE + (0.005 if textured else 0.0)
    assert np.all(np.abs(mean["raster"] / mean["tree"] - 1) < limit), (name, mean)
    if textured:  # same texels
        assert np.corrcoef(frames["raster"][covered, :3].ravel(),
                           frames["tree"][covered, :3].ravel())[0, 1] > 0.95


def test_irradiance_net_against_the_texels(coloured_env):
    """renderer.methods.env_irradiance: the net's bilinear reads at random normals against the
    sum over the texels (its block averaging and the net's interpolation: measured 0.45% at
    worst, 0.05% mean on tinted_studio), and the compiled sums against their numpy twin."""
    name, env = coloured_env
    rng = np.random.default_rng(3)
    n = rng.normal(size=(300, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    exact = np.array([texel_irradiance(env, x) for x in n])
    net = env_irradiance.irradiance_net(env.specular[0])
    err = np.abs(env_irradiance.read(net, n) / exact - 1)
    assert err.max() < 0.01 and err.mean() < 0.002, (name, err.max(), err.mean())
    small = np.ascontiguousarray(env.specular[0][:, ::8, ::8])
    assert np.allclose(env_irradiance.irradiance_net(small), env_irradiance.irradiance_net(small, compiled=False),
                       rtol=1e-10, atol=1e-12)


# (board normal, camera yaw, pitch): the camera 20-25 degrees off the normal
AXES = {"+x": ((1, 0, 0), 65.0, 20.0), "-x": ((-1, 0, 0), -115.0, 20.0), "+y": ((0, 1, 0), 35.0, 65.0),
        "-y": ((0, -1, 0), 35.0, -65.0), "+z": ((0, 0, 1), 25.0, 20.0), "-z": ((0, 0, -1), 205.0, 20.0)}


def _board(normal) -> BakedAsset:
    """A 0.8 grey Lambert board (IOR 1: no specular layer) through the origin facing `normal`."""
    n = np.asarray(normal, np.float64)
    t = np.cross(n, [0.3, 0.9, 0.2] if abs(n[1]) < 0.9 else [1.0, 0.2, 0.1])
    t /= np.linalg.norm(t)
    b = np.cross(n, t)  # t x b = n: the corners below wind counter-clockwise about n
    pos = np.array([-t - b, t - b, t + b, -t + b], np.float32)
    mat = Material(base_color=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=1.0, ior=1.0)
    mesh = BakedMesh("board", pos, np.tile(n.astype(np.float32), (4, 1)), np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                     mat, np.eye(4)[None])
    return BakedAsset(key=f"board-{normal}", source="board", format="test", meshes=[mesh], textures=[],
                      bounds=np.array([pos.min(0), pos.max(0)], np.float64))


@pytest.mark.parametrize("axis", list(AXES))
def test_raster_diffuse_matches_the_integral(coloured_env, axis):
    """Issue 30: the raster's diffuse image light is the exact cosine integral of the cube's
    texels (its baked irradiance cube), not the order-2 SH, whose truncation put these boards
    up to 1.5% (tinted_studio) and 3% (footprint_court) off a channel."""
    name, env = coloured_env
    normal, yaw, pitch = AXES[axis]
    o = RenderOptions(width=40, height=40, tonemap="none", background="transparent", yaw=yaw, pitch=pitch,
                      shadow=0.0, method="opaque")
    frame = render(_board(normal), env, o).linear
    covered = frame[..., 3] > 0.99
    assert covered.sum() > 0.2 * covered.size
    got = frame[covered, :3].mean(0)
    exact = 0.8 * irradiance.irradiance(env.specular[0], np.array(normal, np.float64))
    assert np.all(np.abs(got / exact - 1) < RASTER_EXACT), (name, axis, got, exact)


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
