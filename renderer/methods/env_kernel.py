"""The tracer's environment reads, compiled (numba): raytrace._env (the prefiltered specular
mips, bilinear on a face and linear between the two mips about a roughness) for every
direction of a call in one pass, where the numpy twin groups the rows by level, copies them
and reads each group with trace_kernel.sample_cube. Same arithmetic, so the same radiance to
the bit (tests/test_raytrace.py).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numba.typed import List

# the faces' (s, t) axes and signs (core.cubemap.direction_to_face; trace_kernel's tables)
S_AXIS = np.array([2, 2, 0, 0, 0, 0], np.int64)
S_SIGN = np.array([-1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
T_AXIS = np.array([1, 1, 2, 2, 1, 1], np.int64)
T_SIGN = np.array([-1.0, -1.0, 1.0, -1.0, -1.0, -1.0])
CHUNKS = 64  # rows of a call in this many chunks over the cores


@njit(cache=True, inline="always")
def _cube_texel(faces, dx, dy, dz, s_axis, s_sign, t_axis, t_sign):
    """The bilinear read (r, g, b) of faces along (dx, dy, dz): sample_cube's arithmetic."""
    size = faces.shape[1]
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    major = 0
    if ay > ax and ay >= az:
        major = 1
    elif az > ax and az > ay:
        major = 2
    m = dx if major == 0 else (dy if major == 1 else dz)
    face = major * 2 + (1 if m < 0 else 0)
    ma = abs(m)
    sa, ta = s_axis[face], t_axis[face]
    ds = dx if sa == 0 else (dy if sa == 1 else dz)
    dt = dx if ta == 0 else (dy if ta == 1 else dz)
    s = (s_sign[face] * ds / ma + 1) / 2
    t = (t_sign[face] * dt / ma + 1) / 2
    x = min(max(s * size - 0.5, 0.0), size - 1.0)
    y = min(max(t * size - 0.5, 0.0), size - 1.0)
    x0, y0 = int(math.floor(x)), int(math.floor(y))
    x1, y1 = min(x0 + 1, size - 1), min(y0 + 1, size - 1)
    fx, fy = x - x0, y - y0
    return (_bilinear(faces, face, x0, y0, x1, y1, fx, fy, 0),
            _bilinear(faces, face, x0, y0, x1, y1, fx, fy, 1),
            _bilinear(faces, face, x0, y0, x1, y1, fx, fy, 2))


@njit(cache=True, inline="always")
def _bilinear(faces, face, x0, y0, x1, y1, fx, fy, c):
    top = faces[face, y0, x0, c] * (1 - fx) + faces[face, y0, x1, c] * fx
    bottom = faces[face, y1, x0, c] * (1 - fx) + faces[face, y1, x1, c] * fx
    return top * (1 - fy) + bottom * fy


@njit(cache=True, parallel=True)
def sample_env(levels, d, rough, s_axis, s_sign, t_axis, t_sign):
    """raytrace._env in one call: the prefiltered radiance along d (N x 3) for roughness `rough`
    (N), linear between the bilinear reads of mips floor(lod) and floor(lod) + 1, lod =
    rough x (levels - 1), mip m holding roughness m / (levels - 1), with the numpy grouping's
    arithmetic (a row exactly on a level reads that level alone: c x 1 + c' x 0 = c). Rows go
    in CHUNKS chunks over the cores, each reading the mips one at a time (a level is fetched from
    the list once a chunk: its reference count is shared by the threads, and the reads of
    one level stay in cache together)."""
    n, n_lv = len(d), len(levels)
    out = np.zeros((n, 3))
    lo = np.empty(n, np.int64)
    f = np.empty(n)
    nch = max(min(CHUNKS, n), 1)
    for ch in prange(nch):
        a, b = ch * n // nch, (ch + 1) * n // nch
        for i in range(a, b):
            lod = min(max(rough[i], 0.0), 1.0) * (n_lv - 1)
            if not lod >= 0.0:  # NaN roughness: the sharpest mip
                lod = 0.0
            lo[i] = int(math.floor(lod))
            f[i] = lod - lo[i]
        for level in range(n_lv):
            faces = levels[level]
            for i in range(a, b):
                if lo[i] == level:
                    r, g, bl = _cube_texel(faces, d[i, 0], d[i, 1], d[i, 2], s_axis, s_sign, t_axis, t_sign)
                    if f[i] > 0 and level + 1 < n_lv:  # the next level adds its share below
                        w = 1 - f[i]
                        r, g, bl = r * w, g * w, bl * w
                    out[i, 0], out[i, 1], out[i, 2] = r, g, bl
                elif lo[i] == level - 1 and f[i] > 0:
                    r, g, bl = _cube_texel(faces, d[i, 0], d[i, 1], d[i, 2], s_axis, s_sign, t_axis, t_sign)
                    out[i, 0] += r * f[i]
                    out[i, 1] += g * f[i]
                    out[i, 2] += bl * f[i]
    return out


def cube_levels(faces: list) -> List:
    """sample_env's mips: the 6 x S x S x 3 float32 levels as one numba list."""
    levels = List()
    for f in faces:
        levels.append(np.ascontiguousarray(f, np.float32))
    return levels


def warm() -> None:
    """Compile (or load from numba's cache) sample_env's signature (trace_kernel.warm calls it)."""
    e3 = np.zeros((0, 3))
    sample_env(cube_levels([np.zeros((6, 2, 2, 3), np.float32)]), e3, np.zeros(0), S_AXIS, S_SIGN,
               T_AXIS, T_SIGN)
