"""The `studio` environment: a soft grey photo studio made in code, the default light.

An HDR equirect panorama (linear radiance, `core.cubemap` convention): a grey room,
brighter toward the ceiling, with four large rectangular softboxes — a key light above and to
the right of the default three-quarter camera, a dimmer fill on the left, a long strip
overhead and a narrow rim light behind — so highlights and Fresnel read on metals and glass.
It is neutral (equal R, G, B everywhere) and scaled so a white Lambert surface facing the
default camera has radiance ~1.0, which the Khronos PBR Neutral tone map shows as near white
(sRGB ~0.95) rather than clipped.

This file is the environment's "source": `pipeline.environment.panorama` resolves the name `studio` to
it, so the bake cache key is this file's hash and editing the light here rebakes it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from core.cubemap import equirect_direction

NAME = "studio"
SOURCE = Path(__file__).resolve()
WIDTH = 1024  # as the bundled panoramas


@dataclass(frozen=True)
class Softbox:
    """A flat rectangular light seen from the centre: azimuth from +Z toward +X and elevation
    of its centre (degrees), angular half-width and half-height (degrees), radiance."""
    azimuth: float
    elevation: float
    half_width: float
    half_height: float
    radiance: float

    def direction(self) -> np.ndarray:
        az, el = math.radians(self.azimuth), math.radians(self.elevation)
        return np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])


SOFTBOXES = (
    Softbox(azimuth=60, elevation=35, half_width=22, half_height=16, radiance=5.0),     # key
    Softbox(azimuth=-65, elevation=20, half_width=26, half_height=18, radiance=1.6),    # fill
    Softbox(azimuth=0, elevation=88, half_width=34, half_height=9, radiance=2.0),       # top strip
    Softbox(azimuth=180, elevation=25, half_width=9, half_height=24, radiance=4.0),     # rim
)
CEILING, FLOOR = 0.5, 0.2  # room radiance straight up / straight down
EDGE = 0.08                   # softbox edge falloff, as a fraction of its half size


def radiance(d: np.ndarray) -> np.ndarray:
    """Studio radiance (scalar, grey) toward unit directions d (..., 3)."""
    y = d[..., 1]
    out = FLOOR + (CEILING - FLOOR) * (0.5 + 0.5 * np.tanh(2.0 * y))  # soft room gradient
    for box in SOFTBOXES:
        c = box.direction()
        right = np.cross([0.0, 1.0, 0.0], c)
        if np.linalg.norm(right) < 1e-6:  # overhead: any horizontal axis
            right = np.array([1.0, 0.0, 0.0])
        right /= np.linalg.norm(right)
        up = np.cross(c, right)
        facing = d @ c
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(facing > 0, (d @ right) / facing, np.inf)  # on the panel's plane
            t = np.where(facing > 0, (d @ up) / facing, np.inf)
        inside = (_soft_edge(np.abs(s) / math.tan(math.radians(box.half_width)))
                  * _soft_edge(np.abs(t) / math.tan(math.radians(box.half_height))))
        out = out + box.radiance * inside
    return out


def _soft_edge(x: np.ndarray) -> np.ndarray:
    """1 inside |x| < 1 - EDGE, 0 beyond 1, smooth between (no aliasing in mip 0)."""
    t = np.clip((1.0 - x) / EDGE, 0.0, 1.0)
    return t * t * (3 - 2 * t)


@lru_cache(maxsize=2)
def _panorama(width: int) -> np.ndarray:
    h = width // 2
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(h) + 0.5) / h
    d = equirect_direction(*np.meshgrid(u, v))
    grey = radiance(d).astype(np.float32)
    pixels = np.repeat(grey[..., None], 3, axis=-1)
    pixels.flags.writeable = False
    return pixels


def studio_panorama(width: int = WIDTH) -> np.ndarray:
    """width x width/2 x 3 float32 linear radiance (read-only, cached)."""
    return _panorama(width)
