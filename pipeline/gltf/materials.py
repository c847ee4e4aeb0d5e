"""glTF textures and materials: images (embedded, data: URIs or files, probed and decoded
later), samplers, texture references (UV set, KHR_texture_transform), metallic-roughness
materials with the Khronos extensions (transmission, volume, IOR, emissive strength, unlit,
specular-glossiness converted at ingest, and the lobes beyond metallic-roughness: specular,
clearcoat, sheen, iridescence, anisotropy, diffuse transmission, dispersion). Each
extension's defaults are its own, so a material without one is unchanged."""
from __future__ import annotations

import dataclasses
import logging
import math
from typing import cast

from core.errors import LimitExceeded, MalformedAsset, MissingFile
from core.lobes import BY_NAME
from core.scene import Material, Sampler, Texture, TextureRef
from pipeline import deadline
from pipeline.gltf.accessors import Document
from pipeline.gltf.specgloss import conversion_textures, convert_factors
from pipeline.images import DeferredTexture, probe_image

log = logging.getLogger(__name__)

# The rows of core/lobes.py that read_lobes reads (read_material reads ior, transmission,
# volume, emissive_strength and unlit with the core model); their absence in a renderer would
# change the look but not the geometry.
LOBES = tuple(BY_NAME[name] for name in ("specular", "clearcoat", "sheen", "iridescence",
                                         "anisotropy", "diffuse_transmission", "dispersion"))
MATERIAL_EXTENSIONS = frozenset(lobe.extension for lobe in LOBES if lobe.extension)


class Textures:
    """A document's textures as the scene's: each (image, sampler) pair read once, into
    `textures` (DeferredTextures, decoded at bake), against `Limits.max_textures`."""

    def __init__(self, d: Document):
        self.d = d
        self.textures: list[Texture] = []
        self._texture_map: dict[int, int | None] = {}
        self._image_map: dict[tuple, int | None] = {}  # (image, sampler) -> scene texture
        self._images: dict[int, tuple | None] = {}

    def ref(self, info, slot: str) -> TextureRef | None:
        """A material's textureInfo `info` as a TextureRef; None when absent or unusable."""
        if info is None:
            return None
        d = self.d
        info = d.obj(info, slot)
        tex = self._texture(d.integer(info, "index"))
        if tex is None:
            return None
        uv_set = d.integer(info, "texCoord", 0)
        ref = TextureRef(texture=tex, uv_set=uv_set)
        tt = d.obj(info.get("extensions"), f"{slot} extensions").get("KHR_texture_transform")
        if tt is not None:
            tt = d.obj(tt, f"{slot} KHR_texture_transform")
            ref.offset = d.numbers(tt, "offset", (0.0, 0.0))
            ref.rotation = d.number(tt, "rotation", 0.0)
            ref.scale = d.numbers(tt, "scale", (1.0, 1.0))
            ref.uv_set = d.integer(tt, "texCoord", uv_set)
        if ref.uv_set > 1:
            d.warnings.append(f"{slot}: TEXCOORD_{ref.uv_set} is not read; texture ignored")
            return None
        return ref

    def _texture(self, index: int) -> int | None:
        """Scene texture index for glTF texture `index`; None (with a warning) if unusable."""
        if index in self._texture_map:
            return self._texture_map[index]
        deadline.check()
        d = self.d
        tex = d.item("textures", index, "texture")
        source = tex.get("source")
        ext = d.obj(tex.get("extensions"), f"texture {index} extensions")
        for name in ("KHR_texture_basisu", "EXT_texture_webp"):  # what a viewer would pick
            if name in ext:
                source = d.obj(ext[name], name).get("source", source)
                break
        if not isinstance(source, (int, type(None))) or not isinstance(tex.get("sampler"), (int, type(None))):
            raise d.bad(f"texture {index}: source/sampler are not indices")
        result = None
        if (source, tex.get("sampler")) in self._image_map:
            result = self._image_map[source, tex.get("sampler")]
        elif source is None:
            d.warnings.append(f"texture {index}: no image source we can read "
                              f"(extensions: {', '.join(ext) or 'none'}); factor only")
        elif len(self.textures) >= d.limits.max_textures:
            raise LimitExceeded(d.path, f"more than {d.limits.max_textures} textures")
        else:
            img = d.item("images", source, f"texture {index} source")
            probed = self._image(source, img)
            if probed is not None:
                data, size, label = probed
                self.textures.append(DeferredTexture(
                    name=str(img.get("name") or tex.get("name") or f"image{source}"), data=data,
                    size=size, limits=d.limits, sampler=self._sampler(tex.get("sampler")),
                    source=label))
                result = len(self.textures) - 1
            self._image_map[source, tex.get("sampler")] = result
        self._texture_map[index] = result
        return result

    def _image(self, source: int, img: dict) -> tuple[bytes | memoryview, tuple[int, int], str] | None:
        """An image's encoded bytes, size and label, probed once; None (warned) if unusable."""
        if source in self._images:
            return self._images[source]
        d = self.d
        data: bytes | memoryview
        if "bufferView" in img:
            data = d.view(d.integer(img, "bufferView"))[0]  # no copy: decoded later
            label = f"{d.path} image {source}"
        elif "uri" in img:
            try:
                data, file = d.payload(img["uri"], f"image {source}")
            except MissingFile as exc:  # the material keeps its factors; unsafe URIs still refuse
                self._drop(source, exc.reason)
                return None
            label = file or f"{d.path} image {source}"
        else:
            raise d.bad(f"image {source} has neither uri nor bufferView")
        try:
            size = probe_image(data, label, d.limits)
        except (MalformedAsset, LimitExceeded) as exc:
            self._drop(source, exc.reason)
        else:
            d.account(size[0] * size[1] * 4, f"image {source}")
            self._images[source] = (data, size, label)
        return self._images[source]

    def _drop(self, source: int, reason: str) -> None:
        self.d.warnings.append(f"image {source}: {reason}; its textures are dropped (factor only)")
        log.warning("%s: image %d dropped: %s", self.d.path, source, reason)
        self._images[source] = None

    def _sampler(self, index) -> Sampler:
        if index is None:
            return Sampler()
        s = self.d.item("samplers", index, "sampler")
        out = Sampler()
        for key, attr in (("magFilter", "mag_filter"), ("minFilter", "min_filter"),
                          ("wrapS", "wrap_s"), ("wrapT", "wrap_t")):
            if key in s:
                setattr(out, attr, self.d.integer(s, key))
        return out

    def add(self, texture: Texture) -> int:
        """Append a texture made at ingest (a converted one); its scene index."""
        if len(self.textures) >= self.d.limits.max_textures:
            raise LimitExceeded(self.d.path, f"more than {self.d.limits.max_textures} textures")
        self.textures.append(texture)
        return len(self.textures) - 1


