"""Texture mip chains as baked: capped at the size the largest thumbnail can show, box-filtered.

A thumbnail of S pixels shows about S texels across where a texture spans the frame (anything
finer is averaged away by the mip level GL picks); texture atlases map a part of the texture
across the object, so twice that is kept. A cache baked for thumbnails up to S px keeps each
texture at `texture_size_for(S)` and below, and a render of s px uploads only the levels from
`texture_size_for(s)` down.

Each level halves the one above (sizes rounded down, as GL's level sizes are) with a box over
the exact scale, so a non-power-of-two texture's odd edge is weighed in rather than dropped;
colour of sRGB textures is averaged in linear light and alpha linearly. A box beat Lanczos and
bicubic against a supersampled reference (docs/textures.md): the renderer's pixels are box
averages too. A first level below the source size is the mean of 2^k x 2^k source texels,
computed in one pass over row strips so an 8192^2 image never exists as floats whole. Levels
are RGBA8, row 0 at the top, level 0 first.
"""
from __future__ import annotations

import math

import numpy as np
from PIL import Image

from core.colour import srgb_encode, srgb_to_linear

MIP_FILTER = Image.Resampling.BOX  # measured against Lanczos and bicubic: docs/textures.md
_STRIP_TEXELS = 1 << 22  # source texels converted to float per step (64 MiB of float32 RGBA)


def texture_size_for(pixels: int) -> int:
    """The largest texture level a thumbnail of `pixels` (its longer side) can show: the power
    of two at or above twice its size (atlases), so 1024 px keeps 2048 texels and 300 px 1024.
    Measured: 1x lost detail (CesiumMilkTruck at 256 px: object FLIP 0.010; the 8k-texture Duck
    at 1024 px: 0.021), 2x none visible (README: Thumbnails)."""
    return 1 << max(0, math.ceil(math.log2(2 * max(1, int(pixels)))))


def mip_chain(image: np.ndarray, srgb: bool, cap: int | None = None) -> list[np.ndarray]:
    """RGBA8 levels of `image` (H x W x 4 uint8) from the first one no larger than `cap` on its
    longer side (the source itself when it fits) down to 1 x 1."""
    image = np.ascontiguousarray(image, np.uint8)
    h, w = image.shape[:2]
    factor = _factor(h, w, cap)
    if factor == 1:
        chain, cur = [image], _to_float(image, srgb)
    else:
        cur = _box(image, factor, srgb)
        chain = [_to_uint8(cur, srgb)]
    while cur.shape[0] > 1 or cur.shape[1] > 1:
        cur = _halve(cur)
        chain.append(_to_uint8(cur, srgb))
    return chain


def capped_size(height: int, width: int, cap: int | None) -> tuple[int, int]:
    """(h, w) of the level 0 that `mip_chain(image, srgb, cap)` keeps of a height x width image."""
    f = _factor(height, width, cap)
    return max(height // f, 1), max(width // f, 1)


def _factor(h: int, w: int, cap: int | None) -> int:
    """The power of two the source is reduced by: the first that brings its longer side to `cap`."""
    factor = 1
    while cap is not None and max(h // factor, w // factor) > max(cap, 1):
        factor *= 2
    return factor


def level_shapes(height: int, width: int) -> list[tuple[int, int]]:
    """(h, w) of every level of a chain whose level 0 is height x width."""
    shapes = [(height, width)]
    while height > 1 or width > 1:
        height, width = max(height // 2, 1), max(width // 2, 1)
        shapes.append((height, width))
    return shapes


def _to_float(img: np.ndarray, srgb: bool) -> np.ndarray:
    if not srgb:
        return img.astype(np.float32) / np.float32(255)
    out = np.empty(img.shape, np.float32)
    out[..., :3] = srgb_to_linear(img[..., :3])
    out[..., 3] = img[..., 3] / np.float32(255)
    return out


def _to_uint8(level: np.ndarray, srgb: bool) -> np.ndarray:
    out = level
    if srgb:
        out = level.copy()
        out[..., :3] = srgb_encode(out[..., :3])
    return np.ascontiguousarray(np.clip(out * 255 + 0.5, 0, 255).astype(np.uint8))


def _halve(cur: np.ndarray) -> np.ndarray:
    """The next level: each axis to half (rounded down, at least 1), resampled with
    MIP_FILTER over the exact scale (an odd edge's texel is weighed in, not dropped)."""
    h, w = cur.shape[:2]
    size = (max(w // 2, 1), max(h // 2, 1))
    out = np.empty((size[1], size[0], cur.shape[2]), np.float32)
    for c in range(cur.shape[2]):
        plane = Image.fromarray(np.ascontiguousarray(cur[..., c]), "F")
        out[..., c] = np.asarray(plane.resize(size, MIP_FILTER), np.float32)
    return np.clip(out, 0.0, 1.0, out=out)  # the filter's negative lobes can overshoot


def _box(img: np.ndarray, factor: int, srgb: bool) -> np.ndarray:
    """Mean of each factor x factor block (in linear light), as `log2(factor)` halvings give.
    A dimension smaller than `factor` is averaged whole (the halvings stop at 1 there)."""
    h, w = img.shape[:2]
    fy, fx = min(factor, _pow2_floor(h)), min(factor, _pow2_floor(w))
    oh, ow = h // fy, w // fx
    out = np.empty((oh, ow, 4), np.float32)
    rows = max(1, _STRIP_TEXELS // max(1, w * fy))
    for r0 in range(0, oh, rows):
        r1 = min(oh, r0 + rows)
        strip = _to_float(img[r0 * fy:r1 * fy, :ow * fx], srgb)
        out[r0:r1] = strip.reshape(r1 - r0, fy, ow, fx, 4).mean(axis=(1, 3), dtype=np.float32)
    return out


def _pow2_floor(n: int) -> int:
    return 1 << (max(1, n).bit_length() - 1)
