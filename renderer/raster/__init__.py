"""The raster renderer: frame orchestration (`render`), the geometry passes (`passes`),
per-material state from core/lobes.py (`materials`), render targets (`targets`), the final
pass (`final`), GPU residency of baked data (`gpu`), edge anti-aliasing and the ground shadow.

May import `core`, `gl`, `renderer.view` and the method registry in `renderer.methods`."""
