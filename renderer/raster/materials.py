"""Per-material raster state: the defines, uniform bytes and texture units a mesh's material
compiles and binds, generated from the material-extension table (core/lobes.py): a row's
define while the material uses it, its slots' maps, its uniforms."""
from __future__ import annotations

import logging
from dataclasses import dataclass

import moderngl
import numpy as np

from core import lobes, storm
from core.options import MaterialOverride, RenderOptions
from core.scene import Material, is_srgb
from renderer.raster import gpu

log = logging.getLogger(__name__)

# Texture units: 0 environment, 1 BRDF LUT, then one per material slot; passes that bind more
# (renderer.methods.refraction) start at FIRST_FREE_UNIT.
FIRST_FREE_UNIT = 2 + len(lobes.SLOTS)
MAX_STATES = 32  # per GPU mesh: many distinct overrides (a service) keep it bounded


@dataclass
class MaterialState:
    defines: dict
    uniforms: list[tuple[str, bytes]]
    textures: list[tuple[str, moderngl.Texture]]  # bound from unit 2 on, in this order


def material_state(gm: gpu.GpuMesh, m: Material, asset: gpu.GpuAsset,
                   options: RenderOptions) -> MaterialState:
    """Defines, uniform bytes and textures for mesh `gm` drawn with material `m` (after the
    request's override); cached on the GPU mesh by override."""
    ov = options.override
    cached = gm.states.get(ov)
    if cached is not None:
        return cached
    state = _build(gm.baked, m, asset, ov)
    if len(gm.states) >= MAX_STATES:
        gm.states.clear()
    gm.states[ov] = state
    return state


def _build(mesh, m: Material, asset: gpu.GpuAsset, ov: MaterialOverride | None) -> MaterialState:
    defines: dict = {}
    uv_sets = {0: mesh.uv0 is not None, 1: mesh.uv1 is not None}
    if uv_sets[0]:
        defines["HAS_UV0"] = 1
    textures: list[tuple[str, moderngl.Texture]] = []
    uniforms: list[tuple[str, bytes]] = []
    for row in lobes.LOBES:
        active = row.active(m)
        if active and row.define:
            defines[row.define] = 1
        uniforms += [(u.name, u.pack(m)) for u in row.uniforms if active or u.always]
        for slot in row.slots if active else ():
            ref = getattr(m, f"{slot.name}_texture")
            if ref is None:
                continue
            tex = asset.textures.get((ref.texture, is_srgb(slot.name)))
            if tex is None or not uv_sets.get(ref.uv_set, False):
                log.warning("%s: %s texture skipped (no image or no UV set %d)",
                            mesh.name, slot.name, ref.uv_set)
                continue
            defines[f"HAS_{slot.name.upper()}_MAP"] = 1
            defines[f"{slot.name.upper()}_UV"] = f"v_uv{ref.uv_set}"
            if ref.uv_set == 1:
                defines["HAS_UV1"] = 1
            textures.append((f"u_{slot.name}_map", tex))
            uniforms.append((f"u_{slot.name}_uvm", mat3_bytes(ref.uv_matrix())))
    needs_frame = {"HAS_NORMAL_MAP", "HAS_CLEARCOAT_NORMAL_MAP", "MATERIAL_ANISOTROPY"} & set(defines)
    if needs_frame and mesh.tangents is not None:
        defines["HAS_TANGENTS"] = 1
    if mesh.colors is not None:
        defines["HAS_COLORS"] = 1
    if mesh.ao_per_placement:  # a row per placement, read from a storage buffer (pbr.vert)
        defines["HAS_AO"] = defines["AO_ROWS"] = 1
        uniforms.append(("u_ao_vertices", np.int32(len(mesh.positions)).tobytes()))
    elif mesh.ao is not None and len(mesh.ao) == len(mesh.positions):
        defines["HAS_AO"] = 1
    if "HAS_AO" in defines and mesh.bent is not None and len(mesh.bent) == len(mesh.positions):
        defines["HAS_BENT"] = 1  # bent normals beside the visibility (shaders/ibl.glsl)
    if m.double_sided:
        defines["DOUBLE_SIDED"] = 1
    elif m.show_back_faces:  # USD single-sided: back faces lit as Storm lights them (core.storm)
        defines["SHOW_BACK_FACES"] = 1
        defines["STORM_BACK_TABLE"] = storm.glsl_table()
    if m.face_viewer:
        defines["FACE_VIEWER"] = 1
    if m.alpha_mode == "MASK":
        defines["ALPHA_MASK"] = 1
    elif m.alpha_mode == "BLEND":
        defines["ALPHA_BLEND"] = 1
        if m.opacity_premultiplied:
            defines["OPACITY_PREMULTIPLIED"] = 1
    if ov is not None and ov.metallic is not None:
        defines["METALLIC_OVERRIDDEN"] = 1
    if ov is not None and ov.roughness is not None:
        defines["ROUGHNESS_OVERRIDDEN"] = 1
    return MaterialState(defines, uniforms, textures)


def mat3_bytes(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(np.asarray(m, np.float32).T).tobytes()  # GLSL: column-major
