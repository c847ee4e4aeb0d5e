"""The raster's emissive area lights (core.area_lights) as shader uniforms
(shaders/area_lights.glsl): the baked polygons, or for an asset baked without them (a hand-made
asset, a pose of a rig) the ones found once per asset key."""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from core import area_lights
from core.area_lights import AreaLights
from core.baked import BakedAsset

MAX_FOUND = 16  # assets whose lights were found at render time, kept by key
_found: OrderedDict[str, AreaLights] = OrderedDict()


def of_asset(asset: BakedAsset) -> AreaLights:
    if asset.area_lights is not None:
        return asset.area_lights
    if asset.key in _found:
        _found.move_to_end(asset.key)
        return _found[asset.key]
    lights = _found[asset.key] = area_lights.of_format(asset.format, asset.meshes, asset.textures)
    while len(_found) > MAX_FOUND:
        _found.popitem(last=False)
    return lights


def uniforms(lights: AreaLights) -> dict[str, bytes]:
    if not len(lights):
        return {}
    f4 = np.float32
    corners = np.concatenate([lights.corners, np.zeros((len(lights), 4, 1))], axis=2)
    return {"u_area_corner": np.ascontiguousarray(corners, f4).tobytes(),
            "u_area_normal": np.c_[lights.normal, lights.two_sided].astype(f4).tobytes(),
            "u_area_radiance": np.c_[lights.radiance, lights.mesh].astype(f4).tobytes()}
