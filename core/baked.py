"""What the bake produces and the renderer consumes: no source files needed to render."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from core.scene import Light, Material, SceneCamera, Texture


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
    variants: dict[str, Material] = field(default_factory=dict)  # KHR_materials_variants

    @property
    def interior_length(self) -> np.ndarray | None:
        return None if self.interior is None else np.linalg.norm(self.interior, axis=1)


@dataclass
class BakedAsset:
    key: str
    source: str
    format: str
    meshes: list[BakedMesh]
    textures: list[Texture]
    bounds: np.ndarray               # 2 x 3 world space
    lights: list[Light] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    manifest: dict = field(default_factory=dict)
    variants: list[str] = field(default_factory=list)     # material variant names (glTF)
    cameras: list[SceneCamera] = field(default_factory=list)  # the asset's own cameras
    extent: np.ndarray | None = None  # 2 x 3 bounds incl. backdrops, when wider than `bounds`

    @property
    def triangle_count(self) -> int:
        return sum(len(m.indices) * len(m.transforms) for m in self.meshes)

    def with_variant(self, name: str | None) -> "BakedAsset":
        """This asset with material variant `name` bound (KHR_materials_variants), under its
        own key (GPU caches keep variants apart); None: itself. NotInAsset if unknown."""
        if name is None:
            return self
        if name not in self.variants:
            from .errors import NotInAsset
            raise NotInAsset(self.source, f"no material variant {name!r}; it has "
                             f"{', '.join(map(repr, self.variants)) or 'none'}")
        meshes = [dataclasses.replace(m, material=m.variants.get(name, m.material))
                  for m in self.meshes]
        return dataclasses.replace(self, key=f"{self.key}#variant={name}", meshes=meshes)


@dataclass
class BakedEnvironment:
    key: str
    name: str
    specular: list[np.ndarray]       # mips, each 6 x S x S x 3 linear (faces +X,-X,+Y,-Y,+Z,-Z)
    irradiance_sh: np.ndarray        # 9 x 3, radiance SH (see environment.py for the basis)
    brdf_lut: np.ndarray             # N x N x 3; x = N.V, y = roughness -> (scale, bias) for F0, sheen albedo
    prefilter: str = "ggx"           # "ggx" | "paper"
    manifest: dict = field(default_factory=dict)

    @property
    def face_size(self) -> int:
        return int(self.specular[0].shape[1])
