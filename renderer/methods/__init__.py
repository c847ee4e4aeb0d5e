"""Rendering methods beyond plain PBR raster, listed in one place (`registry`): refraction
(`single`, `wyman`), the ray tracer and its compiled kernels, geometric optics, and `auto`,
which picks one per object.

May import `core`, `gl`, `renderer.view` and the raster passes they draw with (never the
frame orchestration, `renderer.raster.render`, which imports them)."""

import os

# numba's OpenMP layer (GNU libgomp) lets idle workers spin between parallel loops by default;
# a frame runs dozens of short kernels, and on a shared machine the spinning thread takes the
# core the other one needs (figures: bench/RESULTS.md, "the kernels over both cores"). Read
# when libgomp loads, at numba's first parallel loop: set before any kernel module is
# imported. A value set by the user stays.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