def read_material(d: Document, tex: Textures, index: int) -> Material:
    """glTF material `index` as a Material, its textures added to `tex`."""
    m = d.item("materials", index, "material")
    slot = f"material {index}"
    pbr = d.obj(m.get("pbrMetallicRoughness"), f"{slot} pbrMetallicRoughness")
    ext = d.obj(m.get("extensions"), f"{slot} extensions")
    out = Material(name=str(m.get("name") or f"material{index}"))
    out.base_color = d.numbers(pbr, "baseColorFactor", (1.0, 1.0, 1.0, 1.0))
    out.base_color_texture = tex.ref(pbr.get("baseColorTexture"), f"{slot} baseColor")
    out.metallic = d.number(pbr, "metallicFactor", 1.0, 0.0, 1.0)
    out.roughness = d.number(pbr, "roughnessFactor", 1.0, 0.0, 1.0)
    out.metallic_roughness_texture = tex.ref(pbr.get("metallicRoughnessTexture"),
                                             f"{slot} metallicRoughness")
    normal = d.obj(m.get("normalTexture"), f"{slot} normalTexture")
    out.normal_texture = tex.ref(m.get("normalTexture"), f"{slot} normal")
    out.normal_scale = d.number(normal, "scale", 1.0)
    occlusion = d.obj(m.get("occlusionTexture"), f"{slot} occlusionTexture")
    out.occlusion_texture = tex.ref(m.get("occlusionTexture"), f"{slot} occlusion")
    out.occlusion_strength = d.number(occlusion, "strength", 1.0, 0.0, 1.0)
    out.emissive = d.numbers(m, "emissiveFactor", (0.0, 0.0, 0.0))
    out.emissive_texture = tex.ref(m.get("emissiveTexture"), f"{slot} emissive")
    if "KHR_materials_pbrSpecularGlossiness" in ext:
        _spec_gloss(d, tex, out, d.obj(ext["KHR_materials_pbrSpecularGlossiness"],
                                       f"{slot} pbrSpecularGlossiness"), slot)
    alpha_mode = m.get("alphaMode", "OPAQUE")
    if alpha_mode not in ("OPAQUE", "MASK", "BLEND"):
        raise d.bad(f"{slot}: alphaMode {alpha_mode!r} is not OPAQUE, MASK or BLEND")
    out.alpha_mode = alpha_mode
    out.alpha_cutoff = d.number(m, "alphaCutoff", 0.5, 0.0)
    out.double_sided = bool(m.get("doubleSided", False))
    out.unlit = "KHR_materials_unlit" in ext
    if "KHR_materials_emissive_strength" in ext:
        e = d.obj(ext["KHR_materials_emissive_strength"], "emissive_strength")
        out.emissive_strength = d.number(e, "emissiveStrength", 1.0, 0.0)
    if "KHR_materials_transmission" in ext:
        t = d.obj(ext["KHR_materials_transmission"], "transmission")
        out.transmission = d.number(t, "transmissionFactor", 0.0, 0.0, 1.0)
        out.transmission_texture = tex.ref(t.get("transmissionTexture"), f"{slot} transmission")
    if "KHR_materials_ior" in ext:
        out.ior = d.number(d.obj(ext["KHR_materials_ior"], "ior"), "ior", 1.5, 1.0)
    if "KHR_materials_volume" in ext:
        v = d.obj(ext["KHR_materials_volume"], "volume")
        out.thickness = d.number(v, "thicknessFactor", 0.0, 0.0)
        out.thickness_texture = tex.ref(v.get("thicknessTexture"), f"{slot} thickness")
        out.attenuation_color = d.numbers(v, "attenuationColor", (1.0, 1.0, 1.0))
        out.attenuation_distance = d.number(v, "attenuationDistance", math.inf, 1e-9)
    out.thin_walled = out.thickness <= 0.0  # the spec's thin-walled case, with or without volume
    read_lobes(d, tex, ext, out, slot)
    return out


