"""Which environment lights a render when the request names none.

A USD stage with its own lights is lit by them, as Hydra Storm (usdview) lights it: its
textured DomeLight's panorama (times its intensity x 2^exposure x colour), an untextured dome's uniform radiance, or, with only
distant / sphere / rect / disk lights, no environment light at all (`dark`: the background
option still draws, and reflections show only the lights' highlights). The studio
environment lights everything else (glTF's KHR_lights_punctual lights are added to it, as
glTF viewers do), and a stage whose lights are switched off (`lights=False`), unless its
dome has a texture (the dome is the environment either way).
"""
from __future__ import annotations

import logging
import os

from pipeline.environment import scaled, uniform

log = logging.getLogger(__name__)


def dome_texture(asset, path) -> str | None:
    """The panorama file the asset's dome light names (USD), when it is there."""
    rel = (asset.manifest or {}).get("environment")
    if not rel:
        return None
    found = os.path.join(os.path.dirname(os.path.abspath(path)), rel)
    if os.path.isfile(found):
        return found
    log.warning("%s: dome light texture %s not found; default environment used", path, found)
    return None


def environment_source(asset, path, requested: str | None, default: str, lights: bool = True) -> str:
    """The environment a render of `asset` (baked from `path`) uses: the one `requested`,
    else the stage's own lighting (see the module docstring), else `default`."""
    if requested:
        return requested
    dome = dome_texture(asset, path)
    manifest = asset.manifest or {}
    if dome:  # its intensity x exposure x colour on the texture (UsdLux)
        factor = manifest.get("dome_scale")
        return scaled.name(factor, dome) if factor is not None else dome
    if not (lights and manifest.get("own_lighting")):
        return default
    if manifest.get("dome_radiance") is not None:
        return uniform.name(manifest["dome_radiance"])
    return uniform.DARK
