"""What the bake produces and the renderer consumes: no source files needed to render."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import partial
from typing import Callable

import numpy as np

from core.area_lights import AreaLights
from core.errors import NotInAsset
from core.mips import capped_size, mip_chain
from core.scene import Light, Material, Sampler, SceneCamera, Texture


class BakedTexture:
    """A texture as baked: a mip chain (RGBA8 levels, level 0 first, see core.mips) per
    colour space the materials read it in (sRGB for colour slots, linear for data), capped at
    the size the cache was baked for. `load(srgb, top)` yields the levels from the first no
    larger than `top` texels (None: all) down to 1 x 1; it runs on first use of a space and
    again only when a larger render needs sharper levels (from the cache: read, checksummed,
    and only those levels decompressed)."""

    def __init__(self, name: str, sampler: Sampler, source: str, size: tuple[int, int],
                 spaces: tuple[bool, ...], load: Callable[[bool, int | None], list[np.ndarray]]):
        self.name, self.sampler, self.source = name, sampler, source
        self.size = (int(size[0]), int(size[1]))  # level 0 height, width
        self.spaces = tuple(spaces)
        self._load = load
        self._chains: dict[bool, list[np.ndarray]] = {}  # space -> levels loaded (a chain's tail)

    @classmethod
    def from_texture(cls, tex: Texture, spaces=(True, False), cap: int | None = None) -> "BakedTexture":
        """Mips of a decoded Texture, built on first use (hand-made assets, fresh bakes)."""
        h, w = tex.image.shape[:2]
        return cls(tex.name, tex.sampler, tex.source, capped_size(h, w, cap),
                   spaces, partial(_chain_of, tex, cap))

    def mips(self, srgb: bool, top: int | None = None) -> list[np.ndarray]:
        """Levels from the first no larger than `top` texels (None: level 0) down to 1 x 1, in
        the requested space, or in the baked one where only that exists."""
        space = srgb if srgb in self.spaces or not self.spaces else self.spaces[0]
        have = self._chains.get(space)
        if have is None or max(have[0].shape[:2]) < min(top or 1 << 30, max(self.size)):
            have = self._chains[space] = self._load(space, top)
        first = next((i for i, lv in enumerate(have) if top is None or max(lv.shape[:2]) <= top),
                     len(have) - 1)
        return have[first:]

    @property
    def image(self) -> np.ndarray:
        """Level 0 as baked, in the first space it is read in (under the cap: the decoded
        source image, as scene Textures have it)."""
        return self.mips(self.spaces[0] if self.spaces else True)[0]

    def nbytes(self) -> int:
        """The most its mip chains can hold: a whole chain (4/3 of level 0) per colour space
        it is read in, whatever a render has loaded yet."""
        h, w = self.size
        return h * w * 4 * 4 // 3 * max(1, len(self.spaces))

    def __repr__(self) -> str:
        return f"BakedTexture({self.name!r}, {self.size[1]}x{self.size[0]}, loaded {sorted(self._chains)})"


def _chain_of(tex: Texture, cap: int | None, srgb: bool, top: int | None = None) -> list[np.ndarray]:
    return mip_chain(tex.image, srgb, cap)


def quantise_visibility(ao: np.ndarray) -> np.ndarray:
    """Visibility in [0, 1] as stored in BakedMesh.ao: uint8 x 255 (a quarter of float32's bytes)."""
    return np.rint(np.clip(ao, 0.0, 1.0) * 255.0).astype(np.uint8)


def quantise_directions(d: np.ndarray) -> np.ndarray:
    """Unit vector components in [-1, 1] as stored in BakedMesh.bent: uint8, (x + 1) / 2 x 255
    (the raster reads them as normalised floats)."""
    return np.rint((np.clip(d, -1.0, 1.0) + 1.0) * 127.5).astype(np.uint8)


def dequantise_directions(d: np.ndarray) -> np.ndarray:
    """BakedMesh.bent as float32 components in [-1, 1]; a float array passes as it is."""
    d = np.asarray(d)
    if d.dtype == np.uint8:
        return d.astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
    return d.astype(np.float32)


def dequantise_visibility(ao: np.ndarray) -> np.ndarray:
    """BakedMesh.ao as float32 in [0, 1]; a float array (a hand-made mesh) passes as it is."""
    ao = np.asarray(ao)
    if ao.dtype == np.uint8:
        return ao.astype(np.float32) * np.float32(1.0 / 255.0)
    return ao.astype(np.float32)


@dataclass
class BakedMesh:
    """One (geometry, material) pair with every world placement of it."""
    name: str
    positions: np.ndarray            # N x 3 float32, object space
    normals: np.ndarray              # N x 3 float32
    indices: np.ndarray              # M x 3 uint32
    material: Material
    transforms: np.ndarray           # K x 4 x 4 float64 world matrices (one per instance)
    tangents: np.ndarray | None = None
    uv0: np.ndarray | None = None
    uv1: np.ndarray | None = None
    colors: np.ndarray | None = None
    interior: np.ndarray | None = None  # N x 3 float32 object-space vertex->exit vectors, or None
    ao: np.ndarray | None = None        # N x 2 uint8 ambient visibility x 255 (pipeline.occlusion)
    #                                    of the front and back sides, shared by the placements,
    #                                    or (K N) x 2 (one N x 2 row per placement, in transforms'
    #                                    order), or None: read visibility()
    bent: np.ndarray | None = None      # N x 6 uint8 bent normals (pipeline.occlusion: the mean
    #                                    unoccluded direction), front xyz then back xyz, object
    #                                    space, quantise_directions; or None
    # welded edges (core.adjacency.welded_edges), baked for assets within its MAX_TRIANGLES:
    edges: np.ndarray | None = None       # E x 2 uint32 vertex indices
    edge_faces: np.ndarray | None = None  # E x 2 int32 face indices (second -1: boundary)
    support: np.ndarray | None = None     # S x 3 float64 support points (core.hull), baked
    # where the bake batched meshes (pipeline.batching): per edge, the place its mesh had in the
    # unbatched order (a mesh left alone: one value for all), so the edges are drawn in that order
    edge_order: np.ndarray | None = None
    variants: dict[str, Material] = field(default_factory=dict)  # KHR_materials_variants

    @property
    def ao_per_placement(self) -> bool:
        """Whether `ao` holds one row of vertices per placement (else one shared row)."""
        k = len(self.transforms)
        return self.ao is not None and k > 1 and len(self.ao) == k * len(self.positions) > 0

    def visibility(self, placement: int = 0) -> np.ndarray | None:
        """The baked ambient visibility of placement `placement` as N x 2 float32 in [0, 1]
        (a shared row serves every placement), or None where there is none (or it does not
        match the vertices)."""
        if self.ao is None:
            return None
        n = len(self.positions)
        if self.ao_per_placement:
            return dequantise_visibility(self.ao[placement * n:(placement + 1) * n])
        if len(self.ao) != n:
            return None
        return dequantise_visibility(self.ao)

    @property
    def interior_length(self) -> np.ndarray | None:
        return None if self.interior is None else np.linalg.norm(self.interior, axis=1)

    def nbytes(self) -> int:
        """Bytes of its arrays (the materials' textures are the asset's)."""
        return _array_bytes(self.positions, self.normals, self.indices, self.transforms, self.tangents,
                            self.uv0, self.uv1, self.colors, self.interior, self.ao, self.bent, self.edges, self.edge_faces,
                            self.support)


@dataclass
class BakedAsset:
    key: str
    source: str
    format: str
    meshes: list[BakedMesh]
    textures: list[BakedTexture]     # plain Textures given here are wrapped (mips on first use)
    bounds: np.ndarray               # 2 x 3 world space
    lights: list[Light] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    manifest: dict = field(default_factory=dict)
    variants: list[str] = field(default_factory=list)     # material variant names (glTF)
    cameras: list[SceneCamera] = field(default_factory=list)  # the asset's own cameras
    extent: np.ndarray | None = None  # 2 x 3 bounds incl. backdrops, when wider than `bounds`
    # K x 3 world points whose convex hull holds every surface (core.hull), baked; 0 x 3: no
    # bound; None: computed on first render. A copy with other geometry must drop it.
    hull: np.ndarray | None = None
    # The key its GPU copy is kept under when not its own: the frames of one animation
    # (pipeline.gltf.rig) share one upload, whose moved buffers each frame rewrites.
    gpu_key: str | None = None
    # The emissive polygons the raster lights with (core.area_lights), baked; None: found on
    # first render. A copy with other geometry or materials must drop it.
    area_lights: AreaLights | None = None

    def __post_init__(self):
        self.textures = [t if isinstance(t, BakedTexture) else BakedTexture.from_texture(t)
                         for t in self.textures]

    def nbytes(self) -> int:
        """The most it may hold in memory: its meshes' arrays and each texture's whole mip
        chains (textures decompress on demand, so this is what it can grow to)."""
        return (sum(m.nbytes() for m in self.meshes) + sum(t.nbytes() for t in self.textures)
                + _array_bytes(self.bounds, self.extent, self.hull))

    @property
    def triangle_count(self) -> int:
        return sum(len(m.indices) * len(m.transforms) for m in self.meshes)

    @property
    def emissive_triangle_count(self) -> int:
        """Triangles as rendered whose material lights its surroundings (Material.is_light)."""
        return sum(len(m.indices) * len(m.transforms) for m in self.meshes if m.material.is_light)

    def with_variant(self, name: str | None) -> "BakedAsset":
        """This asset with material variant `name` bound (KHR_materials_variants), under its
        own key (GPU caches keep variants apart); None: itself. NotInAsset if unknown."""
        if name is None:
            return self
        if name not in self.variants:
            raise NotInAsset(self.source, f"no material variant {name!r}; it has "
                             f"{', '.join(map(repr, self.variants)) or 'none'}")
        meshes = [dataclasses.replace(m, material=m.variants.get(name, m.material))
                  for m in self.meshes]
        return dataclasses.replace(self, key=f"{self.key}#variant={name}", meshes=meshes, area_lights=None,
                                   gpu_key=None if self.gpu_key is None else
                                   f"{self.gpu_key}#variant={name}")


@dataclass
class BakedEnvironment:
    key: str
    name: str
    specular: list[np.ndarray]       # mips, each 6 x S x S x 3 linear (faces +X,-X,+Y,-Y,+Z,-Z)
    irradiance_sh: np.ndarray        # 9 x 3, radiance SH (see environment.py for the basis)
    brdf_lut: np.ndarray             # N x N x 3; x = N.V, y = roughness -> (scale, bias) for F0, sheen albedo
    irradiance: np.ndarray           # 6 x F x F x 3, E / pi at the texel centres (core.irradiance)
    prefilter: str = "ggx"           # "ggx" | "paper"
    manifest: dict = field(default_factory=dict)

    @property
    def face_size(self) -> int:
        return int(self.specular[0].shape[1])

    def nbytes(self) -> int:
        return _array_bytes(*self.specular, self.irradiance_sh, self.brdf_lut, self.irradiance)


def _array_bytes(*arrays: np.ndarray | None) -> int:
    return sum(a.nbytes for a in arrays if a is not None)
