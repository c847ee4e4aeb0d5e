"""MaterialX surfaces -> the scene's one material model, with PyMaterialX (the `materialx` wheel).

Two ways a USD asset carries MaterialX, read by one evaluator:
- a `.mtlx` document referenced from USD (`references = @look.mtlx@</MaterialX/Materials>`).
  usd-core's wheel has no MaterialX file-format plugin, so USD cannot compose it; the binding
  target (`/Asset/mtl/M_Gold`) is mapped back through the referencing prim to the document's
  `surfacematerial` of that name (`find_references`: in each referenced document, in order) and the document is read here;
- UsdShade networks authored in USD with MaterialX node ids (`info:id = "ND_standard_surface_
  surfaceshader"`, on the material's `outputs:mtlx:surface`).

Each surface input is followed to what produces it: a value (the node definition's default when
unauthored), an `image` / `tiledimage` (a texture, with `texcoord` / `geompropvalue` UVs and
`place2d` / tiling transforms, converted to KHR_texture_transform), or a graph of `constant`,
`multiply`, `add`, `subtract`, `divide`, `mix`, `extract`, `convert`, `dot` nodes, folded to a
constant (or a texture times a factor, as glTF multiplies). A `normalmap` node feeds the normal
texture. Any other node is a warning naming it, and that input keeps its default. The mapping
of the surfaces' inputs onto Material is the README's table (and the SurfaceReader
methods below); MaterialX's `UsdPreviewSurface` node reads as the UsdShade one does.
Colour constants and images are taken from their declared colorspace to lin_rec709
(pipeline.usd.colorspaces: MaterialX's standard spaces).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from pxr import Sdf, UsdShade

from core.errors import AssetError, MalformedAsset
from core.scene import Material, TextureRef
from pipeline.usd import colorspaces
from pipeline.usd.colorspaces import Space

SURFACES = ("standard_surface", "open_pbr_surface", "gltf_pbr", "UsdPreviewSurface")
RENDER_CONTEXT = "mtlx"  # UsdShade render context of MaterialX surfaces (outputs:mtlx:surface)
MAX_DEPTH = 64  # node chain length: a cycle or a hostile graph ends here
WRAPS = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}
COLOUR_TYPES = ("color3", "color4", "color3f", "color4f")  # MaterialX's and Sdf's names


@lru_cache(maxsize=1)
def library():
    """MaterialX's standard node definitions (defaults and categories), loaded once: slow to load."""
    import MaterialX as mx  # here and below: only stages with MaterialX pay its import
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


@lru_cache(maxsize=None)
def nodedef(category: str, type_: str):
    lib = library()
    for nd in lib.getMatchingNodeDefs(category):
        if nd.getType() == type_:
            return nd
    return None


# -- values the evaluator passes around -----------------------------------------------------

@dataclass
class UV:
    """A texture coordinate: the primvar read, then `matrix` (3x3, st space, v up) applied."""
    primvar: str = "st"
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))


@dataclass
class Tex:
    """An image read at `channels` times `factor` (one per channel); `space` is what its
    stored 8-bit texels encode (colorspaces.Space)."""
    texture: int
    channels: tuple[int, ...]
    factor: np.ndarray
    uv: UV
    space: Space
    node: str

    def channel(self, i: int = 0) -> "Tex":
        i = min(i, len(self.channels) - 1)
        return Tex(self.texture, (self.channels[i],), self.factor[i:i + 1], self.uv, self.space,
                   self.node)


@dataclass
class NormalMap:
    tex: Tex
    scale: float


@dataclass
class File:
    """A filename input: the identifier it resolves to, or the error that refused it."""
    identifier: str | None
    text: str
    error: AssetError | None = None


# -- the node adapters ----------------------------------------------------------------------

class Node:
    """What the evaluator needs of a node, from PyMaterialX or from UsdShade."""
    name: str
    category: str
    type: str

    def get(self, name: str):
        """None (unauthored), ("value", v), ("file", File) or ("node", Node, output)."""
        raise NotImplementedError

    def default(self, name: str):
        return _default(self.category, self.type, name)


@lru_cache(maxsize=4096)
def _default(category: str, type_: str, name: str):
    nd = nodedef(category, type_)
    inp = nd.getActiveInput(name) if nd is not None else None
    if inp is None or not inp.hasValueString():
        return None
    return _plain(inp.getValue())


