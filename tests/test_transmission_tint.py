"""One transmission-tint convention for volume glass, in the raster and both tracers (issues
26 and 30): each refraction through a volume's surface takes sqrt(base colour) of the texel it
crosses, as Cycles' Principled BSDF does (a glass sphere half (0.64, 0.16, 0.36), half
(0.16, 0.64, 0.36) seen through the middle gives Cycles 5.0 (0.32, 0.32, 0.36) = sqrt(A B) at
IOR 1, where a tint on entry alone would be A). A solid of one colour still tints by base;
thin-walled glass (one surface) keeps glTF's base colour once (tests/test_thin_walled.py).

Raster `wyman`, the tree tracer and the path tracer, each compiled kernel and its numpy twin.
The sphere is textured A on the camera's half and B on the far half, at IOR 1 (no Fresnel,
no bending) under a constant white sky: the centre pixels are the tint itself.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from test_render_physics import constant_env

from core.baked import BakedAsset, BakedMesh
from core.options import RenderOptions
from core.scene import NEAREST, Material, Sampler, Texture, TextureRef
from renderer import render

A_SRGB = (210, 110, 160)  # 8-bit sRGB texels: the camera's half and the far half
B_SRGB = (110, 210, 160)
SIZE = 48
TOL = 0.02  # relative, per channel: texture filtering at the seam is far from the centre


def _linear(srgb) -> np.ndarray:
    c = np.asarray(srgb, np.float64) / 255
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _sphere(key: str, near, far) -> BakedAsset:
    ico = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    pos = np.asarray(ico.vertices, np.float32)
    # a 2 x 1 texture, nearest: u = 0.25 on the camera's side (+z), 0.75 behind
    uv = np.stack([np.where(pos[:, 2] >= 0, 0.25, 0.75), np.full(len(pos), 0.5)], 1).astype(np.float32)
    img = np.full((1, 2, 4), 255, np.uint8)
    img[0, 0, :3], img[0, 1, :3] = near, far
    mat = Material(name="glass", base_color=(1.0, 1.0, 1.0, 1.0), metallic=0.0, roughness=0.0,
                   transmission=1.0, ior=1.0, thickness=2.0,
                   base_color_texture=TextureRef(0))
    mesh = BakedMesh("sphere", pos, pos / np.linalg.norm(pos, axis=1, keepdims=True),
                     np.asarray(ico.faces, np.uint32), mat, np.eye(4)[None], uv0=uv)
    tex = Texture("halves", img, Sampler(mag_filter=NEAREST, min_filter=NEAREST))
    return BakedAsset(key=f"tint-{key}", source="icosphere", format="test", meshes=[mesh],
                      textures=[tex], bounds=np.array([[-1.0, -1, -1], [1, 1, 1]]))


def _centre(asset: BakedAsset, method: str) -> np.ndarray:
    opts = RenderOptions(width=SIZE, height=SIZE, yaw=0.0, pitch=0.0, background="env",
                         method="raytrace" if method.startswith("raytrace") else method,  # type: ignore[arg-type]
                         integrator="path" if method == "raytrace-path" else "tree")
    frame = render(asset, constant_env(1.0), opts)
    c = SIZE // 2
    return frame.linear[c - 2:c + 2, c - 2:c + 2, :3].reshape(-1, 3).mean(0).astype(np.float64)


@pytest.mark.parametrize("method", ["wyman", "raytrace", "raytrace-path", "raytrace-numpy",
                                    "raytrace-path-numpy"])
def test_volume_glass_tints_by_sqrt_base_at_entry_and_exit(method, monkeypatch):
    if method.endswith("-numpy"):  # the compiled kernels' numpy twins
        from renderer.methods import path_trace, raytrace
        monkeypatch.setattr(path_trace if "path" in method else raytrace, "KERNEL", False)
        method = method.removesuffix("-numpy")
    a, b = _linear(A_SRGB), _linear(B_SRGB)
    seen = _centre(_sphere("ab", A_SRGB, B_SRGB), method)
    want = np.sqrt(a * b)
    assert np.allclose(seen, want, rtol=TOL), (method, seen, want)
    # the old entry-only tint (A) is far outside the tolerance: the test tells them apart
    assert not np.allclose(seen, a, rtol=5 * TOL)
    # one colour all round: base colour overall, as before
    seen_a = _centre(_sphere("aa", A_SRGB, A_SRGB), method)
    assert np.allclose(seen_a, a, rtol=TOL), (method, seen_a, a)

