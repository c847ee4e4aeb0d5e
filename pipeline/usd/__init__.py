"""USD ingest with usd-core: the composed stage, its layer graph checked before composition,
implicit shapes, UsdPreviewSurface and MaterialX materials, subdivision surfaces.

May import `core` and the rest of `pipeline`; nothing in `renderer` or `service`."""