class MxNode(Node):
    """A node of a .mtlx document; `resolve(text)` turns a filename into an identifier."""

    def __init__(self, node, resolve):
        self.node, self.resolve = node, resolve
        self.name, self.category, self.type = node.getNamePath(), node.getCategory(), node.getType()

    def get(self, name: str):
        inp = self.node.getInput(name)
        for _ in range(MAX_DEPTH):  # interfacename: the enclosing nodegraph's input
            if inp is None or not inp.hasInterfaceName():
                break
            inp = inp.getInterfaceInput()
        if inp is None:
            return None
        upstream = inp.getConnectedNode()
        if upstream is not None:
            output = inp.getOutputString()
            if inp.getNodeGraphString() and inp.getConnectedOutput() is not None:
                output = inp.getConnectedOutput().getOutputString()
            return ("node", MxNode(upstream, self.resolve), output or "out")
        if inp.getNodeName() or inp.getNodeGraphString():
            return None  # dangling connection: the default applies
        if not inp.hasValueString():
            return None
        if inp.getType() == "filename":
            return ("file", self.resolve(inp.getResolvedValueString()))
        if inp.getType() in COLOUR_TYPES:  # its own, else the nearest enclosing colorspace
            return ("value", _plain(inp.getValue()), inp.getActiveColorSpace())
        return ("value", _plain(inp.getValue()))

    def colorspace(self, name: str) -> str:
        """The input's own colorspace, else that of the nodegraph interface input giving its
        value (as MaterialX's shader generation takes a file's), else the nearest enclosing
        element's."""
        inp = self.node.getInput(name)
        if inp is None:
            return ""
        first = inp
        for _ in range(MAX_DEPTH):
            if inp.getColorSpace() or not inp.hasInterfaceName() or inp.getInterfaceInput() is None:
                break
            inp = inp.getInterfaceInput()
        return inp.getColorSpace() or first.getActiveColorSpace()


class UsdNode(Node):
    """A UsdShade.Shader with a MaterialX node id (`ND_...`); `resolve(attr, asset_path)`."""

    def __init__(self, shader, time, resolve):
        self.shader, self.time, self.resolve = shader, time, resolve
        ident = shader.GetShaderId() or ""
        nd = library().getNodeDef(ident)
        self.name = str(shader.GetPath())
        self.category = nd.getNodeString() if nd is not None else ident
        self.type = nd.getType() if nd is not None else ""
        self._nd = nd

    def default(self, name: str):
        inp = self._nd.getActiveInput(name) if self._nd is not None else None
        if inp is None or not inp.hasValueString():
            return None
        return _plain(inp.getValue())

    def get(self, name: str):
        inp = self.shader.GetInput(name)
        attrs = inp.GetValueProducingAttributes() if inp else []
        if not attrs:
            return None
        attr = attrs[0]
        if UsdShade.Output.IsOutput(attr):
            return ("node", UsdNode(UsdShade.Shader(attr.GetPrim()), self.time, self.resolve),
                    UsdShade.Output(attr).GetBaseName())
        value = attr.Get(self.time)
        if value is None:
            return None
        if isinstance(value, Sdf.AssetPath):
            return ("file", self.resolve(attr, value.path))
        if str(attr.GetTypeName()) in COLOUR_TYPES:  # usdMtlx writes colorSpace metadata
            return ("value", _plain(value), str(attr.GetColorSpace()))
        return ("value", _plain(value))

    def colorspace(self, name: str) -> str:
        """The colorSpace metadata of the attribute giving the input its value (a material's
        interface input, say), else of the input itself."""
        inp = self.shader.GetInput(name)
        if not inp:
            return ""
        for attr in list(inp.GetValueProducingAttributes()[:1]) + [inp.GetAttr()]:
            space = str(attr.GetColorSpace()) if attr.HasColorSpace() else ""
            if space:
                return space
        return ""


def _plain(v):
    """A MaterialX or Gf value as a float array, or the string / bool it is."""
    if isinstance(v, (str, bool)):
        return v
    if isinstance(v, (int, float)):
        return np.array([float(v)])
    try:
        seq = v.asTuple() if hasattr(v, "asTuple") else tuple(v)
        return np.array([float(x) for x in seq])
    except (TypeError, ValueError):
        return str(v)


# -- evaluating -----------------------------------------------------------------------------

