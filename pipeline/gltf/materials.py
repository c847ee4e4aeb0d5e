"""The Khronos material-lobe extensions beyond metallic-roughness: specular, clearcoat, sheen,
iridescence, anisotropy, diffuse transmission and dispersion, read into `Material` fields
(defaults are each extension's own, so a material without one is unchanged). `read_lobes` is
called by the glTF reader with its checked JSON accessors; textures go through its
`texture_ref` (UV set, KHR_texture_transform, limits)."""
from __future__ import annotations

from core.lobes import BY_NAME
from core.scene import Material

# The rows of core/lobes.py read here (the reader reads ior, transmission, volume,
# emissive_strength and unlit with the core material); their absence in a renderer would
# change the look but not the geometry.
LOBES = tuple(BY_NAME[name] for name in ("specular", "clearcoat", "sheen", "iridescence",
                                         "anisotropy", "diffuse_transmission", "dispersion"))
MATERIAL_EXTENSIONS = frozenset(lobe.extension for lobe in LOBES if lobe.extension)


def read_lobes(r, ext: dict, out: Material, slot: str) -> None:
    """Fill `out` from the extension objects in `ext` (a material's `extensions`); `r` is the
    glTF reader (its `_dict`, `_float`, `_floats` and `texture_ref` raise MalformedAsset
    naming the file). Texture slots and their glTF keys come from the table."""
    for lobe in LOBES:
        if lobe.extension in ext:
            e = r._dict(ext[lobe.extension], f"{slot} {lobe.extension}")
            for t in lobe.slots:
                setattr(out, f"{t.name}_texture", r.texture_ref(
                    e.get(t.gltf), f"{slot} {t.gltf.removesuffix('Texture')}"))
    if "KHR_materials_specular" in ext:
        e = r._dict(ext["KHR_materials_specular"], f"{slot} KHR_materials_specular")
        out.specular = r._float(e, "specularFactor", 1.0, 0.0, 1.0)
        out.specular_color = tuple(max(c, 0.0) for c in r._floats(e, "specularColorFactor",
                                                                  (1.0, 1.0, 1.0)))
    if "KHR_materials_clearcoat" in ext:
        e = r._dict(ext["KHR_materials_clearcoat"], f"{slot} KHR_materials_clearcoat")
        out.clearcoat = r._float(e, "clearcoatFactor", 0.0, 0.0, 1.0)
        out.clearcoat_roughness = r._float(e, "clearcoatRoughnessFactor", 0.0, 0.0, 1.0)
        normal = r._dict(e.get("clearcoatNormalTexture"), f"{slot} clearcoatNormalTexture")
        out.clearcoat_normal_scale = r._float(normal, "scale", 1.0)
    if "KHR_materials_sheen" in ext:
        e = r._dict(ext["KHR_materials_sheen"], f"{slot} KHR_materials_sheen")
        out.sheen_color = tuple(min(max(c, 0.0), 1.0) for c in r._floats(
            e, "sheenColorFactor", (0.0, 0.0, 0.0)))
        out.sheen_roughness = r._float(e, "sheenRoughnessFactor", 0.0, 0.0, 1.0)
    if "KHR_materials_iridescence" in ext:
        e = r._dict(ext["KHR_materials_iridescence"], f"{slot} KHR_materials_iridescence")
        out.iridescence = r._float(e, "iridescenceFactor", 0.0, 0.0, 1.0)
        out.iridescence_ior = r._float(e, "iridescenceIor", 1.3, 1.0, 10.0)
        out.iridescence_thickness_range = (
            r._float(e, "iridescenceThicknessMinimum", 100.0, 0.0, 1e5),
            r._float(e, "iridescenceThicknessMaximum", 400.0, 0.0, 1e5))
    if "KHR_materials_anisotropy" in ext:
        e = r._dict(ext["KHR_materials_anisotropy"], f"{slot} KHR_materials_anisotropy")
        out.anisotropy_strength = r._float(e, "anisotropyStrength", 0.0, 0.0, 1.0)
        out.anisotropy_rotation = r._float(e, "anisotropyRotation", 0.0)
    if "KHR_materials_diffuse_transmission" in ext:
        e = r._dict(ext["KHR_materials_diffuse_transmission"],
                    f"{slot} KHR_materials_diffuse_transmission")
        out.diffuse_transmission = r._float(e, "diffuseTransmissionFactor", 0.0, 0.0, 1.0)
        out.diffuse_transmission_color = tuple(min(max(c, 0.0), 1.0) for c in r._floats(
            e, "diffuseTransmissionColorFactor", (1.0, 1.0, 1.0)))
    if "KHR_materials_dispersion" in ext:
        e = r._dict(ext["KHR_materials_dispersion"], f"{slot} KHR_materials_dispersion")
        out.dispersion = r._float(e, "dispersion", 0.0, 0.0, 100.0)
