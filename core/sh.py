"""Real spherical harmonics l <= 2: the basis the environment bake projects onto
(pipeline.environment.prefilter). Neither renderer lights with it any more (the raster reads
the bake's irradiance cube, the tree its net: core.irradiance); bench/irradiance_cube.py
measures its truncation against them.

Standard order, in world coordinates (x, y, z): Y00; Y1-1 = c1 y, Y10 = c1 z, Y11 = c1 x;
Y2-2 = c2 xy, Y2-1 = c2 yz, Y20 = c3 (3z^2 - 1), Y21 = c2 xz, Y22 = c4 (x^2 - y^2)."""
from __future__ import annotations

import math

import numpy as np

SH_C0 = 0.5 / math.sqrt(math.pi)
SH_C1 = math.sqrt(3 / (4 * math.pi))
SH_C2 = 0.5 * math.sqrt(15 / math.pi)
SH_C3 = 0.25 * math.sqrt(5 / math.pi)
SH_C4 = 0.25 * math.sqrt(15 / math.pi)


def sh_basis(d: np.ndarray) -> np.ndarray:
    """The 9 basis functions at unit directions (..., 3) -> (..., 9)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([np.full_like(x, SH_C0), SH_C1 * y, SH_C1 * z, SH_C1 * x,
                     SH_C2 * x * y, SH_C2 * y * z, SH_C3 * (3 * z * z - 1),
                     SH_C2 * x * z, SH_C4 * (x * x - y * y)], axis=-1)


def sh_irradiance(sh: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance / pi at unit normals (..., 3) -> (..., 3): the radiance a white Lambertian
    surface reflects (Ramamoorthi & Hanrahan 2001: A0 = pi, A1 = 2pi/3, A2 = pi/4)."""
    band = np.array([1.0] + [2 / 3] * 3 + [1 / 4] * 5)
    return (sh_basis(np.asarray(normals, dtype=np.float64)) * band) @ np.asarray(sh, np.float64)
