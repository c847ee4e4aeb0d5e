"""KHR_materials_variants: the asset's variant names and, per primitive, which material each
variant swaps in."""
from __future__ import annotations

from collections.abc import Callable

from pipeline.gltf.accessors import Document


def variant_names(d: Document) -> list[str]:
    """The asset's variant names, in index order."""
    ext = d.obj(d.doc.get("extensions"), "extensions").get("KHR_materials_variants")
    variants = d.array(d.obj(ext, "KHR_materials_variants"), "variants")
    return [str(d.obj(v, f"variant {i}").get("name") or f"variant{i}")
            for i, v in enumerate(variants)]


def variant_materials(d: Document, prim: dict, scene_material: Callable[[int], int]) -> dict[int, int]:
    """{variant index: scene material} from a primitive's mappings; `scene_material` gives
    the scene's index of a glTF material (reading it when new)."""
    ext = d.obj(prim.get("extensions"), "primitive extensions").get("KHR_materials_variants")
    if ext is None:
        return {}
    count = len(variant_names(d))
    out = {}
    for m in d.array(d.obj(ext, "KHR_materials_variants"), "mappings"):
        m = d.obj(m, "variant mapping")
        mat = scene_material(d.integer(m, "material"))
        for v in d.array(m, "variants"):
            if type(v) is not int or not 0 <= v < count:
                raise d.bad(f"KHR_materials_variants mapping names variant {v!r} of {count}")
            out[v] = mat
    return out
