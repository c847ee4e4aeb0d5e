"""The split-sum's horizon: how much of a prefiltered lookup lies under the surface.

The image light reads one prefiltered mip along the lobe's dominant direction d
(shaders/ibl.glsl). The mip was filtered with the N = V = R kernel about d: GGX's
reflected directions l weighted by N.L = l.d (pipeline/environment/prefilter.py). Where d
leans toward the surface's plane (a rough face seen at a low angle) part of that kernel lies
below the plane and reads the ground through the surface, while the true lobe is cut there
(no light arrives from under the surface; the split-sum LUT already counts the energy lost).

`below_fraction(s, roughness)` is the share of the kernel's weight under a plane whose normal
n has n.d = s. The raster takes the prefiltered value P(d) = (1 - h) S + h G, with S the
kernel's mean above the plane and G below it, and solves it for S with G estimated by the
cosine-weighted mean of the lower hemisphere (the SH irradiance about -n):
S = (P - h G) / (1 - h). Under a uniform ground this is exact; at d = n with a narrow lobe
h = 0 and nothing changes. The table is integrated once here (a fixed Hammersley set, the
prefilter's own kernel) and handed to the shader as a constant array (HORIZON_TABLE).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from core.hammersley import ggx_reflections

ROWS = 17      # n.d = 0, 1/16, ..., 1
COLUMNS = 17   # roughness 0, 1/16, ..., 1
SAMPLES = 4096


def _kernel(roughness: float) -> tuple[np.ndarray, np.ndarray]:
    """The prefilter's kernel about +z: directions l and their weights (pdf-sampled GGX
    half vectors reflected about +z, weight N.L; directions under +z's plane dropped)."""
    light, _ = ggx_reflections(max(roughness * roughness, 1e-4), SAMPLES)
    keep = light[:, 2] > 0
    return light[keep], light[keep, 2]


def below_fraction(s, roughness) -> np.ndarray:
    """Share of the kernel about d (roughness) that lies under the plane of n, n.d = s,
    read bilinearly from `horizon_table` (s clamped to [0, 1])."""
    table = horizon_table()
    x = np.clip(np.asarray(s, np.float64), 0, 1) * (ROWS - 1)
    y = np.clip(np.asarray(roughness, np.float64), 0, 1) * (COLUMNS - 1)
    i = np.minimum(x.astype(int), ROWS - 2)
    j = np.minimum(y.astype(int), COLUMNS - 2)
    fx, fy = x - i, y - j
    return ((table[i, j] * (1 - fx) + table[i + 1, j] * fx) * (1 - fy)
            + (table[i, j + 1] * (1 - fx) + table[i + 1, j + 1] * fx) * fy)


@lru_cache(maxsize=1)
def horizon_table() -> np.ndarray:
    """ROWS x COLUMNS: the kernel's share under the plane, by n.d (rows) and roughness."""
    s = np.linspace(0, 1, ROWS)
    normals = np.stack([np.sqrt(np.maximum(1 - s * s, 0.0)), np.zeros(ROWS), s])  # 3 x ROWS: n.d = s
    out = np.zeros((ROWS, COLUMNS))
    for j, r in enumerate(np.linspace(0, 1, COLUMNS)):
        light, weight = _kernel(r)
        # every plane at once (one product, not ROWS); the masked sums as before, row by row
        below = light @ normals < 0
        out[:, j] = [weight[below[:, i]].sum() for i in range(ROWS)]
        out[:, j] /= weight.sum()
    return out


@lru_cache(maxsize=1)
def glsl_table() -> str:
    """The table as a GLSL float array, row-major (n.d, then roughness)."""
    values = ", ".join(f"{v:.5f}" for v in horizon_table().ravel())
    return f"float[{ROWS * COLUMNS}]({values})"
