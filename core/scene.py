"""The scene model every ingest produces: plain dataclasses holding numpy arrays.

No GL objects and no file handles. Units are metres, world space is right-handed with +Y up
(glTF). Colours in factors are linear; texture images are stored as decoded RGBA8 and carry
whether they hold sRGB colour (converted to linear when sampled, never here).
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal, cast

import numpy as np

from core.lobes import SRGB_SLOTS  # texture slots holding colour (sRGB decoded), by extension

MaterialClass = Literal["opaque", "mask", "blend", "transmissive"]


def is_srgb(slot: str) -> bool:
    """Whether a material slot (`base_color` or `base_color_texture`) holds sRGB colour."""
    return slot.removesuffix("_texture") in SRGB_SLOTS

AlphaMode = Literal["OPAQUE", "MASK", "BLEND"]

# OpenGL / glTF sampler enums.
NEAREST, LINEAR = 9728, 9729
LINEAR_MIPMAP_LINEAR = 9987
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648


@dataclass
class Sampler:
    mag_filter: int = LINEAR
    min_filter: int = LINEAR_MIPMAP_LINEAR
    wrap_s: int = REPEAT
    wrap_t: int = REPEAT


UDIM_FIRST, UDIM_LAST = 1001, 1100  # the tiles a UDIM pattern names (10 across, 10 up)
UDIM_GUTTER = 1 / 18  # of a padded cell's side, each edge: a tile of C texels gets C/16


@dataclass(frozen=True)
class UdimLayout:
    """Where the tiles of a UDIM texture (tile 1001 + u + 10 v covers st [u, u+1] x [v, v+1])
    lie in its atlas: cells of equal size, row-major from the top left in `columns` x `rows`,
    `tiles[k]` in cell k; the cells after the last tile are empty (transparent black, which
    is what Storm reads where a tile is missing). Each cell's edge texels are repeated into a
    gutter (UDIM_GUTTER of the cell each side) so that bilinear taps and the first mips stay
    inside it. The bake remaps a mesh's UVs into the cells (pipeline.udim)."""
    tiles: tuple[int, ...]
    columns: int
    rows: int

    @property
    def empty_cell(self) -> int:
        return len(self.tiles)


@dataclass
class Texture:
    """A decoded image: `image` is H x W x 4 uint8, row 0 at the top (as glTF UVs expect)."""
    name: str
    image: np.ndarray
    sampler: Sampler = field(default_factory=Sampler)
    source: str = ""  # file or URI it came from, for messages
    udim: UdimLayout | None = None  # an atlas of UDIM tiles, read through remapped UVs


@dataclass
class TextureRef:
    """Use of a texture by a material slot, with its UV set and KHR_texture_transform."""
    texture: int  # index into Scene.textures
    uv_set: int = 0
    offset: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0
    scale: tuple[float, float] = (1.0, 1.0)

    def uv_matrix(self) -> np.ndarray:
        """3x3 matrix applied to (u, v, 1): translation * rotation * scale, as the extension says."""
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        t = np.array([[1, 0, self.offset[0]], [0, 1, self.offset[1]], [0, 0, 1]], np.float32)
        r = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], np.float32)
        k = np.diag([self.scale[0], self.scale[1], 1.0]).astype(np.float32)
        return t @ r @ k


