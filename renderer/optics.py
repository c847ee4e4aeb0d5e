"""Geometric optics at a smooth interface: reflection, Snell refraction, Fresnel reflectance.

Vectorised numpy over any leading shape (..., 3). Shared by the ray tracer and the tests; the
GLSL twins in shaders/refraction.glsl follow the same conventions:

- `d` is the unit direction of travel toward the surface, `n` the unit normal on the side the
  ray comes from (dot(d, n) <= 0).
- `eta` is n_incident / n_transmitted (as GLSL `refract` takes it): 1/1.5 entering glass from
  air, 1.5 leaving it.
"""
from __future__ import annotations

import numpy as np


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def reflect(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Mirror direction of `d` about `n`."""
    return d - 2.0 * _dot(d, n)[..., None] * n


def refract(d: np.ndarray, n: np.ndarray, eta) -> tuple[np.ndarray, np.ndarray]:
    """Snell's law in vector form (the paper's section 3.2 with ratio = eta).

    Returns (direction, tir): the unit transmitted direction, and a boolean mask of total
    internal reflection where no transmitted ray exists; there the mirror direction is
    returned instead, so the result is always a finite unit vector.
    """
    eta = np.asarray(eta, dtype=np.float64)
    cos_i = np.clip(-_dot(d, n), 0.0, 1.0)
    k = (1.0 - eta * eta) + eta * eta * cos_i * cos_i  # cos^2 of the transmitted angle
    tir = k < 0.0
    t = eta[..., None] * d + (eta * cos_i - np.sqrt(np.maximum(k, 0.0)))[..., None] * n
    t = np.where(tir[..., None], reflect(d, n), t)
    return t / np.linalg.norm(t, axis=-1, keepdims=True), tir


def fresnel_sp(cos_i, eta) -> tuple[np.ndarray, np.ndarray]:
    """Exact reflectance of s- and p-polarised light at a dielectric interface.

    cos_i: cosine of the incidence angle (>= 0); eta = n_incident / n_transmitted.
    Beyond the critical angle both are 1 (total internal reflection).
    """
    cos_i = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    eta = np.asarray(eta, dtype=np.float64)
    # cos^2 of the transmitted angle, arranged so that eta = 1 gives cos_i exactly at grazing.
    cos2_t = (1.0 - eta * eta) + eta * eta * cos_i * cos_i
    tir = cos2_t <= 0.0
    cos_t = np.sqrt(np.maximum(cos2_t, 0.0))
    # Amplitude ratios written with eta = n1/n2 so that IOR 1.0 gives exactly 0.
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
        rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rs2 = np.where(tir, 1.0, np.nan_to_num(rs * rs, nan=1.0))
    rp2 = np.where(tir, 1.0, np.nan_to_num(rp * rp, nan=1.0))
    return rs2, rp2


def fresnel_dielectric(cos_i, eta) -> np.ndarray:
    """Exact unpolarised Fresnel reflectance (mean of s and p); transmittance is 1 - R."""
    rs2, rp2 = fresnel_sp(cos_i, eta)
    return 0.5 * (rs2 + rp2)


def f0_from_ior(n1, n2=1.0) -> np.ndarray:
    """Reflectance at normal incidence, ((n1 - n2) / (n1 + n2))^2."""
    n1, n2 = np.asarray(n1, np.float64), np.asarray(n2, np.float64)
    return ((n1 - n2) / (n1 + n2)) ** 2


def schlick(cos_i, f0) -> np.ndarray:
    """Schlick's approximation F0 + (1 - F0)(1 - cos)^5 (the raster path's Fresnel).

    For a ray leaving the denser medium pass the cosine of the transmitted angle instead, or
    it misses total internal reflection.
    """
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    f0 = np.asarray(f0, dtype=np.float64)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5
