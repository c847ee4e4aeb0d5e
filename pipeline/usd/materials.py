"""UsdPreviewSurface networks -> the scene's one material model (glTF metallic-roughness+).

Each input is followed to what produces its value (`GetValueProducingAttributes`, through
NodeGraphs and interface inputs): a constant becomes the factor, a `UsdUVTexture` becomes a
TextureRef whose factor is the texture's `scale` for the channel read (texture x factor, as
glTF multiplies), a `UsdPrimvarReader_float3` on diffuseColor becomes vertex colours.
Channels land where glTF expects them (roughness G, metallic B, occlusion R, opacity in the
base colour's A); when an asset packs them differently a repacked texture is made, lazily.
`UsdTransform2d` between a texture and its primvar reader becomes KHR_texture_transform,
converted to the glTF UV convention (v down), as the geometry's `st` is.

Opacity, opacityThreshold and ior (the spec reads opacity as presence, and says a fully
transparent prim still reflects, like clear glass):
- opacityThreshold > 0: alpha MASK with that cutoff (cut-outs; opacity is coverage).
- opacity < 1 as a constant, threshold 0, ior authored and != 1, not metallic: a refractive
  dielectric. transmission = 1 - opacity, base alpha 1, ior kept, so the asset's glass goes
  through the refraction passes. Authoring an ior is the asset's statement that light bends.
- any other opacity < 1 (no ior authored, ior 1, metallic, or opacity from a texture):
  alpha BLEND with base alpha = opacity (presence: decals, foliage, fades).
USD says nothing of thickness or absorption, so those stay at their glTF defaults.
"""
from __future__ import annotations

import dataclasses
import io
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np
from PIL import Image
from pxr import Ar, Sdf, Usd, UsdShade

from core.colour import srgb_encode, srgb_to_linear
from core.errors import LimitExceeded, MalformedAsset, MissingFile
from core.scene import (
    CLAMP_TO_EDGE,
    MIRRORED_REPEAT,
    REPEAT,
    UDIM_FIRST,
    UDIM_LAST,
    Material,
    Sampler,
    Scene,
    Texture,
    TextureRef,
)
from pipeline import deadline, udim
from pipeline.images import EXR_MAGIC, PNG_SIGNATURE, DeferredTexture, probe_image
from pipeline.limits import Limits
from pipeline.usd import colorspaces, materialx
from pipeline.usd.layers import LayerGraph

log = logging.getLogger(__name__)

CHANNELS = {"r": 0, "g": 1, "b": 2, "a": 3, "rgb": 0, "rgba": 0}
WRAP = {"repeat": REPEAT, "mirror": MIRRORED_REPEAT, "clamp": CLAMP_TO_EDGE,
        "black": CLAMP_TO_EDGE, "useMetadata": REPEAT}
# UsdPreviewSurface fallbacks (its spec), where they differ from Material's glTF defaults.
DIFFUSE, METALLIC, ROUGHNESS, IOR = (0.18, 0.18, 0.18), 0.0, 0.5, 1.5
UDIM = "<UDIM>"  # the tile number's place in a UDIM texture's file name
HYDRA_GREY = (0.5, 0.5, 0.5)  # displayColor when a gprim authors none (UsdImaging's fallback)


@dataclass
class Binding:
    """A material as one mesh uses it: which primvars feed its UV sets and vertex colours."""
    material: int
    uv_primvars: tuple[str, ...] = ()    # uv_set i reads primvar uv_primvars[i]
    color_primvar: str | None = None     # multiplies the base colour (displayColor etc.)


@dataclass
class _Tex:
    """A UsdUVTexture read by one input."""
    texture: int
    output: str       # the output read: rgb, r, g, b, a
    scale: tuple[float, float, float, float]
    bias: tuple[float, float, float, float]
    primvar: str
    transform: tuple[tuple[float, float], float, tuple[float, float]]  # offset, rotation, scale
    color_space: str  # as resolved: "sRGB" or "raw" (auto decided by the image, Hio's rule)

    @property
    def channel(self) -> int:
        return CHANNELS[self.output]


def auto_source_srgb(data: bytes | memoryview) -> bool:
    """Whether Storm reads an image as sRGB under `sourceColorSpace = "auto"` (Hio's stb
    reader): a PNG gAMA chunk near 1/2.2 says sRGB and near 1.0 says linear; otherwise images
    of 3 or 4 channels are sRGB, 16-bit PNGs too (stb hands them over as 8-bit), and 1-2
    channel ones linear; OpenEXR (float) is linear. Checked against Storm on a stage of grey
    cards (tests/test_usd_look.py)."""
    head = bytes(data[:8])
    if head[:4] == EXR_MAGIC:
        return False
    if head == PNG_SIGNATURE:
        return _png_auto_srgb(data)
    try:
        with Image.open(io.BytesIO(bytes(data))) as im:  # header only
            mode = im.mode
    except Exception:  # noqa: BLE001 - unreadable here is refused where it is decoded
        return True
    return mode in ("RGB", "RGBA", "RGBX", "CMYK", "YCbCr", "P", "PA")


