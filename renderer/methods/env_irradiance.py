"""The environment's irradiance for the Fresnel tree's diffuse share, integrated from the
baked cube map itself (issue 26).

The bake's order-2 SH truncates: on a studio whose upper half is blue and lower half warm it
reads a floor 1.2-1.5% dark and a board facing the horizon 0.9-1.3% bright against the exact
integral of the texels (the path integrator and Mitsuba agree with the integral within their
confidence intervals: bench/RESULTS.md, "Path integrator against the tree"). So the tree reads
the integral (core.irradiance, the definition the raster's baked irradiance cube shares):
E(n) / pi of the sharpest cube level, tabulated at the corners of a GRID x GRID net on every
face (edges and corners included, so that bilinear reads need no neighbouring face), once per
environment per process.
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np

from core import irradiance
from core.baked import BakedEnvironment
from core.cubemap import direction_to_face, face_points

GRID = 48          # intervals per face edge of the irradiance net
CACHE = 8          # environments kept (a net is 6 x 49 x 49 x 3 float64: 350 kB)
_cache: OrderedDict[tuple, np.ndarray] = OrderedDict()
_lock = threading.Lock()


def irradiance_net(faces: np.ndarray, compiled: bool = True) -> np.ndarray:
    """E(n) / pi of the radiance faces (6 x S x S x 3) at the net's corners: 6 x (GRID + 1) x
    (GRID + 1) x 3, net point (j, i) at face coordinates t = -1 + 2 j / GRID, s = -1 + 2 i / GRID.
    `compiled`: trace_kernel.cosine_sums (else its numpy twin)."""
    dirs, le = irradiance.texels(faces)
    n = face_points(np.linspace(-1.0, 1.0, GRID + 1))
    n = (n / np.linalg.norm(n, axis=-1, keepdims=True)).reshape(-1, 3)
    if compiled:
        from renderer.methods import trace_kernel  # numba loads only in a process that traces
        out = trace_kernel.cosine_sums(n, dirs, le)
    else:
        out = irradiance.cosine_sums(n, dirs, le)
    return (out / np.pi).reshape(6, GRID + 1, GRID + 1, 3)


def _identity(env: BakedEnvironment) -> tuple:
    """What a cached net is found by: the key and a digest of the sharpest level (every 5th
    texel) and the coarsest, so two environments under one key (tests make them) never share."""
    top = np.ascontiguousarray(env.specular[0][:, ::5, ::5])
    digest = hashlib.blake2b(top.tobytes(), digest_size=16)
    digest.update(np.ascontiguousarray(env.specular[-1]).tobytes())
    return env.key, env.specular[0].shape, digest.hexdigest()


def net_for(env: BakedEnvironment) -> np.ndarray:
    """irradiance_net of env's sharpest level, computed once per environment."""
    ident = _identity(env)
    with _lock:
        got = _cache.get(ident)
        if got is not None:
            _cache.move_to_end(ident)
            return got
    net = irradiance_net(env.specular[0])
    with _lock:
        _cache[ident] = net
        while len(_cache) > CACHE:
            _cache.popitem(last=False)
    return net


def read(net: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Bilinear read of the net at unit directions n (N x 3) -> N x 3 (E / pi)."""
    g = net.shape[1] - 1
    face, s, t = direction_to_face(np.asarray(n, np.float64))
    x = np.clip(s * g, 0.0, g)
    y = np.clip(t * g, 0.0, g)
    x0 = np.minimum(np.floor(x).astype(np.int64), g - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), g - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = net[face, y0, x0] * (1 - fx) + net[face, y0, x0 + 1] * fx
    bottom = net[face, y0 + 1, x0] * (1 - fx) + net[face, y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy
