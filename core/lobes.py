"""One row per material extension: what each glTF material extension (and the core
metallic-roughness model) adds to `core.scene.Material`, which texture slots it brings and in
which colour space they are sampled, the shader define that compiles its code in, and how its
factors are packed into the raster shaders' uniforms.

Readers of the table: the glTF reader (pipeline/gltf/materials.py: the extensions it accepts
and their texture keys), `core.scene.is_srgb` (colour spaces), and the raster material state
(renderer/raster/materials.py: defines, texture units, uniform bytes). tests/test_lobes.py
checks the table against the GLSL sources: every define is tested there, every slot declared,
every uniform declared with the type and size packed here.

Adding an extension: a row here, its parsing in the reader (factor ranges and defaults are
the extension's own), a `Material.uses` case if it has a define, and its getter in
shaders/material_info.glsl under that define.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

# A core.scene.Material. Not imported: core.scene reads its colour spaces from this table.
Material = Any

# Floats per GLSL type as packed by `Uniform.pack` (plain uniforms: no std140 padding).
GLSL_FLOATS = {"float": 1, "vec2": 2, "vec3": 3, "vec4": 4}


@dataclass(frozen=True)
class Slot:
    """A texture slot: `Material.{name}_texture`, sampled as `u_{name}_map` under
    `HAS_{NAME}_MAP`, from the extension's textureInfo `gltf` key."""
    name: str
    gltf: str
    srgb: bool = False  # colour, decoded from sRGB when sampled; else linear data


@dataclass(frozen=True)
class Uniform:
    """A GLSL uniform `name` of type `glsl`, its value computed from the material."""
    name: str
    glsl: str
    value: Callable[[Material], Sequence[float] | float]
    always: bool = False  # packed even when the row is inactive (read outside its define)

    def pack(self, m: Material) -> bytes:
        """The uniform's bytes (float32), checked against its GLSL type."""
        flat = _floats(self.value(m))
        if len(flat) != GLSL_FLOATS[self.glsl]:
            raise ValueError(f"{self.name}: {len(flat)} floats packed for a {self.glsl}")
        return _f32(flat)


@dataclass(frozen=True)
class Lobe:
    """One material extension (or the core model, `extension` None)."""
    name: str
    extension: str | None
    fields: tuple[str, ...]          # the Material fields it sets (besides its *_texture slots)
    slots: tuple[Slot, ...] = ()
    define: str | None = None        # compiled in while `active`
    uniforms: tuple[Uniform, ...] = ()
    active: Callable[[Material], bool] = lambda m: True  # noqa: E731  # its code and maps are needed


def _floats(v: Sequence[float] | float) -> list[float]:
    return [float(x) for x in v] if isinstance(v, (tuple, list)) else [float(v)]  # type: ignore[arg-type]  # a number


def _f32(values: list[float]) -> bytes:
    return struct.pack(f"<{len(values)}f", *values)


def _uses(lobe: str) -> Callable[[Material], bool]:
    return lambda m: m.uses(lobe)


def _transmissive(m: Material) -> bool:
    return m.material_class == "transmissive"  # its maps are read by shaders/refraction.frag


def _anisotropy(m: Material) -> tuple[float, float, float]:
    return (math.cos(m.anisotropy_rotation), math.sin(m.anisotropy_rotation), m.anisotropy_strength)


def _dispersion(m: Material) -> float:
    iors = m.channel_iors()
    return (iors[2] - iors[0]) / 2  # half the IOR spread between red and blue


