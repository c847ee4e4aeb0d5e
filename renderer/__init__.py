"""Headless OpenGL renderer: baked asset + baked environment + options -> Frame.

`render` and `Frame` are re-exported here; no module of the package imports this `__init__`
back (they import the submodules they need), so the package has no import cycle."""
from __future__ import annotations

from renderer.frame import Frame
from renderer.raster.render import render

# Bump on any change that alters pixels: the service keys cached thumbnails with it.
RENDERER_VERSION = "13"  # 3: energy compensation by default, layering, mirrored transforms (issue 18); 4: anisotropic texture filtering, 5: rough transmittance and TIR attenuation (issue 30)
# 6: image-light specular about the lobe's dominant direction, anisotropic image light along the
#    grain, premultiplied blends and emitter light in the ray tracer, two-sided blends far side first
# 7: the image light's multiply scattered share along the specular lobe, not the irradiance
# 8: the split-sum's horizon (core.horizon) and the irradiance about the baked bent normal
# 9: the tree's diffuse integrates the cube's texels, not the SH (renderer.methods.env_irradiance)
# 10: emissive polygons light the raster (core.area_lights, shaders/area_lights.glsl)
# 11: the tree's diffuse share reads the irradiance about the baked bent normal
# 12: the raster's diffuse reads the bake's irradiance cube (the exact texel integral, core.irradiance), not the SH
# 13: baked visibility on split triangles where it varies (pipeline.occlusion): contact shadows

__all__ = ["render", "Frame", "RENDERER_VERSION"]
