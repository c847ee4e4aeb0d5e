"""pipeline.gltf.variants: KHR_materials_variants names and per-primitive mappings."""
from __future__ import annotations

import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder

from core.errors import MalformedAsset
from pipeline.gltf.accessors import Document
from pipeline.gltf.variants import variant_materials, variant_names
from pipeline.limits import Limits


def _doc(tmp_path, mappings) -> tuple[Document, dict]:
    b = Builder()
    b.doc["extensions"] = {"KHR_materials_variants": {"variants": [{"name": "red"}, {}]}}
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=b.material()))
    b.material()
    b.doc["meshes"][0]["primitives"][0]["extensions"] = {"KHR_materials_variants": {"mappings": mappings}}
    d = Document(b.write(tmp_path / "v.glb"), Limits())
    return d, d.item("meshes", 0)["primitives"][0]


def test_names_and_mappings(tmp_path):
    d, prim = _doc(tmp_path, [{"material": 1, "variants": [0]}, {"material": 0, "variants": [1]}])
    assert variant_names(d) == ["red", "variant1"]
    asked = []
    scene_index = {0: 10, 1: 11}

    def scene_material(mat: int) -> int:
        asked.append(mat)
        return scene_index[mat]

    assert variant_materials(d, prim, scene_material) == {0: 11, 1: 10}
    assert asked == [1, 0]
    assert variant_materials(d, {"attributes": {}}, scene_material) == {}


def test_a_mapping_to_a_missing_variant_is_refused(tmp_path):
    d, prim = _doc(tmp_path, [{"material": 1, "variants": [2]}])
    with pytest.raises(MalformedAsset, match="names variant 2 of 2"):
        variant_materials(d, prim, lambda mat: mat)
