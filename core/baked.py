"""What the bake produces and the renderer consumes: no source files needed to render."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.scene import Light, Material, Texture


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

    @property
    def triangle_count(self) -> int:
        return sum(len(m.indices) * len(m.transforms) for m in self.meshes)


@dataclass
class BakedEnvironment:
    key: str
    name: str
    specular: list[np.ndarray]       # mips, each 6 x S x S x 3 linear (faces +X,-X,+Y,-Y,+Z,-Z)
    irradiance_sh: np.ndarray        # 9 x 3, radiance SH (see environment.py for the basis)
    brdf_lut: np.ndarray             # N x N x 2; x = N.V, y = roughness -> (scale, bias) for F0
    prefilter: str = "ggx"           # "ggx" | "paper"
    manifest: dict = field(default_factory=dict)

    @property
    def face_size(self) -> int:
        return int(self.specular[0].shape[1])