class Evaluator:
    """Folds the graph behind one input; `host` makes textures and takes warnings
    (usd_materials.MaterialReader: `texture(identifier, wraps)`, `pack(parts)`, `warn(text)`,
    `scene`)."""

    def __init__(self, host, material: str):
        self.host, self.material = host, material

    def input(self, node: Node, name: str, depth: int = 0):
        got = node.get(name)
        if got is None:
            d = node.default(name)
            return d.copy() if isinstance(d, np.ndarray) else d  # the cached default stays
        if got[0] == "value":
            if len(got) > 2 and got[2]:
                return self.working(got[1], got[2], f"{node.name}.{name}")
            return got[1]
        if got[0] == "file":
            return got[1]
        return self.output(got[1], got[2], depth + 1, f"{node.name}.{name}")

    def space(self, name: str, where: str) -> Space | None:
        """The standard colour space `name` declares, or None with a warning."""
        space = colorspaces.lookup(name)
        if space is None:
            self.host.warn(f"{self.material}: colorspace {name!r} at {where} is not one of "
                           "MaterialX's standard colour spaces; read as lin_rec709")
        return space

    def working(self, value, name: str, where: str):
        """A colour constant declared in colour space `name`, in lin_rec709 (alpha kept)."""
        space = self.space(name, where)
        if space is None or space == colorspaces.LIN_REC709 or not isinstance(value, np.ndarray) \
                or len(value) < 3:
            return value
        out = value.copy()
        out[:3] = colorspaces.to_working(value[:3], space)
        return out

    def output(self, node: Node, out: str, depth: int, where: str):
        if depth > MAX_DEPTH:
            raise MalformedAsset(self.material, f"MaterialX graph at {node.name} is deeper than "
                                                f"{MAX_DEPTH} nodes (a cycle?)")
        cat = node.category
        arg = lambda n: self.input(node, n, depth)  # noqa: E731
        if cat == "constant":
            return arg("value")
        if cat in ("image", "tiledimage"):
            return self._image(node, arg)
        if cat == "texcoord":
            index = _num(arg("index"), 0)
            return UV("st" if not index else f"st{int(index)}")
        if cat == "geompropvalue":
            prop = arg("geomprop")
            return UV(str(prop) if isinstance(prop, str) and prop else "st")
        if cat == "place2d":
            return self._place2d(node, arg)
        if cat == "normalmap":
            tex = arg("in")
            if isinstance(tex, Tex):
                return NormalMap(tex, _num(arg("scale"), 1.0))
            return None
        if cat in ("dot", "convert"):
            return arg("in")
        if cat == "extract":
            v = arg("in")
            i = int(_num(arg("index"), 0))
            if isinstance(v, Tex):
                return v.channel(i)
            if isinstance(v, np.ndarray):
                return v[min(i, len(v) - 1):][:1]
        if cat in ("multiply", "add", "subtract", "divide"):
            folded = _fold(cat, arg("in1"), arg("in2"))
            if folded is not None:
                return folded
        if cat == "mix":
            fg, bg, mix = arg("fg"), arg("bg"), arg("mix")
            if all(isinstance(v, np.ndarray) for v in (fg, bg, mix)):
                return mix * fg + (1 - mix) * bg
        self.host.warn(f"{self.material}: MaterialX node {node.name!r} ({cat}) feeding {where} "
                       "is not read; the input's default is used")
        return None

    def _image(self, node: Node, arg):
        file = arg("file")
        if not isinstance(file, File) or file.identifier is None:
            why = file.error.reason if isinstance(file, File) and file.error else "no file"
            self.host.warn(f"{self.material}: image {node.name!r}: {why}; its default is used")
            return arg("default")
        wraps = (WRAPS.get(str(arg("uaddressmode")), "repeat"),
                 WRAPS.get(str(arg("vaddressmode")), "repeat"))
        texture = self.host.texture(file.identifier, wraps)
        if texture is None:
            return arg("default")
        uv = arg("texcoord")
        uv = uv if isinstance(uv, UV) else UV()
        if node.category == "tiledimage":
            tiling = _vec(arg("uvtiling"), 2, (1.0, 1.0))
            offset = _vec(arg("uvoffset"), 2, (0.0, 0.0))
            m = np.array([[tiling[0], 0, -offset[0]], [0, tiling[1], -offset[1]], [0, 0, 1]])
            uv = UV(uv.primvar, m @ uv.matrix)
        n = {"float": 1, "vector2": 2, "color3": 3, "vector3": 3, "color4": 4,
             "vector4": 4}.get(node.type, 3)
        return Tex(texture, tuple(range(n)), np.ones(n), uv,
                   self._texel_space(node, file.identifier), node.name)

    def _texel_space(self, node: Node, identifier: str) -> Space:
        """What an image's stored texels encode. Undeclared: colour images sRGB, others
        linear (as Storm reads them). A colour image's gamut is converted as MaterialX's
        colour management converts the image node's output; a float or vector image has no
        gamut, only its transfer is undone. OpenEXR texels are held sRGB-encoded (linear
        files), so only the declared gamut applies to them."""
        colour = node.type in ("color3", "color4")
        declared = node.colorspace("file") if hasattr(node, "colorspace") else ""
        space = (self.space(declared, f"{node.name}.file") if declared else None) or \
            (colorspaces.SRGB_TEXTURE if colour and not declared else colorspaces.LIN_REC709)
        transfer, gamut = space if colour else (space[0], "rec709")
        if self.host.float_image(identifier):
            if transfer != "linear" and declared:
                self.host.warn(f"{self.material}: image {node.name!r}: colorspace {declared!r} "
                               "on an OpenEXR image: its values are read as linear")
            transfer = "srgb"
        return (transfer, gamut)

    def _place2d(self, node: Node, arg):
        uv = arg("texcoord")
        uv = uv if isinstance(uv, UV) else UV()
        px, py = _vec(arg("pivot"), 2, (0.0, 0.0))
        sx, sy = _vec(arg("scale"), 2, (1.0, 1.0))
        ox, oy = _vec(arg("offset"), 2, (0.0, 0.0))
        if sx == 0 or sy == 0:
            self.host.warn(f"{self.material}: place2d {node.name!r} scale is zero; ignored")
            return uv
        t = math.radians(_num(arg("rotate"), 0.0))
        c, s = math.cos(t), math.sin(t)
        rot = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # MaterialX rotate2d
        move = lambda x, y: np.array([[1, 0, x], [0, 1, y], [0, 0, 1.0]])  # noqa: E731
        inv_scale = np.diag([1 / sx, 1 / sy, 1.0])
        if int(_num(arg("operationorder"), 0)) == 0:  # scale, rotate, then offset
            m = move(px, py) @ move(-ox, -oy) @ rot @ inv_scale @ move(-px, -py)
        else:
            m = move(px, py) @ inv_scale @ rot @ move(-ox, -oy) @ move(-px, -py)
        return UV(uv.primvar, m @ uv.matrix)


