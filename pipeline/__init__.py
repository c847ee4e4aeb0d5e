"""Offline half of asset-preview: ingest (glTF, USD, plain meshes) and bake into the cache.

Entry points: `pipeline.ingest.load_scene` (any supported file into a `Scene`),
`pipeline.bake.bake_asset`, `bake_environment` and `load_baked` (baked assets and
environments, cached). The package itself imports nothing, so that its modules, which all
import `pipeline.*`, never come back to it (tests/test_layers.py counts package inits).

May import `core`; nothing in `renderer` or `service`.
"""
