"""Emissive surfaces as polygon area lights for the raster (shaders/area_lights.glsl).

The ray tracers sample every emissive triangle (renderer.methods.trace_lights); the raster
cannot, so the bake keeps a few polygons: per emissive mesh placement its triangles, each
pair that shares an edge, lies in one plane and makes a convex quad merged into that quad
(a cube's face, a panel), the brightest `MAX_LIGHTS` by power (luminance x area) kept.

Decisions:
- Radiance: emissive factor x strength x the mean of the emissive texture (linear), one
  colour per polygon: a texture's pattern is not followed across the polygon.
- A material is a light where Material.is_light says so (not unlit) and the luminance of its
  radiance exceeds `MIN_LUMINANCE`: dim glows light little and each light costs every pixel.
- Each polygon remembers its mesh (`mesh`): an emitter does not light itself (the shader
  skips the lights of the mesh it draws), which also keeps a cube's faces off each other.
- USD stages have none: their reference, Hydra Storm, lights nothing from emissive surfaces
  (as they bake no ambient occlusion, which Storm does not draw either).
- Emitters past the cap are dropped, not merged: a finely tessellated glowing sphere is lit
  from its brightest faces only (what is dropped is counted in `dropped`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.colour import srgb_to_linear

MAX_LIGHTS = 16        # polygons a bake keeps: each costs every shaded pixel (bench/RESULTS.md,
# "Emitters as the raster's area lights": 16 of EmissiveStrengthTest's 30 score as all 30)
MIN_LUMINANCE = 0.05   # linear radiance luminance below which an emitter lights nothing
NONE_FOR = ("usd", "usda", "usdc", "usdz")  # source formats whose raster has no area lights
_LUMA = np.array([0.2126, 0.7152, 0.0722])
_COPLANAR = 1e-4       # 1 - cos of the angle between two triangles' normals merged into a quad
_TEXTURE_LEVEL = 64    # texels across the mip level an emissive texture's mean is read from


@dataclass
class AreaLights:
    """K polygon lights in world space."""
    corners: np.ndarray    # K x 4 x 3 float64, counter-clockwise seen from the front (a
    # triangle repeats its last corner: a zero edge adds nothing to the edge integrals)
    normal: np.ndarray     # K x 3 unit normal of the emitting (front) side
    radiance: np.ndarray   # K x 3 linear emitted radiance
    two_sided: np.ndarray  # K bool: emits from its back too (double-sided material)
    mesh: np.ndarray       # K int: index of the BakedMesh it came from
    dropped: int = 0       # polygons past MAX_LIGHTS

    def __len__(self) -> int:
        return len(self.corners)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"corners": self.corners, "normal": self.normal, "radiance": self.radiance,
                "two_sided": self.two_sided, "mesh": self.mesh, "dropped": np.array(self.dropped)}

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray]) -> "AreaLights":
        return cls(np.asarray(a["corners"], np.float64), np.asarray(a["normal"], np.float64),
                   np.asarray(a["radiance"], np.float64), np.asarray(a["two_sided"], bool),
                   np.asarray(a["mesh"], np.int64), int(a["dropped"]))


def empty() -> AreaLights:
    return AreaLights(np.zeros((0, 4, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                      np.zeros(0, bool), np.zeros(0, np.int64))


def texture_mean(texture) -> np.ndarray:
    """Linear RGB mean of a core.baked.BakedTexture read as colour (sRGB), from a small level."""
    level = texture.mips(True, _TEXTURE_LEVEL)[0]
    return srgb_to_linear(np.asarray(level)[..., :3]).reshape(-1, 3).mean(axis=0)


def radiance_of(material, textures) -> np.ndarray:
    """The linear radiance a material's emitter lights with (zero: not a light)."""
    if not material.is_light:
        return np.zeros(3)
    r = np.asarray(material.emissive, np.float64) * material.emissive_strength
    ref = material.emissive_texture
    if ref is not None and 0 <= ref.texture < len(textures):
        r = r * texture_mean(textures[ref.texture])
    return r if float(r @ _LUMA) > MIN_LUMINANCE else np.zeros(3)


