"""The environment's irradiance for the Fresnel tree's diffuse share, integrated from the
baked cube map itself (issue 26).

The raster's ambient term reads the bake's order-2 SH (shaders/sh.glsl). That truncation is
a bias, not noise: on a studio whose upper half is blue and lower half warm it reads a floor
1.2-1.5% dark and a board facing the horizon 0.9-1.3% bright against the exact integral of
the texels (the path integrator and Mitsuba agree with the integral within their confidence
intervals: bench/RESULTS.md, "Path integrator against the tree"). So the tree reads this
instead: E(n) / pi summed over the texels of the sharpest cube level (block-averaged to at most
SOURCE_FACE a side, weighted by solid angle), tabulated at the corners of a GRID x GRID net on
every face (edges and corners included, so that bilinear reads need no neighbouring face), once
per environment per process.
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np

from core.baked import BakedEnvironment
from core.cubemap import direction_to_face, face_points

SOURCE_FACE = 32   # the radiance's face size integrated (a block's cosine varies < 3 degrees)
GRID = 48          # intervals per face edge of the irradiance net
CACHE = 8          # environments kept (a net is 6 x 49 x 49 x 3 float64: 350 kB)
_cache: OrderedDict[tuple, np.ndarray] = OrderedDict()
_lock = threading.Lock()


def _texels(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def irradiance_net(faces: np.ndarray, compiled: bool = True) -> np.ndarray:
    """E(n) / pi of the radiance faces (6 x S x S x 3) at the net's corners: 6 x (GRID + 1) x
    (GRID + 1) x 3, net point (j, i) at face coordinates t = -1 + 2 j / GRID, s = -1 + 2 i / GRID.
    `compiled`: trace_kernel.cosine_sums (else its numpy twin)."""
    dirs, le = _texels(faces)
    n = face_points(np.linspace(-1.0, 1.0, GRID + 1))
    n = (n / np.linalg.norm(n, axis=-1, keepdims=True)).reshape(-1, 3)
    if compiled:
        from renderer.methods import trace_kernel  # numba loads only in a process that traces
        out = trace_kernel.cosine_sums(n, dirs, le)
    else:
        out = np.empty((len(n), 3))
        for lo in range(0, len(n), 1024):
            out[lo:lo + 1024] = np.maximum(n[lo:lo + 1024] @ dirs.T, 0.0) @ le
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