def _png_auto_srgb(data: bytes | memoryview) -> bool:
    if len(data) < 33:
        return True
    colour = data[25]
    pos = 8
    while pos + 8 <= len(data):  # the chunks before the pixels: a gAMA there decides
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = bytes(data[pos + 4:pos + 8])
        if kind == b"IDAT" or kind == b"IEND":
            break
        if kind == b"gAMA" and length == 4:
            gamma = int.from_bytes(data[pos + 8:pos + 12], "big") / 100000.0
            if abs(gamma - 0.45455) < 0.1:
                return True
            if abs(gamma - 1.0) < 0.1:
                return False
        pos += 12 + length
    return colour in (2, 3, 6)  # RGB, palette (expands to RGB(A)), RGBA; not grey (0), grey+alpha (4)


class _Recoded(Texture):
    """Another texture's colour channels re-encoded so that a slot reads them in the colour
    space the asset asked for: texels in `space` (colorspaces.Space) are taken to linear
    Rec.709, then sRGB-encoded for an sRGB slot (`encode`: base colour, emission) or kept
    linear for a data slot; alpha is kept. Linear Rec.709 into an sRGB slot and sRGB into a
    data slot are the common two; MaterialX's wider gamuts clip to 0..1 here."""

    def __init__(self, name: str, base: Texture, encode: bool,
                 space: colorspaces.Space | None = None):
        self.base, self.encode = base, encode
        self.space = space or (colorspaces.LIN_REC709 if encode else colorspaces.SRGB_TEXTURE)
        self._pixels: np.ndarray | None = None
        super().__init__(name=name, image=None, sampler=base.sampler, source=base.source,  # type: ignore[arg-type]  # made on first use
                         udim=base.udim)

    @property
    def image(self) -> np.ndarray:
        if self._pixels is None:
            rgba = self.base.image
            out = rgba.copy()
            if self.space in (colorspaces.LIN_REC709, colorspaces.SRGB_TEXTURE):
                out[..., :3] = _byte_table(self.space, self.encode)[rgba[..., :3]]
            else:  # a gamut mixes the channels: per texel
                lin = colorspaces.bytes_to_working(rgba[..., :3], self.space)
                y = srgb_encode(lin) if self.encode else lin
                out[..., :3] = np.round(y * 255.0).clip(0, 255).astype(np.uint8)
            self._pixels = out
        return self._pixels

    @image.setter
    def image(self, value) -> None:
        self._pixels = value


def _byte_table(space: colorspaces.Space, encode: bool) -> np.ndarray:
    """Byte -> byte for a channel-wise recode (Rec.709 gamut): what every texel would get."""
    if space == colorspaces.LIN_REC709:
        lin = np.arange(256, dtype=np.float64) / 255.0
    else:
        lin = srgb_to_linear(np.arange(256, dtype=np.uint8)).astype(np.float64)
    y = srgb_encode(lin) if encode else lin
    return np.round(y * 255.0).clip(0, 255).astype(np.uint8)


class _Packed(Texture):
    """Channels gathered from other textures (e.g. roughness G + metallic B), made on demand."""

    def __init__(self, name: str, parts: dict[int, tuple[Texture, int]], sampler: Sampler,
                 source: str):
        self.parts = parts  # dst channel -> (texture, src channel)
        self._pixels: np.ndarray | None = None
        # UDIM atlases of one layout scale onto each other cell for cell (MaterialReader._pack
        # warns when the parts' layouts differ)
        udim = next((t.udim for t, _ in parts.values() if t.udim is not None), None)
        super().__init__(name=name, image=None, sampler=sampler, source=source, udim=udim)  # type: ignore[arg-type]  # made on first use

    @property
    def image(self) -> np.ndarray:
        if self._pixels is None:
            h = max(t.image.shape[0] for t, _ in self.parts.values())
            w = max(t.image.shape[1] for t, _ in self.parts.values())
            out = np.full((h, w, 4), 255, np.uint8)
            for dst, (tex, src) in self.parts.items():
                out[..., dst] = _resized(tex.image[..., src], h, w)
            self._pixels = out
        return self._pixels

    @image.setter
    def image(self, value) -> None:
        self._pixels = value


def _resized(channel: np.ndarray, h: int, w: int) -> np.ndarray:
    if channel.shape == (h, w):
        return channel
    return np.asarray(Image.fromarray(channel).resize((w, h), Image.Resampling.BILINEAR))