def _quads(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T x 3 x 3 world triangles -> (P x 4 x 3 polygons, P areas): coplanar convex pairs that
    share an edge merged, greedily in index order; the rest as triangles."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    cross = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    ok = area > 0
    tri, cross, area = tri[ok], cross[ok], area[ok]
    normal = cross / (2 * area[:, None])
    scale = max(float(np.abs(tri).max(initial=0.0)), 1e-30)
    key = np.round(tri / (scale * 1e-6)).astype(np.int64)  # corners welded within 1e-6 of the size
    edges: dict[tuple, tuple[int, int]] = {}
    used = np.zeros(len(tri), bool)
    polys, areas = [], []
    for t in range(len(tri)):
        for k in range(3):
            a, b = tuple(key[t, k]), tuple(key[t, (k + 1) % 3])
            other = edges.get((b, a))  # the neighbour walks the shared edge the other way
            if other is None or used[other[0]] or used[t]:
                continue
            u, j = other
            if float(normal[t] @ normal[u]) < 1 - _COPLANAR:
                continue
            # quad: t's corners from the shared edge's end round to its start, then u's far corner
            quad = np.array([tri[t, (k + 1) % 3], tri[t, (k + 2) % 3], tri[t, k], tri[u, (j + 2) % 3]])
            if _convex(quad, normal[t]):
                used[t] = used[u] = True
                polys.append(quad)
                areas.append(area[t] + area[u])
        if not used[t]:
            for k in range(3):
                edges[(tuple(key[t, k]), tuple(key[t, (k + 1) % 3]))] = (t, k)
    for t in map(int, np.flatnonzero(~used)):
        polys.append(np.array([tri[t, 0], tri[t, 1], tri[t, 2], tri[t, 2]]))
        areas.append(area[t])
    return np.array(polys).reshape(-1, 4, 3), np.array(areas)


def _convex(quad: np.ndarray, normal: np.ndarray) -> bool:
    turn = np.cross(quad - np.roll(quad, 1, axis=0), np.roll(quad, -1, axis=0) - quad) @ normal
    return bool(np.all(turn > 0))


def of_format(source_format: str, meshes, textures, limit: int = MAX_LIGHTS) -> AreaLights:
    """`extract`, or none for a format in NONE_FOR."""
    return empty() if source_format.lower() in NONE_FOR else extract(meshes, textures, limit)


def extract(meshes, textures, limit: int = MAX_LIGHTS) -> AreaLights:
    """The polygon lights of a list of core.baked.BakedMesh (see the module's decisions)."""
    corners, normals, radiance, two, owner, power = [], [], [], [], [], []
    for i, m in enumerate(meshes):
        r = radiance_of(m.material, textures)
        if not r.any() or not len(m.indices):
            continue
        pos = np.asarray(m.positions, np.float64)
        idx = np.asarray(m.indices, np.int64)
        for x in np.asarray(m.transforms, np.float64).reshape(-1, 4, 4):
            world = pos @ x[:3, :3].T + x[:3, 3]
            tri = world[idx]
            if np.linalg.det(x[:3, :3]) < 0:  # a mirroring placement reverses the winding
                tri = tri[:, ::-1]
            polys, areas = _quads(tri)
            if not len(polys):
                continue
            n = np.cross(polys[:, 1] - polys[:, 0], polys[:, 2] - polys[:, 0])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            corners.append(polys)
            normals.append(n)
            radiance.append(np.tile(r, (len(polys), 1)))
            two.append(np.full(len(polys), bool(m.material.double_sided)))
            owner.append(np.full(len(polys), i))
            power.append(areas * float(r @ _LUMA) * (2.0 if m.material.double_sided else 1.0))
    if not corners:
        return empty()
    p = np.concatenate(power)
    keep = np.sort(np.argsort(-p, kind="stable")[:limit])
    return AreaLights(np.concatenate(corners)[keep], np.concatenate(normals)[keep],
                      np.concatenate(radiance)[keep], np.concatenate(two)[keep],
                      np.concatenate(owner)[keep].astype(np.int64), int(len(p) - len(keep)))
