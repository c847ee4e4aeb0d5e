"""Hammersley points and the GGX directions drawn from them: the fixed sample sets with which
the prefilter (pipeline.environment.prefilter), the split-sum's horizon table (core.horizon)
and Storm's back-face table (core.storm) integrate their kernels once."""
from __future__ import annotations

import numpy as np


def radical_inverse(i: np.ndarray) -> np.ndarray:
    """Van der Corput in base 2 of 32-bit integers (their bits reversed), in [0, 1)."""
    b: np.ndarray = i.astype(np.uint32)
    b = (b << 16) | (b >> 16)
    b = ((b & 0x55555555) << 1) | ((b & 0xAAAAAAAA) >> 1)
    b = ((b & 0x33333333) << 2) | ((b & 0xCCCCCCCC) >> 2)
    b = ((b & 0x0F0F0F0F) << 4) | ((b & 0xF0F0F0F0) >> 4)
    b = ((b & 0x00FF00FF) << 8) | ((b & 0xFF00FF00) >> 8)
    return b.astype(np.float64) * 2.0 ** -32


def ggx_reflections(alpha: float, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The N = V = +z kernel's directions: GGX half vectors of `alpha` drawn from the `count`
    Hammersley points (cos from the radical inverse, azimuth (i + 0.5) / count turns) and
    +z reflected about them. (count x 3 directions l, count half-vector cosines)."""
    i = np.arange(count)
    xi = radical_inverse(i)
    phi = 2 * np.pi * (i + 0.5) / count
    cos_h = np.sqrt((1 - xi) / (1 + (alpha * alpha - 1) * xi))
    sin_h = np.sqrt(np.maximum(1 - cos_h * cos_h, 0))
    light = np.stack([2 * cos_h * sin_h * np.cos(phi), 2 * cos_h * sin_h * np.sin(phi),
                      2 * cos_h * cos_h - 1], axis=-1)
    return light, cos_h