class MaterialReader:
    """Turns bound UsdShade materials into Scene materials and textures, each once."""

    def __init__(self, graph: LayerGraph, scene: Scene, limits: Limits, time: Usd.TimeCode):
        self.graph, self.scene, self.limits, self.time = graph, scene, limits, time
        self._bindings: dict[tuple, Binding] = {}
        self._textures: dict[tuple, int | None] = {}  # (identifier, wrap) -> index
        self._packed: dict[tuple, int] = {}
        self._recoded: dict[tuple, int] = {}
        self._auto_srgb: dict[str, bool | None] = {}  # None: EXR
        self._materials: dict[str, int] = {}
        self._unpacked = 0
        self._documents: dict[str, object] = {}  # .mtlx identifier -> MaterialX document
        self._files: dict[tuple[str, str], materialx.File] = {}
        self._udim: dict[str, dict[int, str]] = {}  # UDIM pattern -> tile number -> identifier

    def bound(self, prim: Usd.Prim):
        """The material bound to `prim` (preview purpose, else all-purpose), or the binding's
        target path when no material prim is there (a .mtlx reference USD could not compose),
        or None."""
        material, rel = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(
            UsdShade.Tokens.preview)
        if material:
            return material
        targets = rel.GetTargets() if rel else []
        return targets[0] if targets else None

    def bind(self, material, double_sided: bool, has_display_color: bool | str,
             face_viewer: bool = False) -> Binding:
        """`material`: what `bound` returned; `has_display_color`: True, or "translucent"
        when its displayOpacity falls under 1; `face_viewer`: for Points (Material.face_viewer)."""
        if isinstance(material, Sdf.Path):
            key = (material, double_sided, has_display_color, face_viewer)
        else:
            key = (material.GetPath() if material else None, double_sided, has_display_color,
                   face_viewer)
        if key not in self._bindings:
            mat, uv_primvars, color_primvar = self._read(material, has_display_color)
            mat.double_sided = double_sided  # a gprim attribute in USD, a material one here
            # usdview culls no back faces by default (its cullBackfaces setting is off): a
            # single-sided gprim seen from behind is drawn, lit with its normal unflipped
            mat.show_back_faces = not double_sided
            mat.face_viewer = face_viewer
            self._bindings[key] = Binding(self._add(mat), uv_primvars, color_primvar)
        return self._bindings[key]

    # -- one material -----------------------------------------------------------------------
    def _read(self, material, has_display_color: bool | str):
        """(Material, uv primvar names, colour primvar name) for one bound material."""
        shader = None
        if isinstance(material, Sdf.Path):
            read = self._mtlx_reference(material)
            if read is not None:
                return read
            self._warn(f"material binding to {material}: no such material; drawn with the "
                       "fallback material")
            material = None
        if material:
            mtlx = material.ComputeSurfaceSource(materialx.RENDER_CONTEXT)[0]
            if mtlx and (mtlx.GetShaderId() or "").startswith("ND_"):
                return self._materialx(str(material.GetPath()), materialx.UsdNode(
                    mtlx, self.time, self._resolve_usd_file))
            shader = material.ComputeSurfaceSource()[0]
            if not shader or shader.GetShaderId() != "UsdPreviewSurface":
                what = shader.GetShaderId() if shader else "no surface shader"
                self._warn(f"material {material.GetPath()}: {what} is not UsdPreviewSurface; "
                           "drawn with the fallback material")
                shader = None
        if shader is None:  # USD draws unbound prims with displayColor when it has one
            if has_display_color:
                mat = Material(name="displayColor", base_color=(1.0, 1.0, 1.0, 1.0),
                               metallic=0.0, roughness=0.5)
                if has_display_color == "translucent":  # displayOpacity < 1 (the vertex alpha)
                    mat.alpha_mode = "BLEND"
                return mat, (), "displayColor"
            name = str(material.GetPath()) if material else "default"
            return fallback_material(name), (), None
        deadline.check()
        assert material is not None  # a shader comes from a bound material
        return self._preview_surface(str(material.GetPath()), shader)

    # -- MaterialX --------------------------------------------------------------------------
    def _materialx(self, name: str, node: "materialx.Node"):
        if node.category not in materialx.SURFACES:
            self._warn(f"material {name}: MaterialX surface {node.category or node.name!r} is "
                       f"not one of {', '.join(materialx.SURFACES)}; drawn with the fallback "
                       "material")
            return fallback_material(name), (), None
        reader = materialx.SurfaceReader(self, name, node)
        mat = reader.read()
        return mat, tuple(reader.uv_names[:2]), None

    def _mtlx_reference(self, target: Sdf.Path):
        """The material a binding to `target` names inside a referenced .mtlx document."""
        found = materialx.find_references(self.graph.stage, target, self.graph)
        if not found:
            return None
        shader = None
        for identifier, name in found:
            doc = self._document(identifier)
            shader = materialx.document_surface(doc, name) if doc is not None else None
            if shader is not None:
                break
        if shader is None:
            names = ", ".join(sorted({i.rsplit("/", 1)[-1] for i, _ in found}))
            self._warn(f"{target}: no surfacematerial {found[0][1]!r} with a surface shader in "
                       f"{names}; drawn with the fallback material")
            return fallback_material(str(target)), (), None
        resolve = lambda text, doc=identifier: self._resolve_file(doc, text)  # noqa: E731
        return self._materialx(str(target), materialx.MxNode(shader, resolve))

    def _document(self, identifier: str):
        """The parsed .mtlx at `identifier` (read once), or None with a warning."""
        if identifier not in self._documents:
            deadline.check()
            try:
                data = self.graph.read_bytes(identifier)
                self._documents[identifier] = materialx.read_document(data, identifier)
            except (MalformedAsset, OSError) as exc:
                self._warn(f"{identifier}: {getattr(exc, 'reason', exc)}; its materials are "
                           "drawn with the fallback material")
                self._documents[identifier] = None
        return self._documents[identifier]

    def _resolve_usd_file(self, attr: Usd.Attribute, text: str) -> "materialx.File":
        layer = authoring_layer(attr, self.time)
        try:
            if UDIM in text:
                return materialx.File(self._udim_tiles(
                    layer.ComputeAbsolutePath(text), text,
                    lambda numbers: self.graph.resolve_each(layer, text, UDIM, numbers)), text)
            return materialx.File(self.graph.resolve(layer, text), text)
        except MissingFile as exc:
            return materialx.File(None, text, exc)

    def _resolve_file(self, document: str, text: str) -> "materialx.File":
        key = (document, text)  # documents name one texture from many materials
        if key not in self._files:
            try:
                if UDIM in text:
                    pattern = str(Path(document).parent / text) if not \
                        Ar.IsPackageRelativePath(document) else f"{document}:{text}"
                    self._files[key] = materialx.File(self._udim_tiles(
                        pattern, text,
                        lambda numbers: self.graph.resolve_file_each(document, text, UDIM, numbers)),
                        text)
                else:
                    self._files[key] = materialx.File(self.graph.resolve_file(document, text), text)
            except MissingFile as exc:
                self._files[key] = materialx.File(None, text, exc)
        return self._files[key]

    # what materialx.SurfaceReader asks of its host
    def warn(self, text: str) -> None:
        self._warn(text)

    def texture(self, identifier: str, wrap: tuple[str, str]) -> int | None:
        return self._texture(identifier, wrap)

    def pack(self, parts: dict[int, tuple[int, int]]) -> int:
        return self._pack(parts)

    def recode(self, texture: int, srgb: bool, space: colorspaces.Space) -> int:
        """`texture`, whose texels are in `space`, re-encoded for a slot that decodes sRGB
        (`srgb`) or reads raw texels."""
        if space == (colorspaces.LIN_REC709 if srgb else colorspaces.SRGB_TEXTURE):
            return self._recode(texture, srgb, "raw" if srgb else "sRGB")
        return self._recode(texture, srgb, "_".join(space), space)

    def float_image(self, identifier: str) -> bool:
        """Whether `identifier` (a texture made before) is OpenEXR: its texels are held
        sRGB-encoded."""
        return self._auto_srgb.get(identifier, False) is None

    def add_material(self, mat: Material) -> int:
        """Index of `mat` in the scene (pipeline.usd.drawmode's stand-in materials)."""
        return self._add(mat)

    def _preview_surface(self, name: str, shader: UsdShade.Shader):
        mat = Material(name=name, metallic=METALLIC, roughness=ROUGHNESS, ior=IOR)
        uv_names: list[str] = []
        color_primvar = None
        alpha = 1.0

        def ref(tex: _Tex) -> TextureRef:
            if tex.primvar not in uv_names:
                uv_names.append(tex.primvar)
            uv_set = uv_names.index(tex.primvar)
            if uv_set > 1:
                self._warn(f"{name}: more than two UV primvars; {tex.primvar!r} read as UV set 1")
                uv_set = 1
            offset, rotation, scale = tex.transform
            return TextureRef(tex.texture, uv_set, offset, rotation, scale)

        diffuse = self._input(shader, "diffuseColor")
        if isinstance(diffuse, _Tex):
            diffuse = self._check_tex(name, "diffuseColor", diffuse, "sRGB")
            if diffuse.output in ("rgb", "rgba"):
                mat.base_color_texture = ref(diffuse)
                rgb = diffuse.scale[:3]
            else:  # one channel, drawn as grey
                c = diffuse.channel
                mat.base_color_texture = ref(_with(diffuse, self._pack(
                    {0: (diffuse.texture, c), 1: (diffuse.texture, c), 2: (diffuse.texture, c)})))
                rgb = (diffuse.scale[c],) * 3
        elif isinstance(diffuse, str):
            color_primvar, rgb = diffuse, (1.0, 1.0, 1.0)
        else:
            rgb = _vec(diffuse, 3, DIFFUSE)

        opacity = self._input(shader, "opacity")
        if isinstance(opacity, _Tex):
            opacity = self._check_tex(name, "opacity", opacity, "raw")
            alpha = _unit(opacity.scale[opacity.channel])
            base = mat.base_color_texture
            if base is not None and base.texture == opacity.texture and opacity.channel == 3:
                pass  # already the base colour texture's alpha
            else:
                packed = {3: (opacity.texture, opacity.channel)}
                if base is not None:
                    packed.update({c: (base.texture, c) for c in range(3)})
                mat.base_color_texture = ref(_with(opacity, self._pack(packed)))
        elif isinstance(opacity, str):
            self._warn(f"{name}: opacity from primvar {opacity!r} is not supported; opaque")
        else:
            alpha = _unit(_scalar(opacity, 1.0))
        mat.base_color = cast(tuple[float, float, float, float], (*[float(c) for c in rgb], 1.0))

        parts: dict[int, tuple[int, int]] = {}
        factors = {}
        for slot, channel in (("roughness", 1), ("metallic", 2)):
            value = self._input(shader, slot)
            if isinstance(value, _Tex):
                value = self._check_tex(name, slot, value, "raw")
                parts[channel] = (value.texture, value.channel)
                factors[slot] = value.scale[value.channel]
                tex_for_ref = value
            else:
                factors[slot] = float(_scalar(value, getattr(mat, slot)))
        # Clamped to 0..1 as the glTF reader clamps its factors: the one material model's range.
        mat.roughness, mat.metallic = _unit(factors["roughness"]), _unit(factors["metallic"])
        if parts:
            mat.metallic_roughness_texture = ref(_with(tex_for_ref, self._pack(parts)))

        occlusion = self._input(shader, "occlusion")
        if isinstance(occlusion, _Tex):
            occlusion = self._check_tex(name, "occlusion", occlusion, "raw")
            mat.occlusion_texture = ref(_with(occlusion, self._pack({0: (occlusion.texture,
                                                                         occlusion.channel)})))

        emissive = self._input(shader, "emissiveColor")
        if isinstance(emissive, _Tex):
            emissive = self._check_tex(name, "emissiveColor", emissive, "sRGB")
            mat.emissive_texture = ref(emissive)
            mat.emissive = cast(tuple[float, float, float], tuple(float(c) for c in emissive.scale[:3]))
        else:
            mat.emissive = cast(tuple[float, float, float], tuple(float(c) for c in _vec(emissive, 3, (0.0, 0.0, 0.0))))

        normal = self._input(shader, "normal")
        if isinstance(normal, _Tex):
            if not (np.allclose(normal.scale[:3], 2.0) and np.allclose(normal.bias[:3], -1.0)):
                self._warn(f"{name}: normal texture scale/bias {normal.scale[:3]}/"
                           f"{normal.bias[:3]} are not (2, -1); read as a standard normal map")
            # an 8-bit RGB normal map left at auto is sRGB-decoded by Storm too, bent normals
            mat.normal_texture = ref(self._in_space(normal, "raw"))

        displacement = self._input(shader, "displacement")
        if isinstance(displacement, (_Tex, str)) or _scalar(displacement, 0.0) != 0.0:
            # Storm moves the surface along its normal; a preview here keeps it where it is
            self._warn(f"{name}: UsdPreviewSurface displacement is not drawn; ignored")

        ior_input = shader.GetInput("ior")
        ior_authored = bool(ior_input) and ior_input.GetAttr().HasAuthoredValue()
        mat.ior = float(_scalar(self._input(shader, "ior"), IOR))
        if not math.isfinite(mat.ior) or mat.ior < 1.0:
            self._warn(f"{name}: ior {mat.ior} is not >= 1; 1.5 used")
            mat.ior = IOR
        threshold = float(_scalar(self._input(shader, "opacityThreshold"), 0.0))
        if threshold > 0.0:
            mat.alpha_mode, mat.alpha_cutoff = "MASK", threshold
            mat.base_color = (*mat.base_color[:3], alpha)
        elif isinstance(opacity, _Tex) or alpha < 1.0:
            refractive = (not isinstance(opacity, _Tex) and ior_authored
                          and abs(mat.ior - 1.0) > 1e-3 and mat.metallic < 1.0)
            if refractive:
                mat.transmission = 1.0 - alpha
            else:
                mat.alpha_mode = "BLEND"
                # as Storm blends it (core.scene.Material), for opacityMode "transparent" (the
                # default); "presence" fades the whole shading (Storm's previewSurface too)
                mat.opacity_premultiplied = self._input(shader, "opacityMode") != "presence"
                mat.base_color = (*mat.base_color[:3], alpha)
        if int(_scalar(self._input(shader, "useSpecularWorkflow"), 0)):
            # UsdPreviewSurface's specular workflow (as Storm's previewSurface shades it):
            # F0 = specularColor (fallback black), F90 = 1, metallic unused, ior for
            # refraction only. As KHR_materials_specular, whose dielectric F0 is
            # ((ior-1)/(ior+1))^2 x specular_color (the product clamped to 1) with F90 = the
            # specular factor: specular_color = specularColor / that IOR's F0, factor 1.
            mat.metallic, mat.specular = 0.0, 1.0
            f0 = ((mat.ior - 1.0) / (mat.ior + 1.0)) ** 2
            if f0 < 1e-4:  # ior ~1 reflects nothing to tint: its own F0 (1.5's) stands in
                self._warn(f"{name}: specular workflow with ior {mat.ior}: specularColor read "
                           "over ior 1.5's reflectance, the refraction keeps ior 1.5")
                mat.ior, f0 = IOR, ((IOR - 1.0) / (IOR + 1.0)) ** 2
            spec = self._input(shader, "specularColor")
            if isinstance(spec, _Tex):
                spec = self._check_tex(name, "specularColor", spec, "sRGB")
                if spec.output in ("rgb", "rgba"):
                    mat.specular_color_texture = ref(spec)
                    rgb = spec.scale[:3]
                else:  # one channel, as grey
                    c = spec.channel
                    mat.specular_color_texture = ref(_with(spec, self._pack(
                        {0: (spec.texture, c), 1: (spec.texture, c), 2: (spec.texture, c)})))
                    rgb = (spec.scale[c],) * 3
            elif isinstance(spec, str):
                self._warn(f"{name}: specularColor from primvar {spec!r} is not supported; black")
                rgb = (0.0, 0.0, 0.0)
            else:
                rgb = _vec(spec, 3, (0.0, 0.0, 0.0))
            mat.specular_color = cast(tuple[float, float, float],
                                      tuple(max(float(c), 0.0) / f0 for c in rgb))
        return mat, tuple(uv_names), color_primvar

    # -- inputs ---------------------------------------------------------------------------------
    def _input(self, shader: UsdShade.Shader, name: str):
        """The value an input resolves to: a constant, a _Tex, a primvar name, or None."""
        inp = shader.GetInput(name)
        if not inp:
            return None
        attrs = inp.GetValueProducingAttributes()
        if not attrs:
            return None
        attr = attrs[0]
        if not UsdShade.Output.IsOutput(attr):
            return attr.Get(self.time)
        node = UsdShade.Shader(attr.GetPrim())
        output = UsdShade.Output(attr).GetBaseName()
        kind = node.GetShaderId() or ""
        if kind == "UsdUVTexture":
            return self._uv_texture(node, output)
        if kind.startswith("UsdPrimvarReader_"):
            return self._primvar_name(node)
        self._warn(f"{shader.GetPath()}.{name}: node {kind or node.GetPath()} is not supported; "
                   "its fallback value is used")
        return None

    def _primvar_name(self, reader: UsdShade.Shader) -> str | None:
        value = self._input(reader, "varname")
        return str(value) if value else None

    def _uv_texture(self, node: UsdShade.Shader, output: str):
        """A _Tex, or when the image cannot be used the node's `fallback` for `output`
        (UsdUVTexture's own rule; its default is black)."""
        fallback = _vec(self._input(node, "fallback"), 4, (0.0, 0.0, 0.0, 1.0))
        fallback = fallback[:3] if output in ("rgb", "rgba") else fallback[CHANNELS.get(output, 0)]
        file_input = node.GetInput("file")
        producers = file_input.GetValueProducingAttributes() if file_input else []
        attr = producers[0] if producers else None  # may be a material's interface input
        asset = attr.Get(self.time) if attr is not None else None
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            self._warn(f"{node.GetPath()}: UsdUVTexture without a file; its fallback is used")
            return fallback
        layer = authoring_layer(attr, self.time)
        try:
            if UDIM in asset.path:
                identifier = self._udim_tiles(
                    layer.ComputeAbsolutePath(asset.path), asset.path,
                    lambda numbers: self.graph.resolve_each(layer, asset.path, UDIM, numbers))
            else:
                identifier = self.graph.resolve(layer, asset.path)  # refuses unsafe
        except MissingFile as exc:
            self._warn(f"{node.GetPath()}: {exc.reason}; its fallback is used")
            return fallback
        wrap = (str(self._input(node, "wrapS") or "useMetadata"),
                str(self._input(node, "wrapT") or "useMetadata"))
        for w in wrap:
            if w == "black":
                self._warn(f"{node.GetPath()}: wrap 'black' drawn as clamp")
        texture = self._texture(identifier, wrap)
        if texture is None:
            return fallback
        st = node.GetInput("st")
        primvar, transform = "st", ((0.0, 0.0), 0.0, (1.0, 1.0))
        source = st.GetValueProducingAttributes() if st else []
        if source and UsdShade.Output.IsOutput(source[0]):
            prev = UsdShade.Shader(source[0].GetPrim())
            if prev.GetShaderId() == "UsdTransform2d":
                transform = _transform2d(self._input(prev, "rotation"), self._input(prev, "scale"),
                                         self._input(prev, "translation"))
                src = prev.GetInput("in")
                source = src.GetValueProducingAttributes() if src else []
                prev = UsdShade.Shader(source[0].GetPrim()) if source and \
                    UsdShade.Output.IsOutput(source[0]) else None
            if prev and (prev.GetShaderId() or "").startswith("UsdPrimvarReader_"):
                primvar = self._primvar_name(prev) or "st"
        else:  # unconnected: every point reads st's value (fallback (0, 0)), as UsdShade says
            value = _vec(self._input(node, "st"), 2, (0.0, 0.0))
            primvar = constant_st(float(value[0]), float(value[1]))
        return _Tex(texture, output if output in CHANNELS else "rgb",
                    tuple(_vec(self._input(node, "scale"), 4, (1.0, 1.0, 1.0, 1.0))),
                    tuple(_vec(self._input(node, "bias"), 4, (0.0, 0.0, 0.0, 0.0))),
                    primvar, transform, self._color_space(node, identifier))

    def _color_space(self, node: UsdShade.Shader, identifier: str) -> str:
        declared = str(self._input(node, "sourceColorSpace") or "auto")
        if self._auto_srgb[identifier] is None:  # EXR: decoded as sRGB-encoded linear values
            if declared == "sRGB":
                self._warn(f"{node.GetPath()}: sourceColorSpace 'sRGB' on an OpenEXR image is "
                           "read as linear")
            return "sRGB"
        if declared in ("raw", "sRGB"):
            return declared
        if declared != "auto":
            self._warn(f"{node.GetPath()}: sourceColorSpace {declared!r} is not one of raw, sRGB, "
                       "auto; read as auto")
        return "sRGB" if self._auto_srgb[identifier] else "raw"

    def _udim_tiles(self, pattern: str, text: str, lookup) -> str:
        """`pattern` (a file path holding <UDIM>, as its layer resolves it), its tiles found
        by `lookup(numbers)` (LayerGraph.resolve_each: tile number -> identifier) as Storm
        looks for them, 1001 to 1100, the absent ones left out; MissingFile when there is
        none, LimitExceeded past `max_udim_tiles`."""
        if pattern not in self._udim:
            tiles = lookup(range(UDIM_FIRST, UDIM_LAST + 1))
            if len(tiles) > self.limits.max_udim_tiles:
                raise LimitExceeded(pattern, f"UDIM texture has {len(tiles)} tiles, more than "
                                             f"{self.limits.max_udim_tiles} "
                                             "(ASSET_PREVIEW_MAX_UDIM_TILES)")
            if not tiles:
                raise MissingFile(pattern, f"no UDIM tile of {text!r} ({UDIM_FIRST} to "
                                           f"{UDIM_LAST}) found")
            self._udim[pattern] = tiles
        return pattern

    def _udim_texture(self, pattern: str, wrap: tuple[str, str]) -> int | None:
        """The atlas of `pattern`'s tiles (pipeline.udim); a tile that does not decode is
        dropped with a warning, as a missing one."""
        tiles: dict[int, DeferredTexture] = {}
        name = pattern.rsplit("/", 1)[-1].rstrip("]")
        for number, identifier in self._udim[pattern].items():
            data = self.graph.read_bytes(identifier)
            try:
                w, h = probe_image(data, identifier, self.limits)
            except (MalformedAsset, LimitExceeded) as exc:
                self._warn(f"UDIM tile {identifier}: {exc.reason}; dropped")
                continue
            self._unpacked += w * h * 4
            if self._unpacked > self.limits.max_unpacked_bytes:
                raise LimitExceeded(pattern, f"decoded textures would exceed "
                                             f"{self.limits.max_unpacked_bytes} bytes (UDIM "
                                             f"tile {number})")
            if not tiles:  # the first tile's encoding decides auto's colour space for all
                self._auto_srgb[pattern] = None if bytes(data[:4]) == EXR_MAGIC else \
                    auto_source_srgb(data)
            tiles[number] = DeferredTexture(name=f"{name}:{number}", data=data, size=(w, h),
                                            limits=self.limits, source=identifier)
        if not tiles:
            self._warn(f"UDIM texture {pattern}: no tile decodes; dropped (factor only)")
            return None
        layout = udim.layout_for(sorted(tiles))
        cell = udim.cell_size([t.size for t in tiles.values()], layout,
                              self.limits.max_texture_pixels)
        self.scene.textures.append(udim.UdimTexture(name, dict(tiles), layout, cell, pattern))
        return len(self.scene.textures) - 1

    def _texture(self, identifier: str, wrap: tuple[str, str]) -> int | None:
        key = (identifier, wrap)
        if key in self._textures:
            return self._textures[key]
        deadline.check()
        if len(self.scene.textures) >= self.limits.max_textures:
            raise LimitExceeded(self.graph.path, f"more than {self.limits.max_textures} textures")
        if identifier in self._udim:  # one atlas whatever the wrap (pipeline.udim: clamped)
            if (identifier, None) not in self._textures:
                self._textures[(identifier, None)] = self._udim_texture(identifier, wrap)
            self._textures[key] = self._textures[(identifier, None)]
            return self._textures[key]
        data = self.graph.read_bytes(identifier)
        self._auto_srgb[identifier] = None if bytes(data[:4]) == EXR_MAGIC else auto_source_srgb(data)
        index = None
        try:
            w, h = probe_image(data, identifier, self.limits)
        except (MalformedAsset, LimitExceeded) as exc:
            self._warn(f"texture {identifier}: {exc.reason}; dropped (factor only)")
        else:
            self._unpacked += w * h * 4
            if self._unpacked > self.limits.max_unpacked_bytes:
                raise LimitExceeded(self.graph.path, f"decoded textures would exceed "
                                                     f"{self.limits.max_unpacked_bytes} bytes")
            sampler = Sampler(wrap_s=WRAP.get(wrap[0], REPEAT), wrap_t=WRAP.get(wrap[1], REPEAT))
            name = identifier.rsplit("/", 1)[-1].rstrip("]")
            self.scene.textures.append(DeferredTexture(name=name, data=data, size=(w, h),
                                                       limits=self.limits, sampler=sampler,
                                                       source=identifier))
            index = len(self.scene.textures) - 1
        self._textures[key] = index
        return index

    def _pack(self, parts: dict[int, tuple[int, int]]) -> int:
        """A texture holding channel `src` of texture `t` at `dst`, for each dst: (t, src);
        the source texture itself when nothing moves and it is the only one."""
        if len({t for t, _ in parts.values()}) == 1 and all(d == s for d, (_, s) in parts.items()):
            return next(iter(parts.values()))[0]
        key = tuple(sorted(parts.items()))
        if key not in self._packed:
            first = self.scene.textures[next(iter(parts.values()))[0]]
            layouts = {self.scene.textures[t].udim for t, _ in parts.values()}
            if len(layouts) > 1:
                self._warn(f"channels of {first.name} packed with textures of other UDIM tiles "
                           "(or none); they read the first UDIM texture's layout")
            self.scene.textures.append(_Packed(
                name="+".join(f"{self.scene.textures[t].name}.{'rgba'[s]}"
                              for _, (t, s) in sorted(parts.items())),
                sampler=first.sampler, source=first.source,
                parts={d: (self.scene.textures[t], s) for d, (t, s) in parts.items()}))
            self._packed[key] = len(self.scene.textures) - 1
        return self._packed[key]

    def _check_tex(self, name: str, slot: str, tex: _Tex, expected: str) -> _Tex:
        """`tex` as the slot reads it: the slot decodes sRGB (`expected` "sRGB") or reads
        texels as they are ("raw"); a texture in the other space is re-encoded (8 bits: a
        linear texel written as sRGB comes back within half a step of it)."""
        if tex.bias != (0.0, 0.0, 0.0, 0.0):
            self._warn(f"{name}: {slot} texture bias {tex.bias} is ignored")
        return self._in_space(tex, expected)

    def _in_space(self, tex: _Tex, expected: str) -> _Tex:
        if tex.color_space == expected or tex.output == "a":  # alpha is never decoded
            return tex
        recoded = self._recode(tex.texture, expected == "sRGB", tex.color_space)
        return dataclasses.replace(_with(tex, recoded), color_space=expected)

    def _recode(self, texture: int, encode: bool, name: str,
                space: colorspaces.Space | None = None) -> int:
        """Texture `texture` re-encoded for a slot reading sRGB (`encode`) or raw texels,
        made once; `name` names the space it is in, `space` gives it when it is neither
        linear nor sRGB Rec.709."""
        key = (texture, encode, space)
        if key not in self._recoded:
            base = self.scene.textures[texture]
            self.scene.textures.append(_Recoded(f"{base.name}.{name}", base, encode, space))
            self._recoded[key] = len(self.scene.textures) - 1
        return self._recoded[key]

    def _add(self, mat: Material) -> int:
        """Index of `mat` in the scene, shared with an equal one added before (many USD
        assets repeat one material per referenced copy)."""
        key = repr(dataclasses.replace(mat, name=""))
        if key not in self._materials:
            self.scene.materials.append(mat)
            self._materials[key] = len(self.scene.materials) - 1
        return self._materials[key]

    def _warn(self, text: str) -> None:
        if text not in self.scene.warnings:
            self.scene.warnings.append(text)
            log.info("%s: %s", self.graph.path, text)  # said once, as the scene's warning