def _fold(op: str, a, b):
    """a (op) b when both are constants, or a texture scaled by a constant."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        if op == "divide":
            b = np.where(b == 0, 1.0, b)
        n = max(len(a), len(b))
        a, b = np.resize(a, n) if len(a) == 1 else a, np.resize(b, n) if len(b) == 1 else b
        if len(a) != len(b):
            return None
        return {"multiply": a * b, "add": a + b, "subtract": a - b, "divide": a / b}[op]
    if op == "multiply" and isinstance(b, Tex) and isinstance(a, np.ndarray):
        a, b = b, a
    if isinstance(a, Tex) and isinstance(b, np.ndarray):
        if op in ("multiply", "divide"):
            k = b if op == "multiply" else 1.0 / np.where(b == 0, 1.0, b)
            if len(k) in (1, len(a.channels)):
                return Tex(a.texture, a.channels, a.factor * np.resize(k, len(a.channels)),
                           a.uv, a.space, a.node)
        elif op in ("add", "subtract") and not np.any(b):
            return a
    return None


# -- surfaces -> Material ----------------------------------------------------------------------

class SurfaceReader:
    """One surface shader node read into a Material; `uv_names` lists the primvars its
    textures read (UV set i = uv_names[i])."""

    def __init__(self, host, name: str, node: Node):
        self.host, self.name, self.node = host, name, node
        self.eval = Evaluator(host, name)
        self.uv_names: list[str] = []
        self.mat = Material(name=name)

    def read(self) -> Material:
        getattr(self, "_" + self.node.category)()
        return self.mat

    # inputs as (constant, texture or None)
    def color(self, name: str, default=(1.0, 1.0, 1.0)):
        v = self.eval.input(self.node, name)
        if isinstance(v, Tex):
            if len(v.channels) == 1:
                v = Tex(v.texture, v.channels * 3, np.repeat(v.factor, 3), v.uv, v.space, v.node)
            return tuple(float(x) for x in v.factor[:3]), v
        return _vec(v, 3, default), None

    def scalar(self, name: str, default=0.0):
        v = self.eval.input(self.node, name)
        if isinstance(v, Tex):
            v = v.channel(0)
            return float(v.factor[0]), v
        if isinstance(v, np.ndarray) and len(v) > 1:  # color3 opacity etc: their mean
            return float(np.mean(v)), None
        return _num(v, default), None

    def ref(self, tex: Tex, texture: int | None = None, expect_srgb: bool | None = None):
        """`texture` (else tex's own) for a slot that decodes sRGB (`expect_srgb`) or reads
        texels raw; an image in another space is re-encoded (converted to lin_rec709 first),
        as usdview's Storm loads MaterialX images raw and converts each from its declared
        colorspace. A gamut needs the image's three channels: a repacked texture keeps only
        the transfer's conversion."""
        index = tex.texture if texture is None else texture
        space = tex.space
        if index != tex.texture and space[1] != "rec709":
            self.warn(f"the {space[1]} gamut of {tex.node!r} is not converted where its "
                      "channels are repacked; only its transfer is")
            space = (space[0], "rec709")
        if expect_srgb is not None and \
                space != (colorspaces.SRGB_TEXTURE if expect_srgb else colorspaces.LIN_REC709):
            index = self.host.recode(index, expect_srgb, space)
        if tex.uv.primvar not in self.uv_names:
            self.uv_names.append(tex.uv.primvar)
        uv_set = self.uv_names.index(tex.uv.primvar)
        if uv_set > 1:
            self.warn(f"more than two UV primvars; {tex.uv.primvar!r} read as UV set 1")
            uv_set = 1
        offset, rotation, scale = gltf_transform(tex.uv.matrix, self.warn)
        return TextureRef(index, uv_set, offset, rotation, scale)

    def pack(self, parts: dict[int, Tex]) -> int:
        return self.host.pack({dst: (t.texture, t.channels[0]) for dst, t in parts.items()})

    def warn(self, text: str) -> None:
        self.host.warn(f"{self.name}: {text}")

    def untextured(self, slot: str, value):
        const, tex = value
        if tex is not None:
            self.warn(f"{slot} from a texture is not supported; its factor {const} is used")
        return const

    # -- the common tail: base colour, metal/rough, normal, emission, opacity, transmission
    def finish(self, base, metallic, roughness, normal, emission, opacity, transmission,
               occlusion=None):
        m = self.mat
        rgb, tex = base
        if tex is not None:
            if tex.channels == (0, 1, 2):
                m.base_color_texture = self.ref(tex, expect_srgb=True)
            else:
                m.base_color_texture = self.ref(tex, self.pack({c: tex.channel(c) for c in range(3)}),
                                                expect_srgb=True)
        parts = {channel: t for channel, (_, t) in ((1, roughness), (2, metallic)) if t is not None}
        m.roughness, m.metallic = _unit(roughness[0]), _unit(metallic[0])
        if parts:
            first = next(iter(parts.values()))
            m.metallic_roughness_texture = self.ref(first, self.pack(parts), expect_srgb=False)
        if occlusion is not None and occlusion[1] is not None:
            m.occlusion_texture = self.ref(occlusion[1], self.pack({0: occlusion[1]}))
        if isinstance(normal, NormalMap):
            m.normal_texture = self.ref(normal.tex, expect_srgb=False)
            m.normal_scale = normal.scale
        elif isinstance(normal, Tex):
            self.warn("normal input reads an image without a normalmap node; read as a "
                      "tangent-space normal map")
            m.normal_texture = self.ref(normal, expect_srgb=False)
        e_rgb, e_tex = emission
        peak = max(e_rgb)
        if peak > 1.0:  # keep emissive in 0..1 as glTF does, the rest in emissive_strength
            m.emissive, m.emissive_strength = (e_rgb[0] / peak, e_rgb[1] / peak, e_rgb[2] / peak), peak
        else:
            m.emissive = (float(e_rgb[0]), float(e_rgb[1]), float(e_rgb[2]))
        if e_tex is not None:
            m.emissive_texture = self.ref(e_tex, expect_srgb=True)
        alpha, a_tex = opacity
        alpha = _unit(alpha)
        if a_tex is not None:
            packed = {3: a_tex}
            if m.base_color_texture is not None:
                base_tex = self.host.scene.textures[m.base_color_texture.texture]
                packed.update({c: Tex(m.base_color_texture.texture, (c,), np.ones(1), a_tex.uv,
                                      colorspaces.SRGB_TEXTURE, base_tex.name) for c in range(3)})
            m.base_color_texture = self.ref(a_tex, self.pack(packed))
            m.alpha_mode = "BLEND"
        elif alpha < 1.0:
            m.alpha_mode = "BLEND"
        m.base_color = (_unit(rgb[0]), _unit(rgb[1]), _unit(rgb[2]), alpha)
        t_value, t_tex = transmission
        m.transmission = _unit(t_value)
        if t_tex is not None:
            m.transmission_texture = self.ref(t_tex, self.pack({0: t_tex}), expect_srgb=False)

    # -- the three surfaces ---------------------------------------------------------------
    def coat_tint(self, rgb, tex, weight_name: str):
        """The base colour seen through the coat: standard_surface and OpenPBR tint all that
        lies under the coat by coat_color, mixed in by the coat's weight (usd-wg's tiled
        brass is a white metal under a brass-coloured coat). Folded into the base colour:
        base x mix(1, coat_color, weight); a textured coat colour becomes the base colour's
        texture where the base has none."""
        k = _unit(self.scalar(weight_name, 0.0)[0])
        c_rgb, c_tex = self.color("coat_color")
        if k <= 0 or (c_tex is None and all(abs(c - 1.0) < 1e-6 for c in c_rgb)):
            return rgb, tex
        if c_tex is None:
            return tuple(b * (1 - k + k * c) for b, c in zip(rgb, c_rgb)), tex
        if tex is not None:
            self.warn("coat_color from a texture over a textured base colour is not supported; "
                      "the base is drawn untinted")
            return rgb, tex
        if k < 1:
            self.warn(f"coat_color from a texture at coat weight {k:g} is applied at full weight")
        return tuple(b * c for b, c in zip(rgb, c_rgb)), c_tex

    def _standard_surface(self):
        m = self.mat
        weight = self.scalar("base", 1.0)[0]
        rgb, tex = self.color("base_color", (0.8, 0.8, 0.8))
        rgb = tuple(c * weight for c in rgb)
        rgb, tex = self.coat_tint(rgb, tex, "coat")
        transmission = self.scalar("transmission", 0.0)
        t_color = self.untextured("transmission_color", self.color("transmission_color"))
        depth = self.scalar("transmission_depth", 0.0)[0]
        if transmission[0] > 0 or transmission[1] is not None:
            if depth > 0:
                m.attenuation_color, m.attenuation_distance = t_color, depth
            elif tex is None:  # thin tint: glTF tints transmission by the base colour
                k = _unit(transmission[0])
                rgb = tuple((1 - k) * b + k * t for b, t in zip(rgb, t_color))
        m.ior = _ior(self.scalar("specular_IOR", 1.5)[0], self.warn)
        m.specular = _unit(self.untextured("specular", self.scalar("specular", 1.0)))
        m.specular_color = self.untextured("specular_color", self.color("specular_color"))
        m.clearcoat = _unit(self.untextured("coat", self.scalar("coat", 0.0)))
        m.clearcoat_roughness = _unit(self.untextured("coat_roughness",
                                                      self.scalar("coat_roughness", 0.1)))
        sheen = self.untextured("sheen", self.scalar("sheen", 0.0))
        sheen_rgb = self.untextured("sheen_color", self.color("sheen_color"))
        m.sheen_color = (_unit(sheen * sheen_rgb[0]), _unit(sheen * sheen_rgb[1]), _unit(sheen * sheen_rgb[2]))
        m.sheen_roughness = _unit(self.untextured("sheen_roughness",
                                                  self.scalar("sheen_roughness", 0.3)))
        film = self.untextured("thin_film_thickness", self.scalar("thin_film_thickness", 0.0))
        if film > 0:  # nanometres, as KHR_materials_iridescence
            m.iridescence, m.iridescence_thickness_range = 1.0, (film, film)
            m.iridescence_ior = self.untextured("thin_film_IOR", self.scalar("thin_film_IOR", 1.5))
        m.anisotropy_strength = _unit(self.untextured("specular_anisotropy",
                                                      self.scalar("specular_anisotropy", 0.0)))
        m.anisotropy_rotation = 2 * math.pi * self.untextured(
            "specular_rotation", self.scalar("specular_rotation", 0.0))
        e = self.scalar("emission", 0.0)[0]
        e_rgb, e_tex = self.color("emission_color")
        for slot in ("subsurface", "thin_walled"):
            v = self.eval.input(self.node, slot)
            if v is True or (not isinstance(v, bool) and _num(v, 0.0) > 0):
                self.warn(f"{slot} is not supported; ignored")
        self.finish((rgb, tex), self.scalar("metalness", 0.0), self.scalar("specular_roughness", 0.2),
                    self.eval.input(self.node, "normal"), (tuple(e * c for c in e_rgb), e_tex),
                    self.scalar("opacity", 1.0), transmission)

    def _open_pbr_surface(self):
        m = self.mat
        weight = self.scalar("base_weight", 1.0)[0]
        rgb, tex = self.color("base_color", (0.8, 0.8, 0.8))
        rgb = tuple(c * weight for c in rgb)
        rgb, tex = self.coat_tint(rgb, tex, "coat_weight")
        transmission = self.scalar("transmission_weight", 0.0)
        t_color = self.untextured("transmission_color", self.color("transmission_color"))
        depth = self.scalar("transmission_depth", 0.0)[0]
        if transmission[0] > 0 or transmission[1] is not None:
            if depth > 0:
                m.attenuation_color, m.attenuation_distance = t_color, depth
            elif tex is None:
                k = _unit(transmission[0])
                rgb = tuple((1 - k) * b + k * t for b, t in zip(rgb, t_color))
        m.ior = _ior(self.scalar("specular_ior", 1.5)[0], self.warn)
        m.specular = _unit(self.untextured("specular_weight", self.scalar("specular_weight", 1.0)))
        m.specular_color = self.untextured("specular_color", self.color("specular_color"))
        m.clearcoat = _unit(self.untextured("coat_weight", self.scalar("coat_weight", 0.0)))
        m.clearcoat_roughness = _unit(self.untextured("coat_roughness",
                                                      self.scalar("coat_roughness", 0.0)))
        fuzz = self.untextured("fuzz_weight", self.scalar("fuzz_weight", 0.0))
        fuzz_rgb = self.untextured("fuzz_color", self.color("fuzz_color"))
        m.sheen_color = (_unit(fuzz * fuzz_rgb[0]), _unit(fuzz * fuzz_rgb[1]), _unit(fuzz * fuzz_rgb[2]))
        m.sheen_roughness = _unit(self.untextured("fuzz_roughness",
                                                  self.scalar("fuzz_roughness", 0.5)))
        film = self.untextured("thin_film_weight", self.scalar("thin_film_weight", 0.0))
        if film > 0:  # OpenPBR's thickness is in micrometres; glTF's in nanometres
            nm = 1000.0 * self.untextured("thin_film_thickness",
                                          self.scalar("thin_film_thickness", 0.5))
            m.iridescence, m.iridescence_thickness_range = _unit(film), (nm, nm)
            m.iridescence_ior = self.untextured("thin_film_ior", self.scalar("thin_film_ior", 1.4))
        m.anisotropy_strength = _unit(self.untextured(
            "specular_roughness_anisotropy", self.scalar("specular_roughness_anisotropy", 0.0)))
        lum = self.scalar("emission_luminance", 0.0)[0]
        e_rgb, e_tex = self.color("emission_color")
        if _num(self.eval.input(self.node, "subsurface_weight"), 0.0) > 0:
            self.warn("subsurface_weight is not supported; ignored")
        self.finish((rgb, tex), self.scalar("base_metalness", 0.0),
                    self.scalar("specular_roughness", 0.3),
                    self.eval.input(self.node, "geometry_normal"),
                    (tuple(lum * c for c in e_rgb), e_tex), self.scalar("geometry_opacity", 1.0),
                    transmission)

    def _gltf_pbr(self):
        m = self.mat
        m.ior = _ior(self.scalar("ior", 1.5)[0], self.warn)
        m.specular = _unit(self.untextured("specular", self.scalar("specular", 1.0)))
        m.specular_color = self.untextured("specular_color", self.color("specular_color"))
        m.clearcoat = _unit(self.untextured("clearcoat", self.scalar("clearcoat", 0.0)))
        m.clearcoat_roughness = _unit(self.untextured("clearcoat_roughness",
                                                      self.scalar("clearcoat_roughness", 0.0)))
        m.sheen_color = self.untextured("sheen_color", self.color("sheen_color", (0.0, 0.0, 0.0)))
        m.sheen_roughness = _unit(self.untextured("sheen_roughness",
                                                  self.scalar("sheen_roughness", 0.0)))
        m.iridescence = _unit(self.untextured("iridescence", self.scalar("iridescence", 0.0)))
        m.iridescence_ior = self.untextured("iridescence_ior", self.scalar("iridescence_ior", 1.3))
        nm = self.untextured("iridescence_thickness", self.scalar("iridescence_thickness", 100.0))
        m.iridescence_thickness_range = (nm, nm)
        m.thickness = max(0.0, self.untextured("thickness", self.scalar("thickness", 0.0)))
        dist = self.eval.input(self.node, "attenuation_distance")
        if isinstance(dist, np.ndarray) and dist[0] > 0:
            m.attenuation_distance = float(dist[0])
        m.attenuation_color = self.untextured("attenuation_color", self.color("attenuation_color"))
        m.anisotropy_strength = _unit(self.untextured("anisotropy_strength",
                                                      self.scalar("anisotropy_strength", 0.0)))
        m.anisotropy_rotation = self.untextured("anisotropy_rotation",
                                                self.scalar("anisotropy_rotation", 0.0))
        e_rgb, e_tex = self.color("emissive", (0.0, 0.0, 0.0))
        strength = self.scalar("emissive_strength", 1.0)[0]
        mode = int(_num(self.eval.input(self.node, "alpha_mode"), 0))
        alpha = self.scalar("alpha", 1.0)
        self.finish(self.color("base_color"), self.scalar("metallic", 1.0),
                    self.scalar("roughness", 1.0), self.eval.input(self.node, "normal"),
                    (tuple(strength * c for c in e_rgb), e_tex),
                    alpha if mode else (1.0, None), self.scalar("transmission", 0.0),
                    occlusion=self.scalar("occlusion", 1.0))
        if mode == 1:
            m.alpha_mode, m.alpha_cutoff = "MASK", _num(self.eval.input(self.node, "alpha_cutoff"), 0.5)


    def _UsdPreviewSurface(self):  # noqa: N802  # named after its node category
        """ND_UsdPreviewSurface_surfaceshader: the UsdPreviewSurface spec's inputs, read as
        pipeline/usd/materials.py reads the UsdShade one (opacityThreshold > 0 a cut-out; a
        constant opacity under 1 with an authored ior other than 1 on a dielectric a
        refractive transmission, else a blend; the specular workflow's specularColor as
        KHR_materials_specular's F0 colour)."""
        m = self.mat
        m.ior = _ior(self.scalar("ior", 1.5)[0], self.warn)
        m.clearcoat = _unit(self.untextured("clearcoat", self.scalar("clearcoat", 0.0)))
        m.clearcoat_roughness = _unit(self.untextured("clearcoatRoughness",
                                                      self.scalar("clearcoatRoughness", 0.01)))
        metallic = self.scalar("metallic", 0.0)
        opacity = self.scalar("opacity", 1.0)
        threshold = _num(self.eval.input(self.node, "opacityThreshold"), 0.0)
        transmission: tuple[float, Tex | None] = (0.0, None)
        if threshold <= 0 and opacity[1] is None and opacity[0] < 1.0 and \
                self.node.get("ior") is not None and abs(m.ior - 1.0) > 1e-3 and \
                metallic[1] is None and metallic[0] < 1.0:
            transmission, opacity = (1.0 - _unit(opacity[0]), None), (1.0, None)
        if _num(self.eval.input(self.node, "displacement"), 0.0) != 0.0:
            self.warn("displacement is not supported; ignored")
        self.finish(self.color("diffuseColor", (0.18, 0.18, 0.18)), metallic,
                    self.scalar("roughness", 0.5), self.eval.input(self.node, "normal"),
                    self.color("emissiveColor", (0.0, 0.0, 0.0)), opacity, transmission,
                    occlusion=self.scalar("occlusion", 1.0))
        if threshold > 0:
            m.alpha_mode, m.alpha_cutoff = "MASK", threshold
        elif m.alpha_mode == "BLEND":
            # MaterialX's own definition (bxdf/usd_preview_surface.mtlx) layers the whole
            # specular over mix(transmission, diffuse, opacity): the premultiplied rule of
            # the UsdShade node (standard_surface's opacity is presence: a faded blend)
            m.opacity_premultiplied = True
        if int(_num(self.eval.input(self.node, "useSpecularWorkflow"), 0)):
            # F0 = specularColor, F90 = 1, metallic unused (Storm's previewSurface); as
            # KHR_materials_specular: specular_color = specularColor / F0(ior), factor 1
            # metallic factor 0: a metallic texture channel then counts for nothing
            m.metallic, m.specular = 0.0, 1.0
            f0 = ((m.ior - 1.0) / (m.ior + 1.0)) ** 2
            if f0 < 1e-4:
                self.warn(f"specular workflow with ior {m.ior}: specularColor read over ior "
                          "1.5's reflectance, the refraction keeps ior 1.5")
                m.ior, f0 = 1.5, 0.04
            rgb, tex = self.color("specularColor", (0.0, 0.0, 0.0))
            if tex is not None:
                packed = None if tex.channels == (0, 1, 2) else \
                    self.pack({c: tex.channel(c) for c in range(3)})
                m.specular_color_texture = self.ref(tex, packed, expect_srgb=True)
            m.specular_color = tuple(max(float(c), 0.0) / f0 for c in rgb)  # type: ignore[assignment]


# -- .mtlx documents referenced from USD ------------------------------------------------------

def find_references(stage, target, graph) -> list[tuple[str, str]]:
    """[(identifier of a .mtlx, material name)] a binding to the missing prim `target` may
    mean, strongest arc first: every reference or payload to a .mtlx file on the nearest
    existing ancestor, with `target` mapped into the usdMtlx namespace
    (/MaterialX/Materials/<name>). A stage often references several documents on one prim;
    the material is the one of the first document that defines it."""
    path = target
    prim = stage.GetPrimAtPath(path)
    while not prim and path.pathElementCount > 1:
        path = path.GetParentPath()
        prim = stage.GetPrimAtPath(path)
    if not prim:
        return []
    tail = target.MakeRelativePath(path)
    found = []
    for spec in prim.GetPrimStack():
        arcs = list(spec.referenceList.GetAddedOrExplicitItems()) + \
            list(spec.payloadList.GetAddedOrExplicitItems())
        for arc in arcs:
            if not arc.assetPath.lower().endswith(".mtlx"):
                continue
            inside = arc.primPath if not arc.primPath.isEmpty else Sdf.Path("/MaterialX")
            full = inside if tail == Sdf.Path(".") else inside.AppendPath(tail)
            parts = str(full).strip("/").split("/")
            if len(parts) == 3 and parts[:2] == ["MaterialX", "Materials"]:
                found.append((graph.resolve(spec.layer, arc.assetPath), parts[2]))
    return found


def read_document(data: bytes, where: str):
    """A parsed .mtlx document; XIncludes are not followed (they would read files unchecked)."""
    import MaterialX as mx
    doc = mx.createDocument()
    options = mx.XmlReadOptions()
    options.readXIncludeFunction = None
    try:
        mx.readFromXmlString(doc, data.decode("utf-8"), mx.FileSearchPath(), options)
    except (UnicodeDecodeError, mx.ExceptionParseError, mx.Exception) as exc:
        raise MalformedAsset(where, f"not a readable MaterialX document: {exc}") from None
    return doc


def document_surface(doc, material: str):
    """The surface shader node of `material` in `doc`, or None."""
    node = doc.getNode(material)
    if node is None or node.getType() != "material":
        return None
    import MaterialX as mx
    shaders = [s for s in mx.getShaderNodes(node) if s.getType() == "surfaceshader"]
    return shaders[0] if shaders else None


# -- small helpers ------------------------------------------------------------------------------

def gltf_transform(m_st: np.ndarray, warn=None):
    """A 3x3 affine map of st (v up) as KHR_texture_transform (offset, rotation, scale) in glTF
    UVs (v down): F M F with F the v flip, split into T R S."""
    flip = np.array([[1, 0, 0], [0, -1, 1], [0, 0, 1.0]])
    g = flip @ m_st @ flip
    lin = g[:2, :2]
    sx = float(np.hypot(lin[0, 0], lin[1, 0]))
    theta = math.atan2(-lin[1, 0], lin[0, 0]) if sx > 0 else 0.0
    s, c = math.sin(theta), math.cos(theta)
    sy = float(lin[0, 1] * s + lin[1, 1] * c)
    if warn and not np.allclose(lin[:, 1], sy * np.array([s, c]), atol=1e-6):
        warn("texture transform has a shear (scale after a rotation); drawn without it")
    return (float(g[0, 2]) + 0.0, float(g[1, 2]) + 0.0), float(theta) + 0.0, (sx, sy)


def _ior(value: float, warn) -> float:
    if not math.isfinite(value) or value < 1.0:
        warn(f"ior {value} is not >= 1; 1.5 used")
        return 1.5
    return float(value)


def _unit(value) -> float:
    return min(max(float(value), 0.0), 1.0)


def _num(value, default: float) -> float:
    if isinstance(value, np.ndarray) and len(value):
        v = float(value[0])
        return v if math.isfinite(v) else default
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    return default


def _vec(value, n: int, default):
    if isinstance(value, np.ndarray) and np.isfinite(value).all():
        if len(value) == 1:
            return tuple(float(value[0]) for _ in range(n))
        if len(value) >= n:
            return tuple(float(x) for x in value[:n])
    return tuple(default)