@dataclass
class Material:
    """One material model for every format: glTF metallic-roughness plus transmission/volume."""
    name: str = "default"
    base_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    base_color_texture: TextureRef | None = None
    metallic: float = 1.0
    roughness: float = 1.0
    metallic_roughness_texture: TextureRef | None = None  # B = metallic, G = roughness
    normal_texture: TextureRef | None = None
    normal_scale: float = 1.0
    occlusion_texture: TextureRef | None = None  # R channel
    occlusion_strength: float = 1.0
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    emissive_texture: TextureRef | None = None
    emissive_strength: float = 1.0
    alpha_mode: AlphaMode = "OPAQUE"
    alpha_cutoff: float = 0.5
    # BLEND as Storm blends a UsdPreviewSurface: opacity scales the diffuse share only, the
    # specular (and emission) stay whole, over (1 - opacity) of what is behind; glTF's BLEND
    # (False) fades the whole shaded colour by alpha.
    opacity_premultiplied: bool = False
    double_sided: bool = False
    # A single-sided surface whose back faces are drawn (not culled) and shaded with the
    # normal as it is, unflipped: a USD gprim with doubleSided = 0, as usdview draws it by
    # default (no backface culling; Storm flips the normal only of a double-sided gprim).
    show_back_faces: bool = False
    # Shaded with the normal toward the viewer wherever it is seen: a UsdGeom.Points sprite,
    # which Storm draws as a flat screen-facing disc (its geometry here is a small sphere that
    # gives the disc's outline)
    face_viewer: bool = False
    unlit: bool = False
    # KHR_materials_transmission / _ior / _volume
    transmission: float = 0.0
    transmission_texture: TextureRef | None = None  # R channel
    ior: float = 1.5
    thickness: float = 0.0
    # glTF: no KHR_materials_volume, or thicknessFactor 0, is a thin-walled sheet: light
    # crosses it unbent and unabsorbed, tinted by base colour (renderer/methods/refraction.py)
    thin_walled: bool = False
    thickness_texture: TextureRef | None = None  # G channel
    attenuation_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    attenuation_distance: float = math.inf
    # KHR_materials_specular / _clearcoat / _sheen / _iridescence / _anisotropy (glTF defaults,
    # which mean "absent": a material that uses none compiles none: core/lobes.py);
    # glTF fills them in pipeline/gltf/materials.py, MaterialX surfaces in pipeline/usd/materialx.py.
    specular: float = 1.0
    specular_texture: TextureRef | None = None  # A channel
    specular_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    specular_color_texture: TextureRef | None = None  # RGB, sRGB
    clearcoat: float = 0.0
    clearcoat_texture: TextureRef | None = None  # R
    clearcoat_roughness: float = 0.0
    clearcoat_roughness_texture: TextureRef | None = None  # G
    clearcoat_normal_texture: TextureRef | None = None
    clearcoat_normal_scale: float = 1.0
    sheen_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sheen_color_texture: TextureRef | None = None  # RGB, sRGB
    sheen_roughness: float = 0.0
    sheen_roughness_texture: TextureRef | None = None  # A
    iridescence: float = 0.0
    iridescence_texture: TextureRef | None = None  # R
    iridescence_ior: float = 1.3
    iridescence_thickness_range: tuple[float, float] = (100.0, 400.0)  # nanometres
    iridescence_thickness_texture: TextureRef | None = None  # G: minimum..maximum
    anisotropy_strength: float = 0.0
    anisotropy_rotation: float = 0.0            # radians, counter-clockwise from the tangent
    anisotropy_texture: TextureRef | None = None  # RG direction (-1..1), B strength
    dispersion: float = 0.0                     # KHR_materials_dispersion: 20 / Abbe number
    diffuse_transmission: float = 0.0           # KHR_materials_diffuse_transmission
    diffuse_transmission_texture: TextureRef | None = None  # A
    diffuse_transmission_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    diffuse_transmission_color_texture: TextureRef | None = None  # RGB, sRGB

    def uses(self, lobe: str) -> bool:
        """Whether the material needs `lobe`'s shader code ("ior", "specular", "clearcoat",
        "sheen", "iridescence", "anisotropy", "diffuse_transmission", "dispersion"): the
        defaults of an extension cost nothing."""
        if lobe == "ior":
            return self.ior != 1.5
        if lobe == "specular":
            return (self.specular != 1.0 or self.specular_color != (1.0, 1.0, 1.0)
                    or self.specular_texture is not None or self.specular_color_texture is not None)
        if lobe == "clearcoat":
            return self.clearcoat > 0.0
        if lobe == "sheen":
            return any(c > 0.0 for c in self.sheen_color)
        if lobe == "iridescence":
            return self.iridescence > 0.0
        if lobe == "anisotropy":
            return self.anisotropy_strength > 0.0
        if lobe == "diffuse_transmission":
            return self.diffuse_transmission > 0.0
        if lobe == "dispersion":
            return self.dispersion > 0.0
        raise ValueError(f"unknown lobe {lobe!r}")

    @property
    def is_light(self) -> bool:
        """Its emission lights other surfaces in the ray tracers (renderer.methods.trace_lights
        .emitters_of: an emissive luminance, and not unlit, whose colour is shown, not shone)."""
        e = self.emissive
        return not self.unlit and self.emissive_strength * (0.2126 * e[0] + 0.7152 * e[1] + 0.0722 * e[2]) > 0

    @property
    def material_class(self) -> MaterialClass:
        """Decides which passes run and what is baked: transmissive wins over alpha modes."""
        if self.transmission > 0.0 or self.transmission_texture is not None:
            return "transmissive"
        return cast(MaterialClass, {"MASK": "mask", "BLEND": "blend"}.get(self.alpha_mode, "opaque"))

    def absorption(self) -> np.ndarray:
        """Beer-Lambert coefficient per scene unit (KHR_materials_volume): light keeps
        attenuation_color after attenuation_distance, so sigma = -ln(color) / distance; zero
        when no distance is given."""
        d = self.attenuation_distance
        if not (math.isfinite(d) and d > 0):
            return np.zeros(3)
        return -np.log(np.clip(np.asarray(self.attenuation_color, np.float64), 1e-6, 1.0)) / d

    def channel_iors(self) -> tuple[float, float, float]:
        """IOR per RGB channel (KHR_materials_dispersion): the spread (ior - 1) x dispersion / 20
        between red and blue, centred on the given IOR (green)."""
        half = (self.ior - 1.0) * 0.025 * self.dispersion
        return (self.ior - half, self.ior, self.ior + half)

    def texture_refs(self) -> dict[str, TextureRef]:
        """The texture slots in use, by slot name."""
        return {k: v for k, v in vars(self).items() if k.endswith("_texture") and v is not None}


