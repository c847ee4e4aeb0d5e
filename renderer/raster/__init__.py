"""The raster renderer: frame orchestration, GPU residency of baked data, edge
anti-aliasing and the ground shadow.

May import `core`, `gl`, `renderer.view` and the method registry in `renderer.methods`."""
