"""Baked textures: mip chains capped for the thumbnails served, compressed, uploaded by need."""
from __future__ import annotations

import pickle

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, png_bytes

from core.mips import level_shapes, mip_chain, texture_size_for
from pipeline.bake import bake_asset, load_baked
from pipeline.cache import CorruptEntry


def _srgb_to_linear(c):
    c = c / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(x):
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _box_reference(img: np.ndarray, k: int, srgb: bool) -> np.ndarray:
    """Independent float64 k x k box filter: colour in linear light (sRGB), alpha linear;
    unrounded, in 8-bit units."""
    h, w = img.shape[0] // k, img.shape[1] // k
    f = img[:h * k, :w * k].astype(np.float64)
    if srgb:
        f[..., :3] = _srgb_to_linear(f[..., :3])
        f[..., 3] /= 255
    else:
        f /= 255
    mean = f.reshape(h, k, w, k, 4).mean(axis=(1, 3))
    if srgb:
        mean[..., :3] = _linear_to_srgb(mean[..., :3])
    return mean * 255


def _assert_rounded(level: np.ndarray, exact: np.ndarray) -> None:
    """Each texel is the exact value rounded to nearest (a tie may go either way)."""
    assert np.abs(level - exact).max() <= 0.5 + 1e-3


def checkerboard(size: int, square: int = 3) -> np.ndarray:
    """Squares of 3 texels, so 4 x 4 blocks mix both colours in many proportions."""
    y, x = np.mgrid[:size, :size]
    odd = ((y // square + x // square) % 2).astype(bool)
    img = np.empty((size, size, 4), np.uint8)
    img[~odd] = (250, 30, 0, 255)
    img[odd] = (10, 90, 200, 64)
    return img


@pytest.mark.parametrize("srgb", [True, False])
def test_checkerboard_four_times_the_cap_mip0_is_the_box_filter(srgb):
    """A source 4x the cap: level 0 is its 4 x 4 box. mip_chain has no size-specific path, so a
    1024 px source at cap 256 proves what a 4096 px one at the 1024 default does, at 1/16 of
    the cost (8k textures through a whole bake and render are `asset-preview bench thumbnail`)."""
    img = checkerboard(1024)
    chain = mip_chain(img, srgb, cap=256)
    assert [c.shape[:2] for c in chain] == level_shapes(256, 256)
    assert chain[-1].shape == (1, 1, 4) and all(c.dtype == np.uint8 for c in chain)
    _assert_rounded(chain[0], _box_reference(img, 4, srgb))
    assert len(np.unique(chain[0][..., 0])) >= 3  # the blocks really are mixtures
    # every further level is the box over the source's texels: level 3 = 32 x 32 of the source
    _assert_rounded(chain[3], _box_reference(img, 32, srgb))


def test_under_the_cap_mip0_is_the_source_and_levels_have_gl_sizes():
    img = np.random.default_rng(1).integers(0, 256, (300, 517, 4), dtype=np.uint8)
    chain = mip_chain(img, True, cap=1024)
    np.testing.assert_array_equal(chain[0], img)
    assert [c.shape[:2] for c in chain] == level_shapes(300, 517)
    assert chain[1].shape[:2] == (150, 258)
    assert texture_size_for(1024) == 2048 and texture_size_for(300) == 1024 and texture_size_for(1) == 2


def test_odd_edge_is_weighed_in_not_dropped():
    """A non-power-of-two texture loses nothing at its odd edge: a white last column of a
    black 5-wide image reaches level 1 (2 wide; a 2x2 box drops that column), on its own
    side; and a constant image stays constant at every level."""
    img = np.zeros((4, 5, 4), np.uint8)
    img[..., 3] = 255
    img[:, 4, :3] = 255
    chain = mip_chain(img, False)
    assert chain[1].shape[:2] == (2, 2)
    assert (chain[1][:, 1, 0] >= 255 / 5).all() and (chain[1][:, 0, 0] == 0).all()
    flat = np.full((37, 91, 4), 200, np.uint8)
    assert all((lv == 200).all() for lv in mip_chain(flat, True))


def _textured_cube(path, texture: np.ndarray):
    b = Builder()
    tex = b.image(png_bytes(texture))
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": {"index": tex},
                                           "metallicRoughnessTexture": {"index": tex}})
    uv = (CUBE_POSITIONS[:, :2] + 1) / 2
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=mat, TEXCOORD_0=uv))
    return b.write(path)


