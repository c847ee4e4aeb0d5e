"""The exact cosine integral of a cube map's texels: the image light's irradiance, one
definition for the bake's irradiance cube (pipeline.environment.prefilter, which the raster's
diffuse samples) and the Fresnel tree's net (renderer.methods.env_irradiance).

E(n) / pi = sum over texels of L x solid angle x max(n . d, 0) / pi: the radiance a white
Lambertian surface facing n reflects. Order-2 spherical harmonics truncate it by 1-3% a channel
on coloured skies (bench/RESULTS.md, issue 30); this is the integral itself. The radiance is
block-averaged to at most SOURCE_FACE texels a side first (a block's cosine varies by less than
3 degrees), each block weighted by its texels' solid angle, so the sum is still the integral
of the texels.
"""
from __future__ import annotations

import numpy as np

from core.cubemap import face_directions, face_points

SOURCE_FACE = 32      # the radiance's face size integrated
IRRADIANCE_FACE = 24  # the bake's irradiance cube: its seamless bilinear reads are within
                      # 0.03-0.1% of the integral on average on every shipped environment (16:
                      # 0.05-0.2%, 32: 0.01-0.05% for 1.8x the bake's time; bench/RESULTS.md, issue 30)
_CHUNK = 1024         # normals a matrix product takes at once (memory: CHUNK x texels)


def texels(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit directions M x 3, radiance x solid angle M x 3) of faces (6 x S x S x 3) averaged
    into blocks of at most SOURCE_FACE a side: each block's radiance is the solid-angle-weighted
    mean of its texels, so the sum over blocks is the integral of the texels."""
    s = faces.shape[1]
    c = (np.arange(s) + 0.5) / s * 2 - 1
    tc, sc = np.meshgrid(c, c, indexing="ij")
    dom = (2.0 / s) ** 2 / (1 + sc * sc + tc * tc) ** 1.5   # texel solid angle
    weighted = np.asarray(faces[..., :3], np.float64) * dom[None, ..., None]
    b = max(s // SOURCE_FACE, 1) if s % SOURCE_FACE == 0 else 1
    k = s // b
    le = weighted.reshape(6, k, b, k, b, 3).sum(axis=(2, 4))
    d_sum = np.broadcast_to(dom, (6, s, s)).reshape(6, k, b, k, b).sum(axis=(2, 4))
    cb = (np.arange(k) + 0.5) / k * 2 - 1
    d = face_points(cb)
    # the block's direction: its texels' solid-angle-weighted mean (its centre for b = 1)
    if b > 1:
        pts = face_points(c)
        pts /= np.linalg.norm(pts, axis=-1, keepdims=True)
        d = (pts * dom[None, ..., None]).reshape(6, k, b, k, b, 3).sum(axis=(2, 4)) / d_sum[..., None]
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return d.reshape(-1, 3), le.reshape(-1, 3)


def cosine_sums(normals: np.ndarray, dirs: np.ndarray, le: np.ndarray, dtype=np.float64) -> np.ndarray:
    """sum_k max(n . d_k, 0) le_k for every unit normal (N x 3) -> N x 3 float64 (E, not
    E / pi). `dtype` of the products: float32 halves the bake's time for a relative 1e-6."""
    out = np.empty((len(normals), 3))
    d, w = dirs.astype(dtype), le.astype(dtype)
    for lo in range(0, len(normals), _CHUNK):
        out[lo:lo + _CHUNK] = np.maximum(normals[lo:lo + _CHUNK].astype(dtype) @ d.T, 0.0) @ w
    return out


def irradiance(faces: np.ndarray, normals: np.ndarray, dtype=np.float64) -> np.ndarray:
    """E(n) / pi of the radiance faces (6 x S x S x 3) at unit normals (..., 3) -> (..., 3)."""
    n = np.asarray(normals, np.float64)
    return (cosine_sums(n.reshape(-1, 3), *texels(faces), dtype=dtype) / np.pi).reshape(n.shape)


def irradiance_cube(faces: np.ndarray, size: int = IRRADIANCE_FACE) -> np.ndarray:
    """E / pi at the texel centres of a size x size cube (6 x size x size x 3 float32, the
    faces' order and orientation): what the raster's diffuse reads with seamless bilinear
    filtering."""
    return irradiance(faces, face_directions(size), np.float32).astype(np.float32)
