"""Colour conventions: sRGB (IEC 61966-2-1) <-> linear. Textures and LDR panoramas are sRGB
and become linear when decoded or sampled; all shading is linear."""
from __future__ import annotations

import numpy as np


def srgb_decode(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values -> linear, float64 (IEC 61966-2-1; below 0 stays linear)."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.04045, x / 12.92, (np.maximum(x + 0.055, 0.0) / 1.055) ** 2.4)


def srgb_to_linear(rgb8: np.ndarray) -> np.ndarray:
    """uint8 sRGB -> float32 linear (IEC 61966-2-1), through a 256-entry table."""
    table = srgb_decode(np.arange(256, dtype=np.float64) / 255.0).astype(np.float32)
    return table[rgb8]


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear (clipped to 0..1) -> sRGB-encoded float in 0..1 (IEC 61966-2-1)."""
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
