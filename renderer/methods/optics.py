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


def dominant_direction(r: np.ndarray, n: np.ndarray, roughness) -> np.ndarray:
    """Where most of a GGX lobe's reflected light comes from, given its mirror direction r
    and normal n (unit, N x 3): toward n as the lobe widens (Lagarde & de Rousiers 2014,
    mix(n, r, s (sqrt(s) + alpha)), s = 1 - alpha, alpha = roughness^2; shaders/ibl.glsl
    specular_dir). The prefiltered mips were filtered about this axis."""
    alpha = np.asarray(roughness, np.float64) ** 2
    s = 1.0 - alpha
    f = (s * (np.sqrt(s) + alpha))[..., None]
    m = n + (r - n) * f
    return m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-15)


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


def specular_tint(fres, f_smooth, ior, specular, specular_color, entering) -> np.ndarray:
    """N x 3 reflectance of a dielectric under KHR_materials_specular from its N untinted one
    `fres` (`f_smooth`: the same before any rough-lobe albedo). glTF's Schlick curve
    F = s (f0' + (1 - f0')(1 - cos)^5), f0' = min(f0 x specular colour, 1) (as path_bsdf), keeps
    the exact Fresnel's shape: F' = s (f0' + (1 - f0') x) with x = (F - f0) / (1 - f0), so the
    default (s = 1, white) is untouched. On the way out of a volume (not `entering`) the
    interface is left untinted: TIR stays total."""
    fres = np.asarray(fres, np.float64)
    out = np.repeat(fres[:, None], 3, axis=1)
    spec = np.asarray(specular, np.float64)
    col = np.asarray(specular_color, np.float64)
    if spec.size == 0:
        return out
    tinted = entering & ((spec != 1.0) | np.any(col != 1.0, axis=1))
    if not np.any(tinted):
        return out
    sel = np.flatnonzero(tinted)
    f0 = (((ior[sel] - 1) / (ior[sel] + 1)) ** 2)[:, None]
    f0c = np.minimum(f0 * col[sel], 1.0)
    x = np.clip((f_smooth[sel, None] - f0) / np.maximum(1 - f0, 1e-12), 0.0, 1.0)
    smooth_c = spec[sel, None] * (f0c + (1 - f0c) * x)
    ratio = fres[sel, None] / np.maximum(f_smooth[sel, None], 1e-12)  # the rough lobe's share
    out[sel] = np.clip(smooth_c * ratio, 0.0, 1.0)
    return out


def schlick(cos_i, f0) -> np.ndarray:
    """Schlick's approximation F0 + (1 - F0)(1 - cos)^5 (the raster path's Fresnel).

    For a ray leaving the denser medium pass the cosine of the transmitted angle instead, or
    it misses total internal reflection.
    """
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    f0 = np.asarray(f0, dtype=np.float64)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


# Rough interfaces: GGX microfacets (Walter et al. 2007), alpha = roughness^2 as glTF and
# Mitsuba's roughdielectric, normals drawn from the distribution of visible normals (Heitz
# 2018), so that a sample's weight is the Smith masking of its outgoing direction alone.

def orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents t, b with (t, b, n) right-handed (Duff et al. 2017, branchless)."""
    sign = np.where(n[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    t = np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], -1)
    s = np.stack([b, sign + n[..., 1] ** 2 * a, -n[..., 1]], -1)
    return t, s


def ggx_smith_g1(cos_v, alpha) -> np.ndarray:
    """Smith masking of GGX for a direction at cosine `cos_v` to the macro normal (>= 0)."""
    c2 = np.clip(np.asarray(cos_v, np.float64) ** 2, 1e-12, 1.0)
    return 2.0 / (1.0 + np.sqrt(1.0 + np.asarray(alpha) ** 2 * (1.0 - c2) / c2))


def ggx_visible_normal(v: np.ndarray, n: np.ndarray, alpha, u1, u2) -> np.ndarray:
    """A microfacet normal seen from unit direction `v` (pointing away from the surface, on
    the side of `n`), drawn from GGX's visible-normal distribution with uniforms u1, u2."""
    alpha = np.asarray(alpha, np.float64)
    t, b = orthonormal_basis(n)
    vl = np.stack([_dot(v, t), _dot(v, b), np.maximum(_dot(v, n), 1e-7)], -1)
    vh = np.stack([alpha * vl[..., 0], alpha * vl[..., 1], vl[..., 2]], -1)
    vh /= np.linalg.norm(vh, axis=-1, keepdims=True)
    lensq = vh[..., 0] ** 2 + vh[..., 1] ** 2
    inv = 1.0 / np.sqrt(np.maximum(lensq, 1e-30))
    t1 = np.where((lensq > 0)[..., None],
                  np.stack([-vh[..., 1] * inv, vh[..., 0] * inv, np.zeros_like(lensq)], -1),
                  np.array([1.0, 0.0, 0.0]))
    t2 = np.cross(vh, t1)
    r, phi = np.sqrt(u1), 2.0 * np.pi * np.asarray(u2)
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + vh[..., 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    nh = (p1[..., None] * t1 + p2[..., None] * t2
          + np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))[..., None] * vh)
    ml = np.stack([alpha * nh[..., 0], alpha * nh[..., 1], np.maximum(nh[..., 2], 1e-7)], -1)
    ml /= np.linalg.norm(ml, axis=-1, keepdims=True)
    return ml[..., :1] * t + ml[..., 1:2] * b + ml[..., 2:] * n


def sample_rough_dielectric(d: np.ndarray, n: np.ndarray, alpha, eta, u1, u2):
    """One visible microfacet normal m per ray and what each child carries: (m, fresnel,
    reflected dir, its weight, refracted dir, its weight, tir).

    The weights are Walter et al.'s rough dielectric over the VNDF pdf: F(d.m) G1(o_r) for
    the reflection and (1 - F(d.m)) G1(o_t) for the refraction (before the eta^2 radiance
    factor), 0 where the child leaves on the wrong side of the macro surface (as Mitsuba's
    roughdielectric); a total internal reflection on m reflects all (F = 1)."""
    m = ggx_visible_normal(-d, n, alpha, u1, u2)
    cos_m = np.clip(-_dot(d, m), 0.0, 1.0)
    f = fresnel_dielectric(cos_m, eta)
    r = reflect(d, m)
    t, tir = refract(d, m, eta)
    cr, ct = _dot(r, n), _dot(t, n)
    w_r = np.where((cr > 0) & (_dot(r, m) > 0), f * ggx_smith_g1(cr, alpha), 0.0)
    w_t = np.where((ct < 0) & ~tir, (1.0 - f) * ggx_smith_g1(-ct, alpha), 0.0)
    return m, f, r, w_r, t, w_t, tir
