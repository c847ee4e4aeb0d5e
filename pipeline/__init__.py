"""Offline half of asset-preview: ingest (glTF, USD, plain meshes) and bake into the cache.

The functions here import their modules lazily so that `import pipeline` stays cheap.
"""
from __future__ import annotations

from core.cubemap import DEFAULT_FACE_SIZE
from core.errors import AssetError
from core.scene import Scene

__all__ = ["AssetError", "Scene", "load_scene", "bake_asset", "bake_environment", "load_baked"]


def load_scene(path, limits=None, root=None, variant_sets=()) -> Scene:
    """Read any supported asset file into a `Scene` (raises an `AssetError` on bad input);
    the files it references must lie inside `root` (default: its folder); `variant_sets`:
    USD selections "[PRIM:]SET=NAME"."""
    from pipeline.ingest import load_scene as _load
    return _load(path, limits, root, tuple(variant_sets))


def bake_asset(path, cache_dir=None, **options):
    """Ingest and bake `path` into the cache (or load it from there): a `BakedAsset`."""
    from pipeline.bake import bake_asset as _bake
    return _bake(path, cache_dir, **options)


def bake_environment(source, cache_dir=None, face_size=DEFAULT_FACE_SIZE, prefilter="ggx"):
    """Bake a panorama (file or bundled name) into a `BakedEnvironment` (cached)."""
    from pipeline.bake import bake_environment as _bake
    return _bake(source, cache_dir, face_size=face_size, prefilter=prefilter)


def load_baked(key, cache_dir=None):
    """Load a baked asset by cache key alone, without its source file."""
    from pipeline.bake import load_baked as _load
    return _load(key, cache_dir)
