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
    l = np.stack(np.broadcast_arrays(sl[:, None] * np.cos(ph), sl[:, None] * np.sin(ph),
                                     cl[:, None]), -1).reshape(-1, 3)
    v = np.stack([np.sqrt(1 - nv ** 2), np.zeros(n), nv], -1)
    h = v[:, None, :] + l[None]
    nh = h[..., 2] / np.linalg.norm(h, axis=-1)
    out = np.zeros((n, n), np.float32)
    for j, r in enumerate((np.arange(n) + 0.5) / n):
        f = d_charlie(r, nh) * v_sheen(nv[:, None], l[None, :, 2], r) * l[None, :, 2]
        out[j] = np.minimum(f.sum(1) * (2 * np.pi / (theta * phi)), 1.0)
    return out
