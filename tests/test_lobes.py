"""The material-extension table (core/lobes.py) agrees with the scene model, the glTF reader
and the shaders: each row's define is tested in the GLSL, each slot is a Material field and a
declared map, each uniform is declared with the type it is packed as and read by a compiled
program (GL reflection: the packed bytes are the size the driver reports)."""
from __future__ import annotations

import dataclasses
import re

import pytest

import shaders
from core import lobes
from core.scene import Material, TextureRef
from gl import context
from pipeline.gltf.materials import MATERIAL_EXTENSIONS
from pipeline.gltf.reader import SUPPORTED_EXTENSIONS
from renderer.raster.materials import FIRST_FREE_UNIT

SOURCES = {name: shaders.load(name) for name in ("pbr.frag", "refraction.frag", "backface.frag")}
GLSL = "\n".join(SOURCES.values())
FIELDS = {f.name for f in dataclasses.fields(Material)}


def _all_on() -> Material:
    """A material that uses every row (so each row's define, maps and uniforms are live)."""
    ref = TextureRef(0)
    maps = {f"{s.name}_texture": ref for s in lobes.SLOTS}
    return Material(ior=1.45, specular=0.5, clearcoat=1.0, sheen_color=(1, 1, 1), iridescence=1.0,
                    anisotropy_strength=0.5, anisotropy_rotation=0.3, diffuse_transmission=0.5,
                    dispersion=1.0, transmission=1.0, **maps)


def test_rows_name_real_fields_and_every_field_has_a_row():
    owned: set[str] = set()
    for row in lobes.LOBES:
        for name in row.fields:
            assert name in FIELDS, f"{row.name}: Material has no field {name!r}"
        owned |= set(row.fields) | {f"{s.name}_texture" for s in row.slots}
    assert len(lobes.SLOTS) == len({s.name for s in lobes.SLOTS}), "a slot in two rows"
    assert not FIELDS - owned - {"name"}, "Material fields no row owns"


def test_every_define_is_tested_in_the_shaders():
    for row in lobes.LOBES:
        if row.define:
            assert re.search(rf"#ifn?def {row.define}\b|defined\({row.define}\)", GLSL), row.define


def test_shader_lobes_are_the_material_switches():
    plain = Material()
    for name in lobes.SHADER_LOBES:
        assert not plain.uses(name), name  # the defaults of an extension cost nothing
        assert lobes.BY_NAME[name].active(_all_on()), name
    with pytest.raises(ValueError):
        plain.uses("no_such_lobe")


def test_every_slot_is_declared_and_every_declared_map_is_a_slot():
    declared = set(re.findall(r"^DECLARE_MAP\((\w+)\)", shaders.load("textures.glsl"), re.M))
    assert declared == {s.name for s in lobes.SLOTS}
    for s in lobes.SLOTS:
        assert f"HAS_{s.name.upper()}_MAP" in GLSL, s.name
    assert FIRST_FREE_UNIT == 2 + len(declared)  # units 0, 1: environment, BRDF LUT


def test_colour_spaces():
    assert lobes.SRGB_SLOTS == {"base_color", "emissive", "specular_color", "sheen_color",
                                "diffuse_transmission_color"}


def test_glTF_reader_accepts_every_row():
    for row in lobes.LOBES:
        if row.extension:
            assert row.extension in SUPPORTED_EXTENSIONS, row.extension
    assert MATERIAL_EXTENSIONS <= SUPPORTED_EXTENSIONS
    for s in lobes.SLOTS:
        assert s.gltf.endswith("Texture"), s


def test_every_uniform_is_declared_with_its_packed_type():
    m = _all_on()
    for row in lobes.LOBES:
        for u in row.uniforms:
            types = set(re.findall(rf"uniform\s+(\w+)\s+{u.name}\s*;", GLSL))
            assert types == {u.glsl}, f"{row.name}: {u.name} declared as {types}, packed as {u.glsl}"
            assert len(u.pack(m)) == 4 * lobes.GLSL_FLOATS[u.glsl]


def test_packed_sizes_match_the_compiled_programs():
    """Compiled with every row's define and map, the programs read every uniform the table
    packs, each of the size packed (float32 x the components GL reports)."""
    defines: dict = {"LIGHT_COUNT": 1, "HAS_UV0": 1, "HAS_TANGENTS": 1, "ALPHA_MASK": 1}
    for row in lobes.LOBES:
        if row.define and row.define != "UNLIT":
            defines[row.define] = 1
    for s in lobes.SLOTS:
        defines[f"HAS_{s.name.upper()}_MAP"] = 1
        defines[f"{s.name.upper()}_UV"] = "v_uv0"
    progs = [context.program("pbr.vert", frag, defines) for frag in ("pbr.frag", "refraction.frag")]
    m = _all_on()
    for row in lobes.LOBES:
        for u in row.uniforms:
            found = [p[u.name] for p in progs if u.name in p]
            assert found, f"{u.name} ({row.name}) is read by no program"
            for member in found:
                assert member.dimension == lobes.GLSL_FLOATS[u.glsl], u.name  # type: ignore[union-attr]
                assert len(u.pack(m)) == 4 * member.dimension, u.name  # type: ignore[union-attr]
        for s in row.slots:
            assert any(f"u_{s.name}_map" in p for p in progs), f"map {s.name} is sampled nowhere"


def test_a_mis_sized_row_is_refused():
    bad = lobes.Uniform("u_specular_color", "vec3", lambda m: (1.0, 1.0))
    with pytest.raises(ValueError, match="u_specular_color"):
        bad.pack(Material())
