"""Headless OpenGL renderer: baked asset + baked environment + options -> Frame."""
from __future__ import annotations

# Bump on any change that alters pixels: the service keys cached thumbnails with it.
RENDERER_VERSION = "4"  # 3: energy compensation by default, layering, mirrored transforms (issue 18); 4: anisotropic texture filtering (issue 30)

# Imported eagerly: the submodule `renderer.raster.render` would otherwise shadow the function.
from renderer.frame import Frame  # noqa: E402
from renderer.raster.render import render  # noqa: E402

__all__ = ["render", "Frame", "RENDERER_VERSION"]