def test_bake_stores_capped_compressed_chains_and_renders_upload_by_need(tmp_path):
    from test_render_physics import constant_env

    from core.options import RenderOptions
    from renderer.raster import gpu
    from renderer.raster.render import render

    img = checkerboard(2048)
    src = _textured_cube(tmp_path / "cube.glb", img)
    baked = bake_asset(src, tmp_path / "cache", thumbnail_size=256)  # keeps 512 texels
    entry = tmp_path / "cache" / "assets" / baked.key
    files = sorted(p.name for p in entry.glob("texture.*"))
    assert files == ["texture.0.linear.zst", "texture.0.srgb.zst"]  # colour and data uses
    raw = 4 * sum(h * w for h, w in level_shapes(512, 512))
    assert sum((entry / f).stat().st_size for f in files) < raw  # compressed (a checkerboard: much)
    loaded = load_baked(baked.key, tmp_path / "cache")
    tex = loaded.textures[0]
    assert tex.size == (512, 512) and tex.spaces == (True, False)
    np.testing.assert_array_equal(tex.mips(True)[0], baked.textures[0].mips(True)[0])
    _assert_rounded(tex.mips(False)[0], _box_reference(img, 4, False))
    pickle.loads(pickle.dumps(loaded.textures[0]))  # picklable (process pools)
    # a small render decompresses only the levels it needs (stored smallest first)
    fresh = load_baked(baked.key, tmp_path / "cache").textures[0]
    small = fresh.mips(True, 64)
    assert small[0].shape == (64, 64, 4) and fresh._chains[True][0].shape == (64, 64, 4)
    np.testing.assert_array_equal(small[0], baked.textures[0].mips(True)[3])
    assert fresh.mips(True)[0].shape == (512, 512, 4)  # sharper levels: read again, whole

    gpu.clear()
    opts = dict(tonemap="none", background="transparent", yaw=30.0, pitch=20.0)
    render(loaded, constant_env(1.0), RenderOptions(width=64, height=64, **opts))
    gasset = gpu._assets[loaded.key]
    # levels up to twice the render's size (atlases), no sharper
    assert {k: v[0] for k, v in gasset.texture_levels.items()} == {(0, True): (128, 128), (0, False): (128, 128)}
    # trilinear with the anisotropic footprint (the context has GL_EXT_texture_filter_anisotropic)
    assert all(t.anisotropy == min(16.0, t.ctx.max_anisotropy) > 1 for t in gasset.textures.values())
    small_bytes = gasset.nbytes
    render(loaded, constant_env(1.0), RenderOptions(width=200, height=150, **opts))
    assert gasset.texture_levels[(0, True)][0] == (512, 512)  # sharper levels, same GL texture
    assert gasset.nbytes > small_bytes
    render(loaded, constant_env(1.0), RenderOptions(width=64, height=64, **opts))
    assert gasset.texture_levels[(0, True)][0] == (512, 512)  # never re-uploaded coarser


def test_corrupt_compressed_texture_is_detected(tmp_path):
    src = _textured_cube(tmp_path / "cube.glb", checkerboard(64))
    key = bake_asset(src, tmp_path / "cache").key
    f = tmp_path / "cache" / "assets" / key / "texture.0.srgb.zst"
    data = bytearray(f.read_bytes())
    data[len(data) // 2] ^= 0x01
    f.write_bytes(bytes(data))
    with pytest.raises(CorruptEntry):
        load_baked(key, tmp_path / "cache").textures[0].mips(True)
    assert not (tmp_path / "cache" / "assets" / key).exists()
