"""pipeline.gltf.materials: texture references (UV sets, KHR_texture_transform, shared images)
and materials with their extensions, through the public `Textures.ref` and `read_material`."""
from __future__ import annotations

import math

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, png_bytes

from core.errors import LimitExceeded, MalformedAsset
from pipeline.gltf.accessors import Document
from pipeline.gltf.materials import Textures, read_material
from pipeline.limits import Limits


def _doc(tmp_path, limits=None, **material) -> Document:
    b = Builder()
    b.image(png_bytes(np.full((4, 4, 3), 200)))
    b.doc["textures"].append({"source": 0, "sampler": 0})  # the same image, another sampler
    b.doc["samplers"] = [{"magFilter": 9728, "wrapS": 33071}]
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=b.material(**material)))
    return Document(b.write(tmp_path / "m.glb"), limits or Limits())


def test_ref_reads_uv_set_and_texture_transform(tmp_path):
    d = _doc(tmp_path)
    tex = Textures(d)
    ref = tex.ref({"index": 0, "texCoord": 1, "extensions": {"KHR_texture_transform": {
        "offset": [0.5, 0.0], "rotation": 0.25, "scale": [2.0, 2.0]}}}, "baseColor")
    assert ref is not None and ref.texture == 0 and ref.uv_set == 1
    assert ref.offset == (0.5, 0.0) and ref.rotation == 0.25 and ref.scale == (2.0, 2.0)
    assert tex.ref(None, "none") is None
    assert tex.ref({"index": 0, "texCoord": 2}, "far") is None
    assert "TEXCOORD_2 is not read" in d.warnings[-1]


def test_an_image_with_two_samplers_is_two_textures_read_once(tmp_path):
    d = _doc(tmp_path)
    tex = Textures(d)
    first, again, other = (tex.ref({"index": i}, "t") for i in (0, 0, 1))
    assert first is not None and again is not None and other is not None
    assert first.texture == again.texture == 0 and other.texture == 1
    assert len(tex.textures) == 2
    assert tex.textures[1].sampler.mag_filter == 9728 and tex.textures[1].sampler.wrap_s == 33071


def test_texture_limit(tmp_path):
    tex = Textures(_doc(tmp_path, Limits(max_textures=1)))
    tex.ref({"index": 0}, "t")
    with pytest.raises(LimitExceeded, match="more than 1 textures"):
        tex.ref({"index": 1}, "t")


def test_read_material_factors_and_extensions(tmp_path):
    d = _doc(tmp_path, name="glass", alphaMode="BLEND", doubleSided=True,
             pbrMetallicRoughness={"baseColorFactor": [1, 0.5, 0.25, 0.5], "metallicFactor": 3,
                                   "roughnessFactor": 0.2, "baseColorTexture": {"index": 0}},
             extensions={"KHR_materials_transmission": {"transmissionFactor": 1.0},
                         "KHR_materials_ior": {"ior": 1.33},
                         "KHR_materials_volume": {"thicknessFactor": 0.1},
                         "KHR_materials_clearcoat": {"clearcoatFactor": 0.7}})
    m = read_material(d, Textures(d), 0)
    assert m.name == "glass" and m.alpha_mode == "BLEND" and m.double_sided
    assert m.base_color == (1.0, 0.5, 0.25, 0.5) and m.metallic == 1.0 and m.roughness == 0.2
    assert m.base_color_texture is not None and m.base_color_texture.texture == 0
    assert m.transmission == 1.0 and m.ior == 1.33 and m.thickness == 0.1
    assert math.isinf(m.attenuation_distance) and m.clearcoat == 0.7


def test_spec_gloss_is_converted_to_metallic_roughness(tmp_path):
    d = _doc(tmp_path, extensions={"KHR_materials_pbrSpecularGlossiness": {
        "diffuseFactor": [0.8, 0.8, 0.8, 1.0], "specularFactor": [0.04, 0.04, 0.04],
        "glossinessFactor": 0.5}})
    m = read_material(d, Textures(d), 0)
    assert m.metallic == pytest.approx(0.0, abs=1e-6) and m.roughness == pytest.approx(0.5)


def test_bad_material_names_the_file(tmp_path):
    d = _doc(tmp_path, alphaMode="SOMETIMES")
    with pytest.raises(MalformedAsset, match="alphaMode 'SOMETIMES'") as err:
        read_material(d, Textures(d), 0)
    assert str(d.path) in str(err.value)


def test_a_primitive_without_a_material_takes_the_specs_default_material(tmp_path):
    """glTF 2.0 3.9.6: no `material` means every property at its default (white, metallic 1,
    roughness 1), as the Sample Viewer and three.js draw it; not our grey for plain meshes."""
    from pipeline.ingest import load_scene
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES))
    scene = load_scene(b.write(tmp_path / "plain.glb"))
    (mat,) = scene.materials
    assert mat.base_color == (1.0, 1.0, 1.0, 1.0) and mat.metallic == 1.0 and mat.roughness == 1.0
    assert mat.base_color_texture is None and mat.alpha_mode == "OPAQUE"