@dataclass
class Creases:
    """A subdivision cage's sharp edges and corners (USD creaseIndices / cornerIndices), by
    the positions of their cage vertices (a mesh's vertices are split for UVs, and subsets
    renumber them; the refinement welds by position). Sharpness as OpenSubdiv counts it:
    levels of refinement an edge stays sharp, 10 or more for ever (SHARPNESS_INFINITE)."""
    edges: np.ndarray            # K x 2 x 3 end positions
    edge_sharpness: np.ndarray   # K
    corners: np.ndarray          # C x 3 positions
    corner_sharpness: np.ndarray  # C


@dataclass
class Cage:
    """A Catmull-Clark or bilinear subdivision surface's control cage as USD authors it: its
    polygons over its points, whole (every face of the USD mesh, holes and every GeomSubset's
    faces included: they shape their neighbours), with the creases and the rules that
    refine it (pipeline/usd/subdivision.py). Several Meshes (one per subset) share one Cage;
    each says which corners it draws (`Mesh.cage_corners`)."""
    scheme: str                   # catmullClark / bilinear
    counts: np.ndarray            # F polygon sizes (>= 3)
    corners: np.ndarray           # sum(counts) point indices, counter-clockwise (right-handed)
    points: np.ndarray            # P x 3
    crease_edges: np.ndarray      # K x 2 point indices
    crease_sharpness: np.ndarray  # K, as OpenSubdiv counts it (10 or more: for ever)
    corner_points: np.ndarray     # C point indices
    corner_sharpness: np.ndarray  # C
    interpolate_boundary: str = "edgeAndCorner"    # none / edgeOnly / edgeAndCorner
    face_varying: str = "cornersPlus1"             # faceVaryingLinearInterpolation
    triangle_rule: str = "catmullClark"            # triangleSubdivisionRule: or smooth


