"""Rendering methods beyond plain PBR raster, listed in one place (`registry`): refraction
(`single`, `wyman`), the ray tracer and its compiled kernels, geometric optics, and `auto`,
which picks one per object.

May import `core`, `gl`, `renderer.view` and the raster passes they draw with (never the
frame orchestration, `renderer.raster.render`, which imports them)."""
