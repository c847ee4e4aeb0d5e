"""Texel reads of the baked mip chains (all levels' RGBA8 rows stored flat), compiled (numba):
glTF's wrap modes, bilinear or nearest within a level, trilinear across levels, sRGB decoded
through a table. Shared by the tracer's texture lookups (renderer.methods.trace_material) and
the compiled material at the hits (renderer.methods.material_kernel)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.colour import srgb_decode

# Byte -> value in [0, 1], and byte -> linear for sRGB-encoded colour.
UNIT_LUT = np.arange(256) / 255.0
SRGB_LUT = srgb_decode(UNIT_LUT)


@njit(cache=True, inline="always")
def _wrap(i, n, mode):
    if mode == 33071:  # CLAMP_TO_EDGE
        return min(max(i, 0), n - 1)
    if mode == 33648:  # MIRRORED_REPEAT
        m = i % (2 * n)
        return m if m < n else 2 * n - 1 - m
    return i % n  # REPEAT


@njit(cache=True)
def texel_level(texels, offset, h, w, x, y, nearest, wrap_s, wrap_t, table, out, scale):
    """Add `scale` x the bilinear (or nearest) RGBA of one level at texel coordinates x, y."""
    x0f, y0f = math.floor(x), math.floor(y)
    fx, fy = x - x0f, y - y0f
    if nearest:
        fx, fy = float(round(fx)), float(round(fy))
    x0, y0 = int(x0f), int(y0f)
    xa, xb = _wrap(x0, w, wrap_s), _wrap(x0 + 1, w, wrap_s)
    ya, yb = _wrap(y0, h, wrap_t), _wrap(y0 + 1, h, wrap_t)
    for c in range(4):
        tab = table if c < 3 else UNIT_LUT
        v00, v01 = tab[texels[offset + ya * w + xa, c]], tab[texels[offset + ya * w + xb, c]]
        v10, v11 = tab[texels[offset + yb * w + xa, c]], tab[texels[offset + yb * w + xb, c]]
        out[c] += scale * ((v00 * (1 - fx) + v01 * fx) * (1 - fy) + (v10 * (1 - fx) + v11 * fx) * fy)


@njit(cache=True)
def sample_texture(texels, offsets, heights, widths, uv, lod, srgb, wrap_s, wrap_t, mag_nearest,
                   min_nearest, mip_mode):
    """N x 4 RGBA (sRGB colour decoded to linear) of a mip chain stored flat (`texels`: all
    levels' RGBA8 rows one after another, level l from offsets[l]) at `uv` (glTF: v = 0 is
    row 0) and level `lod`. mip_mode: 0 no mips (level 0), 1 nearest level, 2 linear."""
    n = len(uv)
    out = np.zeros((n, 4))
    top = len(offsets) - 1
    px = np.zeros(4)
    for i in range(n):
        level_f = min(max(lod[i], 0.0), float(top))
        if mip_mode == 0:
            level_f = 0.0
        elif mip_mode == 1:
            level_f = float(round(level_f))
        lo = int(math.floor(level_f))
        frac = level_f - lo
        nearest = min_nearest if lod[i] > 0 else mag_nearest
        px[:] = 0.0
        for level, weight in ((lo, 1.0 - frac), (min(lo + 1, top), frac)):
            if weight <= 0.0:
                continue
            h, w = heights[level], widths[level]
            texel_level(texels, offsets[level], h, w, uv[i, 0] * w - 0.5, uv[i, 1] * h - 0.5,
                         nearest, wrap_s, wrap_t, SRGB_LUT if srgb else UNIT_LUT, px, weight)
        for c in range(4):
            out[i, c] = px[c]
    return out


def warm() -> None:
    """Compile (or load from numba's cache) the texel kernel on empty arrays."""
    i64 = np.int64
    sample_texture(np.zeros((1, 4), np.uint8), np.zeros(1, i64), np.ones(1, i64), np.ones(1, i64),
                   np.zeros((0, 2)), np.zeros(0), True, 10497, 10497, False, False, 2)
