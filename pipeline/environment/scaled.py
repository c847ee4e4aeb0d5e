"""A panorama file times a linear RGB factor: `scaled:R,G,B:PATH`.

What a textured UsdLux DomeLight is: its radiance is the texture x intensity x 2^exposure x
colour (x the blackbody colour when enabled), so the stage's dome names the file and the
factor (pipeline.lighting.environment_source). The factor is a bake option of the
environment (pipeline.bake.bake_or_load_environment): each value is its own entry, keyed by
the file's content as the plain panorama is.
"""
from __future__ import annotations

import math
import re

from pipeline.environment.uniform import MAX_RADIANCE

PREFIX = "scaled:"
_NUMBER = r"[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?"
_SCALED = re.compile(rf"^scaled:({_NUMBER}),({_NUMBER}),({_NUMBER}):(.+)$", re.S)


def name(rgb, path: str) -> str:
    """The source string of `path` scaled by `rgb` (rounded, so equal domes share one bake);
    the path alone when the factor is 1."""
    r, g, b = (min(max(float(c), 0.0), MAX_RADIANCE) for c in rgb)
    r, g, b = (float(f"{c:.6g}") for c in (r, g, b))
    if r == g == b == 1.0:
        return str(path)
    return f"{PREFIX}{r:.6g},{g:.6g},{b:.6g}:{path}"


def parse(source) -> tuple[tuple[float, float, float], str] | None:
    """(factor, path) of a scaled source, or None when it is not one."""
    if not isinstance(source, str):
        return None
    m = _SCALED.match(source)
    if not m:
        return None
    rgb = tuple(float(x) for x in m.groups()[:3])
    if not all(math.isfinite(c) and c <= MAX_RADIANCE for c in rgb):
        return None
    return rgb, m.group(4)  # type: ignore[return-value]