def fallback_material(name: str) -> Material:
    """What Hydra draws a gprim with when it has no usable material and no displayColor:
    displayColor's fallback, 0.5 linear grey (UsdImagingGprimAdapter::GetColor), opaque."""
    return Material(name=name, base_color=(*HYDRA_GREY, 1.0), metallic=0.0, roughness=0.5)


def _with(tex: _Tex, texture: int) -> _Tex:
    return dataclasses.replace(tex, texture=texture)


def constant_st(s: float, t: float) -> str:
    """The uv set name of a texture whose `st` is unconnected: one st for every point."""
    return f"={s!r},{t!r}"


def authoring_layer(attr: Usd.Attribute, time: Usd.TimeCode) -> Sdf.Layer:
    """The layer whose opinion gives `attr` its value: asset paths are relative to it."""
    for spec in attr.GetPropertyStack(time):
        if spec.HasDefaultValue() or spec.layer.GetNumTimeSamplesForPath(spec.path):
            return spec.layer
    return attr.GetStage().GetRootLayer()


def _transform2d(rotation, scale, translation):
    """UsdTransform2d (scale, rotate degrees CCW, translate, in st with v up) expressed as
    KHR_texture_transform in glTF UVs (v down): flip v, apply, flip back."""
    theta = math.radians(float(_scalar(rotation, 0.0)))
    sx, sy = _vec(scale, 2, (1.0, 1.0))
    tx, ty = _vec(translation, 2, (0.0, 0.0))
    offset = (tx - math.sin(theta) * sy, 1.0 - ty - math.cos(theta) * sy)
    return (float(offset[0]), float(offset[1])), theta, (float(sx), float(sy))


def _unit(value: float) -> float:
    return min(max(float(value), 0.0), 1.0)


def _scalar(value, default):
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    return v if math.isfinite(v) else default


def _vec(value, n: int, default):
    try:
        v = [float(x) for x in value][:n]
    except (TypeError, ValueError):
        return default
    return tuple(v) if len(v) == n and all(math.isfinite(x) for x in v) else default
