"""Thumbnail encoding: PNGs decode to exactly the frame's pixels; JPEG and WebP are what they say."""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from renderer.frame import Frame, encode_png


def _frame(rgba8: np.ndarray) -> Frame:
    return Frame(linear=np.zeros(rgba8.shape, np.float32), rgba8=rgba8)


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (64, 65), (257, 256)])
@pytest.mark.parametrize("opaque", [True, False])
def test_png_decodes_to_the_same_pixels(shape, opaque):
    rng = np.random.default_rng(sum(shape))
    px = rng.integers(0, 256, shape + (4,), dtype=np.uint8)
    px[: shape[0] // 2] = px[0, 0]  # flat rows too (long runs for deflate)
    if opaque:
        px[..., 3] = 255
    data = _frame(px).encode("png")
    img = Image.open(io.BytesIO(data))
    assert img.mode == ("RGB" if opaque else "RGBA") and img.size == (shape[1], shape[0])
    np.testing.assert_array_equal(np.asarray(img), px[..., :3] if opaque else px)


def test_png_of_a_rendered_frame_is_bit_exact_and_compressed():
    from test_render_physics import constant_env, sphere_asset

    from core.options import RenderOptions
    from renderer.raster.render import render
    f = render(sphere_asset(0.0, 0.5), constant_env(1.0),
               RenderOptions(width=96, height=96, background="transparent"))
    data = f.encode("png")
    np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(data))), f.rgba8)
    assert len(data) < f.rgba8.nbytes / 2


def test_png_of_non_contiguous_pixels():
    px = np.arange(5 * 8 * 4, dtype=np.uint8).reshape(5, 8, 4)[:, ::2]
    np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(encode_png(px)))), px)


def test_jpeg_and_webp_decode_to_close_pixels():
    y, x = np.mgrid[:64, :64]
    px = np.stack([x * 4, y * 4, (x + y) * 2, np.full_like(x, 255)], -1).astype(np.uint8)
    for fmt in ("jpeg", "webp"):
        img = Image.open(io.BytesIO(_frame(px).encode(fmt)))
        assert img.format == fmt.upper() and img.size == (64, 64)
        assert np.abs(np.asarray(img.convert("RGB"), np.int16) - px[..., :3]).mean() < 3


def test_webp_keeps_alpha_close():
    """WebP's lossy alpha (WEBP_SETTINGS) keeps a soft edge and a shadow ramp within 10/255,
    and fully transparent and fully opaque pixels exactly."""
    y, x = np.mgrid[:96, :96]
    alpha = np.clip((x - 16) * 4, 0, 255)  # transparent, a ramp, opaque
    px = np.stack([x * 2, y * 2, np.full_like(x, 128), alpha], -1).astype(np.uint8)
    img = Image.open(io.BytesIO(_frame(px).encode("webp")))
    assert img.mode == "RGBA"
    a = np.asarray(img, np.int16)[..., 3]
    assert np.abs(a - alpha).max() <= 10
    assert np.all(a[alpha == 0] == 0) and np.all(a[alpha == 255] == 255)