@dataclass
class Mesh:
    """Triangle geometry of one primitive (one material). Arrays are float32 / uint32."""
    name: str
    positions: np.ndarray            # N x 3
    normals: np.ndarray              # N x 3, unit length
    indices: np.ndarray              # M x 3 uint32
    tangents: np.ndarray | None = None  # N x 4 (xyz, handedness w)
    uv0: np.ndarray | None = None    # N x 2, glTF convention (v down from the image top)
    uv1: np.ndarray | None = None
    colors: np.ndarray | None = None  # N x 4 linear
    subdivision: str | None = None  # a subdivision cage ("catmullClark", "loop"): refined at bake
    creases: Creases | None = None  # the cage's sharp edges and corners, used by that refinement
    cage: Cage | None = None  # catmullClark / bilinear: the polygon cage refined at bake
    cage_corners: np.ndarray | None = None  # per cage corner: this mesh's vertex, -1 off its faces
    # per refined attribute (uv0, uv1, colors): its primvar's interpolation (vertex, varying,
    # faceVarying, uniform, constant), which chooses how the refinement interpolates it
    cage_interpolation: dict[str, str] | None = None

    @property
    def triangle_count(self) -> int:
        return int(len(self.indices))


@dataclass
class Instance:
    """A placement of a mesh with a material: world = matrix @ object (column vectors)."""
    mesh: int      # index into Scene.meshes
    material: int  # index into Scene.materials
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4, dtype=np.float64))
    variants: dict[int, int] = field(default_factory=dict)  # variant index -> material (glTF)
    backdrop: bool = False  # a skybox/backdrop around the content: not framed (pipeline.framing)
    # glTF: (node, skinned, matrix in the node's frame) to place it again at another pose
    # (pipeline.gltf.rig): world = (identity if skinned else node's world) @ matrix
    placement: tuple | None = None


@dataclass
class SceneCamera:
    """A camera the asset defines (glTF), placed in world space; it looks down its local -Z
    with +Y up. Angles in radians; an aspect of None follows the output's."""
    name: str
    type: Literal["perspective", "orthographic"] = "perspective"
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4, dtype=np.float64))
    yfov: float = 0.8
    aspect: float | None = None
    znear: float = 0.01
    zfar: float = math.inf
    xmag: float = 1.0
    ymag: float = 1.0


@dataclass
class Light:
    """KHR_lights_punctual light, placed in world space."""
    type: Literal["directional", "point", "spot"]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0
    range: float = math.inf
    inner_cone: float = 0.0
    outer_cone: float = math.pi / 4
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4, dtype=np.float64))
    # UsdLux ShadowAPI: whether the light casts shadows (glTF lights always do), and the
    # colour that shadowed light is multiplied by instead of black
    shadow: bool = True
    shadow_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # A USD light's extent, which the ray tracer samples for soft shadows (the raster draws the
    # light as the point or direction above): "" none, "rect" (size: width, height along the
    # matrix's x and y), "disk" (radius, radius), "sphere" (radius, 0), "cylinder" (radius,
    # length along x), "cone" (a directional light's half-angle in radians, 0); metres
    shape: str = ""
    size: tuple[float, float] = (0.0, 0.0)