LOBES: tuple[Lobe, ...] = (
    Lobe("core", None,
         ("base_color", "metallic", "roughness", "normal_scale", "occlusion_strength", "emissive",
          "alpha_mode", "alpha_cutoff", "opacity_premultiplied", "double_sided",
          "show_back_faces", "face_viewer"),
         (Slot("base_color", "baseColorTexture", srgb=True),
          Slot("metallic_roughness", "metallicRoughnessTexture"),
          Slot("normal", "normalTexture"), Slot("occlusion", "occlusionTexture"),
          Slot("emissive", "emissiveTexture", srgb=True)),
         None,
         (Uniform("u_base_color", "vec4", lambda m: m.base_color),
          Uniform("u_metallic", "float", lambda m: m.metallic),
          Uniform("u_roughness", "float", lambda m: m.roughness),
          Uniform("u_normal_scale", "float", lambda m: m.normal_scale),
          Uniform("u_occlusion_strength", "float", lambda m: m.occlusion_strength),
          Uniform("u_emissive", "vec3",  # factor x KHR_materials_emissive_strength
                  lambda m: tuple(c * m.emissive_strength for c in m.emissive)),
          Uniform("u_alpha_cutoff", "float", lambda m: m.alpha_cutoff))),
    Lobe("ior", "KHR_materials_ior", ("ior",), (), "MATERIAL_IOR",
         # read by shaders/refraction.frag whether or not MATERIAL_IOR compiles the F0 code
         (Uniform("u_ior", "float", lambda m: max(m.ior, 1.0), always=True),),
         _uses("ior")),
    Lobe("specular", "KHR_materials_specular", ("specular", "specular_color"),
         (Slot("specular", "specularTexture"),
          Slot("specular_color", "specularColorTexture", srgb=True)),
         "MATERIAL_SPECULAR",
         (Uniform("u_specular", "float", lambda m: m.specular),
          Uniform("u_specular_color", "vec3", lambda m: m.specular_color)),
         _uses("specular")),
    Lobe("clearcoat", "KHR_materials_clearcoat",
         ("clearcoat", "clearcoat_roughness", "clearcoat_normal_scale"),
         (Slot("clearcoat", "clearcoatTexture"),
          Slot("clearcoat_roughness", "clearcoatRoughnessTexture"),
          Slot("clearcoat_normal", "clearcoatNormalTexture")),
         "MATERIAL_CLEARCOAT",
         (Uniform("u_clearcoat", "float", lambda m: m.clearcoat),
          Uniform("u_clearcoat_roughness", "float", lambda m: m.clearcoat_roughness),
          Uniform("u_clearcoat_normal_scale", "float", lambda m: m.clearcoat_normal_scale)),
         _uses("clearcoat")),
    Lobe("sheen", "KHR_materials_sheen", ("sheen_color", "sheen_roughness"),
         (Slot("sheen_color", "sheenColorTexture", srgb=True),
          Slot("sheen_roughness", "sheenRoughnessTexture")),
         "MATERIAL_SHEEN",
         (Uniform("u_sheen_color", "vec3", lambda m: m.sheen_color),
          Uniform("u_sheen_roughness", "float", lambda m: m.sheen_roughness)),
         _uses("sheen")),
    # Transmission and volume factors are packed by the refraction pass (renderer/methods/refraction.py).
    Lobe("transmission", "KHR_materials_transmission", ("transmission",),
         (Slot("transmission", "transmissionTexture"),), None, (), _transmissive),
    Lobe("volume", "KHR_materials_volume",
         ("thickness", "attenuation_color", "attenuation_distance", "thin_walled"),  # thin: thickness 0
         (Slot("thickness", "thicknessTexture"),), None, (), _transmissive),
    Lobe("iridescence", "KHR_materials_iridescence",
         ("iridescence", "iridescence_ior", "iridescence_thickness_range"),
         (Slot("iridescence", "iridescenceTexture"),
          Slot("iridescence_thickness", "iridescenceThicknessTexture")),
         "MATERIAL_IRIDESCENCE",
         (Uniform("u_iridescence", "float", lambda m: m.iridescence),
          Uniform("u_iridescence_ior", "float", lambda m: m.iridescence_ior),
          Uniform("u_iridescence_thickness", "vec2", lambda m: m.iridescence_thickness_range)),
         _uses("iridescence")),
    Lobe("anisotropy", "KHR_materials_anisotropy", ("anisotropy_strength", "anisotropy_rotation"),
         (Slot("anisotropy", "anisotropyTexture"),), "MATERIAL_ANISOTROPY",
         (Uniform("u_anisotropy", "vec3", _anisotropy),), _uses("anisotropy")),
    Lobe("diffuse_transmission", "KHR_materials_diffuse_transmission",
         ("diffuse_transmission", "diffuse_transmission_color"),
         (Slot("diffuse_transmission", "diffuseTransmissionTexture"),
          Slot("diffuse_transmission_color", "diffuseTransmissionColorTexture", srgb=True)),
         "MATERIAL_DIFFUSE_TRANSMISSION",
         (Uniform("u_diffuse_transmission", "vec4",  # colour, factor
                  lambda m: (*m.diffuse_transmission_color, m.diffuse_transmission)),),
         _uses("diffuse_transmission")),
    Lobe("dispersion", "KHR_materials_dispersion", ("dispersion",), (), "MATERIAL_DISPERSION",
         (Uniform("u_dispersion", "float", _dispersion),), _uses("dispersion")),
    Lobe("emissive_strength", "KHR_materials_emissive_strength", ("emissive_strength",)),
    Lobe("unlit", "KHR_materials_unlit", ("unlit",), (), "UNLIT", (), lambda m: m.unlit),
)

BY_NAME = {lobe.name: lobe for lobe in LOBES}
SLOTS: tuple[Slot, ...] = tuple(s for lobe in LOBES for s in lobe.slots)
SRGB_SLOTS = frozenset(s.name for s in SLOTS if s.srgb)
# Lobes whose shader code a material compiles only when it uses them (Material.uses).
SHADER_LOBES = tuple(lobe.name for lobe in LOBES if lobe.define and lobe.define.startswith("MATERIAL_"))


# -- baked visibility (pipeline.occlusion) on the image light ----------------------------------
# shaders/ibl.glsl has the same two functions; the ray tracer's diffuse share reads the first.

def ao_multibounce(ao, albedo):
    """Diffuse occlusion from the baked visibility `ao`, lifted by the light interreflection
    brings back on an albedo (Jimenez et al. 2016's cubic fit; never below `ao`). Arrays
    broadcast: ao (N, 1) against albedo (N, 3)."""
    ao, albedo = np.asarray(ao, np.float64), np.asarray(albedo, np.float64)
    a, b, c = 2.0404 * albedo - 0.3324, -4.7951 * albedo + 0.6417, 2.7552 * albedo + 0.6903
    return np.maximum(ao, ((ao * a + b) * ao + c) * ao)


def specular_occlusion(n_dot_v, ao, roughness):
    """The specular lobe's share left unblocked (Lagarde & de Rousiers 2014, from the
    visibility, N.V and alpha = roughness^2), in [0, 1]. The raster lifts it by
    `ao_multibounce(that, F0)`: a metal's blocked directions see lit neighbours."""
    alpha = np.asarray(roughness, np.float64) ** 2
    return np.clip((np.asarray(n_dot_v) + ao) ** np.exp2(-16.0 * alpha - 1.0) - 1.0 + ao, 0.0, 1.0)
