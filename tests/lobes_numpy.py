"""Numpy twins of the GLSL lobes (shaders/brdf.glsl), written independently for the tests."""
from __future__ import annotations

import numpy as np

SHEEN_MIN_ROUGHNESS = 0.07


def d_charlie(r, nh):
    a = np.maximum(r, SHEEN_MIN_ROUGHNESS) ** 2
    return (2 + 1 / a) * np.maximum(1 - nh * nh, 0) ** (0.5 / a) / (2 * np.pi)


def _sheen_lambda(x, a):
    t = (1 - a) ** 2
    coef = [np.interp(t, [0, 1], p) for p in ((21.5473, 25.3245), (3.82987, 3.32435),
                                               (0.19823, 0.16801), (-1.97760, -1.27393),
                                               (-4.32054, -4.85967))]

    def ell(y):
        return coef[0] / (1 + coef[1] * y ** coef[2]) + coef[3] * y + coef[4]
    return np.where(x < 0.5, np.exp(ell(x)), np.exp(2 * ell(0.5) - ell(1 - x)))


def v_sheen(nv, nl, r):
    a = np.maximum(r, SHEEN_MIN_ROUGHNESS) ** 2
    v = 1 / ((1 + _sheen_lambda(nv, a) + _sheen_lambda(nl, a)) * np.maximum(4 * nv * nl, 1e-6))
    return np.clip(v, 0, 1e4)


def sheen_albedo(n: int = 32, theta: int = 256, phi: int = 128) -> np.ndarray:
    """E[roughness row j, N.V column i] of sheen colour 1: a finer midpoint rule over the
    whole hemisphere (phi over 2 pi, not folded) than the shader's; clamped to 1 as the
    shader's (see shaders/brdf_lut.frag)."""
    nv = (np.arange(n) + 0.5) / n
    cl = (np.arange(theta) + 0.5) / theta
    ph = 2 * np.pi * (np.arange(phi) + 0.5) / phi
    sl = np.sqrt(1 - cl ** 2)
    ls = np.stack(np.broadcast_arrays(sl[:, None] * np.cos(ph), sl[:, None] * np.sin(ph),
                                      cl[:, None]), -1).reshape(-1, 3)
    v = np.stack([np.sqrt(1 - nv ** 2), np.zeros(n), nv], -1)
    h = v[:, None, :] + ls[None]
    nh = h[..., 2] / np.linalg.norm(h, axis=-1)
    out = np.zeros((n, n), np.float32)
    for j, r in enumerate((np.arange(n) + 0.5) / n):
        f = d_charlie(r, nh) * v_sheen(nv[:, None], ls[None, :, 2], r) * ls[None, :, 2]
        out[j] = np.minimum(f.sum(1) * (2 * np.pi / (theta * phi)), 1.0)
    return out


_XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                           [-0.9692660, 1.8760108, 0.0415560],
                           [0.0556434, -0.2040259, 1.0572252]])


def _film_sensitivity(opd, shift):
    phase = 2 * np.pi * opd * 1e-9
    val = np.array([5.4856e-13, 4.4201e-13, 5.2481e-13])
    pos = np.array([1.6810e+06, 1.7953e+06, 2.2084e+06])
    var = np.array([4.3278e+09, 9.3046e+09, 6.6121e+09])
    p = phase[..., None]
    xyz = val * np.sqrt(2 * np.pi * var) * np.cos(pos * p + shift) * np.exp(-p * p * var)
    xyz[..., 0] += (9.7470e-14 * np.sqrt(2 * np.pi * 4.5282e+09) * np.cos(2.2399e+06 * phase + shift[..., 0])
                    * np.exp(-4.5282e+09 * phase * phase))
    return (xyz / 1.0685e-7) @ _XYZ_TO_REC709.T


def thin_film_fresnel(cos1, film_ior: float, thickness: float, base_f0) -> np.ndarray:
    """Belcour & Barla's two-order Airy reflectance, (..., 3), as shaders/iridescence.glsl."""
    cos1 = np.asarray(cos1, np.float64)
    n2 = film_ior if thickness >= 30 else 1 + (film_ior - 1) * np.interp(thickness, [0, 30], [0, 1])
    cos2 = np.sqrt(np.maximum(1 - (1 - cos1 ** 2) / n2 ** 2, 0))
    r12 = ((n2 - 1) / (n2 + 1)) ** 2
    R12 = (r12 + (1 - r12) * (1 - cos1) ** 5)[..., None]
    T121 = 1 - R12
    phi21 = np.pi - (np.pi if n2 < 1 else 0.0)
    s = np.sqrt(np.clip(np.asarray(base_f0, np.float64), 0, 0.9999))
    n3 = (1 + s) / (1 - s)
    r23 = ((n3 - n2) / (n3 + n2)) ** 2
    R23 = r23 + (1 - r23) * ((1 - cos2) ** 5)[..., None]
    phi = phi21 + np.where(n3 < n2, np.pi, 0.0) * np.ones_like(R23)
    opd = 2 * n2 * thickness * cos2
    R123 = np.clip(R12 * R23, 1e-5, 0.9999)
    Rs = T121 ** 2 * R23 / (1 - R123)
    out = R12 + Rs
    cm = Rs - T121
    for k in (1, 2):
        cm = cm * np.sqrt(R123)
        out = out + cm * 2 * _film_sensitivity(k * opd, k * phi)
    return np.clip(out, 0, 1)