@dataclass
class Scene:
    source: str
    format: str
    meshes: list[Mesh] = field(default_factory=list)
    materials: list[Material] = field(default_factory=list)
    textures: list[Texture] = field(default_factory=list)
    instances: list[Instance] = field(default_factory=list)
    lights: list[Light] = field(default_factory=list)
    environment: str | None = None  # panorama file the asset lights itself with (USD dome light)
    # USD: the stage has its own lights (UsdLux), so it is lit by them alone, as Storm lights
    # it, not by the studio (pipeline.lighting); an untextured dome's uniform radiance (linear)
    own_lighting: bool = False
    dome_radiance: tuple[float, float, float] | None = None
    dome_scale: tuple[float, float, float] | None = None  # a textured dome's factor on its texture
    warnings: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)  # every file read (the asset and what it references)
    absent: list[str] = field(default_factory=list)  # files it looked for and did not find (cache key)
    cameras: list[SceneCamera] = field(default_factory=list)
    variants: list[str] = field(default_factory=list)  # KHR_materials_variants names, by index
    variant_sets: list[dict] = field(default_factory=list)  # USD: {prim, set, variants, selection}
    extensions: dict[str, str] = field(default_factory=dict)  # used -> supported|partial|ignored
    animations: list[dict] = field(default_factory=list)  # core.animation.Animation.summary()s
    time_range: dict | None = None  # USD: start/end time codes and timeCodesPerSecond
    skel_animations: list[dict] = field(default_factory=list)  # USD: each SkelAnimation's joints, shapes, samples
    moment: dict | None = None  # the animation and time the scene was posed at; None: at rest

    @property
    def triangle_count(self) -> int:
        """Triangles as rendered: every instance counts."""
        return sum(self.meshes[i.mesh].triangle_count for i in self.instances)

    @property
    def emissive_triangle_count(self) -> int:
        """Triangles as rendered whose material lights its surroundings (Material.is_light):
        the emitters the ray tracers sample."""
        return sum(self.meshes[i.mesh].triangle_count for i in self.instances
                   if 0 <= i.material < len(self.materials) and self.materials[i.material].is_light)

    @cached_property
    def bounds(self) -> np.ndarray:
        """World-space axis-aligned bounds, 2 x 3 (min row, max row), of what the camera
        frames: backdrop instances left out."""
        framed = [i for i in self.instances if not i.backdrop] or self.instances
        return placed_bounds((self.meshes[i.mesh].positions, i.matrix) for i in framed)


def extent(scene: "Scene") -> np.ndarray:
    """Bounds of everything drawn, backdrops included (Scene.bounds leaves those out)."""
    return placed_bounds((scene.meshes[i.mesh].positions, i.matrix) for i in scene.instances)


def placed_bounds(placed: Iterable[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Bounds, 2 x 3, of (positions, matrix) pairs, each placed exactly; zeros when empty."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for positions, matrix in placed:
        lo_i, hi_i = transformed_bounds(positions, matrix)
        lo, hi = np.minimum(lo, lo_i), np.maximum(hi, hi_i)
    return np.stack([lo, hi]) if np.all(np.isfinite(lo)) else np.zeros((2, 3))


def point_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) per coordinate of N x 3 points, exact: over a 3 x N copy, whose rows reduce
    contiguously (`points.min(axis=0)` is a strided reduction, tens of times slower)."""
    rows = np.ascontiguousarray(np.asarray(points).reshape(-1, 3).T)
    return rows.min(axis=1), rows.max(axis=1)


def transformed_bounds(positions: np.ndarray, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of `positions` after `matrix`, exact (transforms the points, not the box)."""
    if len(positions) == 0:
        return np.full(3, np.inf), np.full(3, -np.inf)
    # 3 x N: each coordinate's min and max run along a contiguous row (an N x 3 array's
    # reduction over axis 0 is strided, several times slower)
    m = np.asarray(matrix, np.float64)
    p = m[:3, :3] @ np.asarray(positions, np.float64).reshape(-1, 3).T + m[:3, 3:4]
    return p.min(axis=1), p.max(axis=1)


def default_material(name: str = "default") -> Material:
    """The material given to plain meshes (PLY, STL, OBJ) and unbound USD prims; a glTF primitive
    without one takes the spec's default, `Material()`."""
    return Material(name=name, base_color=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=0.5)