def _spec_gloss(d: Document, tex: Textures, out: Material, sg: dict, slot: str) -> None:
    """KHR_materials_pbrSpecularGlossiness as metallic-roughness (pipeline.gltf.specgloss);
    it replaces the material's pbrMetallicRoughness values, as the extension says."""
    diffuse = d.numbers(sg, "diffuseFactor", (1.0, 1.0, 1.0, 1.0))
    specular = d.numbers(sg, "specularFactor", (1.0, 1.0, 1.0))
    gloss = d.number(sg, "glossinessFactor", 1.0, 0.0, 1.0)
    d_ref = tex.ref(sg.get("diffuseTexture"), f"{slot} diffuse")
    s_ref = tex.ref(sg.get("specularGlossinessTexture"), f"{slot} specularGlossiness")
    out.base_color, out.metallic, out.roughness = convert_factors(diffuse, specular, gloss)
    out.base_color_texture = out.metallic_roughness_texture = None
    if d_ref is None and s_ref is None:
        return
    if d_ref is not None and s_ref is not None and (d_ref.uv_set, d_ref.uv_matrix().tolist()) \
            != (s_ref.uv_set, s_ref.uv_matrix().tolist()):
        d.warnings.append(f"{slot}: diffuse and specularGlossiness textures use different "
                          "UVs; converted with the diffuse texture's")
    if len(tex.textures) + 2 > d.limits.max_textures:
        raise LimitExceeded(d.path, f"more than {d.limits.max_textures} textures")
    base, mr = conversion_textures(
        None if d_ref is None else tex.textures[d_ref.texture],
        None if s_ref is None else tex.textures[s_ref.texture], diffuse, specular, gloss)
    ref = d_ref or s_ref
    assert ref is not None  # one of them, by the return above
    w, h = cast(DeferredTexture, tex.textures[ref.texture]).size
    d.account(2 * 4 * w * h, f"{slot} converted textures")
    for converted, attr in ((base, "base_color_texture"), (mr, "metallic_roughness_texture")):
        setattr(out, attr, dataclasses.replace(ref, texture=tex.add(converted)))
    out.base_color, out.metallic, out.roughness = (1.0, 1.0, 1.0, 1.0), 1.0, 1.0


