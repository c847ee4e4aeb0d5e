"""Hydra Storm's (usdview's) shading of a single-sided gprim's back faces, which the raster and
the tracers follow for USD (`Material.show_back_faces`).

usdview culls no back faces by default, and Storm lights a gprim with doubleSided = 0 seen
from behind with its normal as authored, pointing away from the viewer, so that N.E clamps
to 0 (usdShaders' previewSurface.glslfx: NdotE = max(0, dot(n, e))). What follows there:
- its dome light: the specular is (F0 A + B) x the prefiltered light along reflect(-e, n),
  (A, B) Storm's split-sum table at N.E = 0 (`back_face_albedo`); the diffuse is the base
  colour x (1 - F0) x the irradiance about n (the dome's Fresnel is taken at E.H = 1);
- a direct light: no specular (its geometric term has N.E as a factor), the diffuse
  N.L about n x (1 - F(E.H)).
Storm's table is not ours: hdSt's domeLight.glslfx integrates the GGX lobe with 1024
Hammersley samples and Schlick-Smith visibility (k = alpha / 2), N.E clamped to 0.001, where
ours uses height-correlated Smith; at N.E -> 0 the two differ most (roughness 0.3: Storm
0.51, 0.32; ours 0.55, 0.40). Its row at N.E = 0.001 is integrated here the same way, once,
at TABLE_SIZE roughnesses, and read linearly between them.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from core.hammersley import radical_inverse

TABLE_SIZE = 33  # roughness 0, 1/32, ..., 1
SAMPLES = 1024  # Storm's NUM_SAMPLES
NOV = 0.001  # Storm's clamp of N.E in its table


@lru_cache(maxsize=1)
def _hammersley() -> tuple[np.ndarray, np.ndarray]:
    """Storm's SAMPLES points (i / N, radical inverse of i): made once, not per roughness."""
    i = np.arange(SAMPLES)
    return i / SAMPLES, radical_inverse(i)


def _integrate(roughness: float) -> tuple[float, float]:
    """(A, B) of the split sum at N.E = NOV: E[(1 - Fc) G_vis], E[Fc G_vis] over GGX samples."""
    u1, u2 = _hammersley()
    alpha = roughness * roughness
    phi = 2 * np.pi * u1
    cos_t = np.minimum(1.0, np.sqrt((1 - u2) / (1 + (alpha * alpha - 1) * u2)))
    sin_t = np.sqrt(1 - cos_t * cos_t)
    h = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
    v = np.array([np.sqrt(1 - NOV * NOV), 0.0, NOV])
    vh = h @ v
    nl = 2 * vh * h[:, 2] - v[2]  # (2 (v.h) h - v).n
    ok = nl > 0
    k = alpha / 2
    g = nl / (nl * (1 - k) + k) * NOV / (NOV * (1 - k) + k)
    g_vis = np.where(ok, g * np.maximum(vh, 0) / np.maximum(h[:, 2] * NOV, 1e-30), 0.0)
    fc = (1 - np.maximum(vh, 0)) ** 5
    return float(((1 - fc) * g_vis).sum() / SAMPLES), float((fc * g_vis).sum() / SAMPLES)


@lru_cache(maxsize=1)
def back_face_table() -> np.ndarray:
    """TABLE_SIZE x 2: Storm's (A, B) at N.E = 0 for roughness 0 .. 1."""
    return np.array([_integrate(r) for r in np.linspace(0.0, 1.0, TABLE_SIZE)])


def back_face_albedo(roughness) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) at each roughness, read linearly from `back_face_table`."""
    table = back_face_table()
    x = np.linspace(0.0, 1.0, TABLE_SIZE)
    r = np.clip(np.asarray(roughness, np.float64), 0.0, 1.0)
    return np.interp(r, x, table[:, 0]), np.interp(r, x, table[:, 1])


@lru_cache(maxsize=1)
def glsl_table() -> str:
    """The table as a GLSL array constructor (the raster's STORM_BACK_TABLE define)."""
    rows = ", ".join(f"vec2({a:.6f}, {b:.6f})" for a, b in back_face_table())
    return f"vec2[{TABLE_SIZE}]({rows})"
