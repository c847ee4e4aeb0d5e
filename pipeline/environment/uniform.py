"""Uniform environments made in code: `uniform:R,G,B` (linear radiance), `dark` = no light.

What a USD stage with its own lights is rendered in when it has no textured dome (the studio
would add light Storm does not), and what an untextured UsdLux DomeLight is: radiance
colour x intensity x 2^exposure from every direction. This file is their "source" for the
bake key (pipeline.environment.panorama resolves the names to it); the radiance itself is a
bake option (pipeline.bake.bake_or_load_environment), so each value is its own entry.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

DARK = "dark"
PREFIX = "uniform:"
SOURCE = Path(__file__).resolve()
_NUMBER = r"[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?"
_UNIFORM = re.compile(rf"^uniform:({_NUMBER}),({_NUMBER}),({_NUMBER})$")
MAX_RADIANCE = 65504.0  # the half-float caches' ceiling (as panorama._sanitize clamps)


def name(rgb) -> str:
    """The source string of radiance `rgb` (rounded, so equal lights share one bake)."""
    r, g, b = (min(max(float(c), 0.0), MAX_RADIANCE) for c in rgb)
    return DARK if r == g == b == 0 else f"{PREFIX}{r:.6g},{g:.6g},{b:.6g}"


def parse(source) -> tuple[float, float, float] | None:
    """The radiance a source names, or None when it is not a uniform environment."""
    if not isinstance(source, str):
        return None
    if source == DARK:
        return (0.0, 0.0, 0.0)
    m = _UNIFORM.match(source)
    if not m:
        return None
    rgb = tuple(float(x) for x in m.groups())
    if not all(math.isfinite(c) and c <= MAX_RADIANCE for c in rgb):
        return None
    return rgb  # type: ignore[return-value]


def panorama(rgb, width: int = 64) -> np.ndarray:
    """A 2:1 equirect panorama of constant radiance (small: it has no detail to resolve)."""
    return np.broadcast_to(np.asarray(rgb, np.float32), (width // 2, width, 3)).copy()