def read_lobes(d: Document, tex: Textures, ext: dict, out: Material, slot: str) -> None:
    """Fill `out` from the extension objects in `ext` (a material's `extensions`), through
    the document's checked JSON access and `tex.ref` (UV set, KHR_texture_transform, limits).
    Texture slots and their glTF keys come from the table."""
    for lobe in LOBES:
        if lobe.extension in ext:
            e = d.obj(ext[lobe.extension], f"{slot} {lobe.extension}")
            for t in lobe.slots:
                setattr(out, f"{t.name}_texture", tex.ref(
                    e.get(t.gltf), f"{slot} {t.gltf.removesuffix('Texture')}"))
    if "KHR_materials_specular" in ext:
        e = d.obj(ext["KHR_materials_specular"], f"{slot} KHR_materials_specular")
        out.specular = d.number(e, "specularFactor", 1.0, 0.0, 1.0)
        out.specular_color = tuple(max(c, 0.0) for c in d.numbers(e, "specularColorFactor",
                                                                  (1.0, 1.0, 1.0)))
    if "KHR_materials_clearcoat" in ext:
        e = d.obj(ext["KHR_materials_clearcoat"], f"{slot} KHR_materials_clearcoat")
        out.clearcoat = d.number(e, "clearcoatFactor", 0.0, 0.0, 1.0)
        out.clearcoat_roughness = d.number(e, "clearcoatRoughnessFactor", 0.0, 0.0, 1.0)
        normal = d.obj(e.get("clearcoatNormalTexture"), f"{slot} clearcoatNormalTexture")
        out.clearcoat_normal_scale = d.number(normal, "scale", 1.0)
    if "KHR_materials_sheen" in ext:
        e = d.obj(ext["KHR_materials_sheen"], f"{slot} KHR_materials_sheen")
        out.sheen_color = tuple(min(max(c, 0.0), 1.0) for c in d.numbers(
            e, "sheenColorFactor", (0.0, 0.0, 0.0)))
        out.sheen_roughness = d.number(e, "sheenRoughnessFactor", 0.0, 0.0, 1.0)
    if "KHR_materials_iridescence" in ext:
        e = d.obj(ext["KHR_materials_iridescence"], f"{slot} KHR_materials_iridescence")
        out.iridescence = d.number(e, "iridescenceFactor", 0.0, 0.0, 1.0)
        out.iridescence_ior = d.number(e, "iridescenceIor", 1.3, 1.0, 10.0)
        out.iridescence_thickness_range = (
            d.number(e, "iridescenceThicknessMinimum", 100.0, 0.0, 1e5),
            d.number(e, "iridescenceThicknessMaximum", 400.0, 0.0, 1e5))
    if "KHR_materials_anisotropy" in ext:
        e = d.obj(ext["KHR_materials_anisotropy"], f"{slot} KHR_materials_anisotropy")
        out.anisotropy_strength = d.number(e, "anisotropyStrength", 0.0, 0.0, 1.0)
        out.anisotropy_rotation = d.number(e, "anisotropyRotation", 0.0)
    if "KHR_materials_diffuse_transmission" in ext:
        e = d.obj(ext["KHR_materials_diffuse_transmission"],
                    f"{slot} KHR_materials_diffuse_transmission")
        out.diffuse_transmission = d.number(e, "diffuseTransmissionFactor", 0.0, 0.0, 1.0)
        out.diffuse_transmission_color = tuple(min(max(c, 0.0), 1.0) for c in d.numbers(
            e, "diffuseTransmissionColorFactor", (1.0, 1.0, 1.0)))
    if "KHR_materials_dispersion" in ext:
        e = d.obj(ext["KHR_materials_dispersion"], f"{slot} KHR_materials_dispersion")
        out.dispersion = d.number(e, "dispersion", 0.0, 0.0, 100.0)
