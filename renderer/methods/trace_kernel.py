"""The ray tracer's per-surface work, compiled (numba): what renderer.methods.raytrace's numpy twin
`_shade_numpy` does to the rays of one bounce that hit something, in one loop.

Per hit (the material as renderer.methods.trace_material evaluated it, textures included:
per-hit shading normal, base colour, metallic, roughness, transmission, emission,
occlusion; IOR and absorption per material): the shading normal turned to face the ray,
Beer-Lambert over the segment just travelled, emission, exact Fresnel (rough glass: on a GGX visible normal drawn from the
pixel's scrambled Sobol set), the metallic and rough-lobe albedos from the split-sum LUT,
the diffuse share, and the reflected and refracted children that carry more than
MIN_WEIGHT (with fresnel_split="sample" past the first surface, one of them). Same
arithmetic as the numpy twin (tests/test_raytrace.py compares the two frames), without the
numpy twin's some 80 array passes a bounce and their temporaries. The rows run in CHUNKS fixed
chunks over numba's threads, each writing its outputs from its own first row, then packed in
row order: the children, misses and shares come out as one serial pass gives them, whatever
the thread count (a pixel's sum of rays is the same to the bit).
"""
from __future__ import annotations

import math
import time

import numpy as np
from numba import njit, prange

from renderer.methods.path_kernel import glass_albedo

_SOBOL_DIM1 = np.zeros(32, np.uint64)
_SOBOL_DIM1[0] = 0x80000000
for _i in range(1, 32):
    _SOBOL_DIM1[_i] = _SOBOL_DIM1[_i - 1] ^ (_SOBOL_DIM1[_i - 1] >> np.uint64(1))
_M32 = 0xFFFFFFFF


@njit(cache=True, inline="always")
def _pixel_shift(pix, depth):
    h = (np.uint64(pix) * np.uint64(0x9E3779B97F4A7C15)
         + np.uint64(depth + 1) * np.uint64(0xBF58476D1CE4E5B9))
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return float(h >> np.uint64(11)) / 9007199254740992.0


@njit(cache=True, inline="always")
def _rev(x):
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return ((x >> 16) | (x << 16)) & _M32


@njit(cache=True, inline="always")
def _owen(x, seed):
    x = (_rev(x) + seed) & _M32
    x ^= (x * 0x6C50B47C) & _M32
    x ^= (x * 0xB82F1E52) & _M32
    x ^= (x * 0xC7AFE638) & _M32
    x ^= (x * 0x8D22F6E6) & _M32
    return _rev(x)


@njit(cache=True, inline="always")
def _pixel_samples(pix, sub, depth, sobol):
    seed = np.int64(_pixel_shift(pix, 1000 + depth) * 4294967296.0) & _M32
    index = _owen(np.int64(sub) & _M32, seed)
    x = _rev(index)
    y = np.int64(0)
    for bit in range(32):  # branch-free: the shuffled index's bits are random
        y ^= np.int64(sobol[bit]) & -((index >> bit) & 1)
    x = _owen(x, (seed * 0x9E3779B9 + 1) & _M32)
    y = _owen(y, (seed * 0x85EBCA6B + 2) & _M32)
    return (x + 0.5) / 4294967296.0, (y + 0.5) / 4294967296.0


@njit(cache=True, inline="always")
def _fresnel(cos_i, eta):
    c = min(max(cos_i, 0.0), 1.0)
    cos2_t = (1.0 - eta * eta) + eta * eta * c * c
    if cos2_t <= 0.0:
        return 1.0
    cos_t = math.sqrt(cos2_t)
    a, b = eta * c + cos_t, c + eta * cos_t
    rs2 = ((eta * c - cos_t) / a) ** 2 if a != 0.0 else 1.0
    rp2 = ((c - eta * cos_t) / b) ** 2 if b != 0.0 else 1.0
    return 0.5 * (rs2 + rp2)


@njit(cache=True, inline="always")
def _g1(cos_v, alpha):
    c2 = min(max(cos_v * cos_v, 1e-12), 1.0)
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2))


@njit(cache=True)
def _split_sum(lut, cos_v, rough):
    n_r, n_v = lut.shape[0], lut.shape[1]
    x = min(max(cos_v * n_v - 0.5, 0.0), n_v - 1.0)
    y = min(max(rough * n_r - 0.5, 0.0), n_r - 1.0)
    x0, y0 = min(int(x), n_v - 2), min(int(y), n_r - 2)
    fx, fy = x - x0, y - y0
    out = np.empty(2)
    for c in range(2):
        top = lut[y0, x0, c] * (1 - fx) + lut[y0, x0 + 1, c] * fx
        bottom = lut[y0 + 1, x0, c] * (1 - fx) + lut[y0 + 1, x0 + 1, c] * fx
        out[c] = top * (1 - fy) + bottom * fy
    return out[0], out[1]


@njit(cache=True, inline="always")
def _spec_albedo(f0, a, b, ms):
    fss = f0 * a + b
    if not ms:
        return fss
    ems = 1.0 - (a + b)
    favg = f0 + (1.0 - f0) / 21.0
    return fss + ems * fss * favg / max(1.0 - ems * favg, 1e-6)


@njit(cache=True)
def _storm_ab(table, rough):
    """core.storm.back_face_albedo: Storm's (A, B) at N.E = 0, linear in roughness."""
    x = min(max(rough, 0.0), 1.0) * (len(table) - 1)
    i = min(int(x), len(table) - 2)
    f = x - i
    return table[i, 0] * (1 - f) + table[i + 1, 0] * f, table[i, 1] * (1 - f) + table[i + 1, 1] * f


@njit(cache=True)
def _lut_albedo(lut, cos_v, rough):
    if rough <= 0:
        return 1.0
    n = lut.shape[0]
    x = min(max(abs(cos_v) * n - 0.5, 0.0), n - 1.0)
    y = min(max(rough * n - 0.5, 0.0), n - 1.0)
    x0, y0 = int(math.floor(x)), int(math.floor(y))
    x1, y1 = min(x0 + 1, n - 1), min(y0 + 1, n - 1)
    fx, fy = x - x0, y - y0

    def e(i, j):
        return lut[i, j, 0] + lut[i, j, 1]
    top = e(y0, x0) * (1 - fx) + e(y0, x1) * fx
    bottom = e(y1, x0) * (1 - fx) + e(y1, x1) * fx
    return top * (1 - fy) + bottom * fy


@njit(cache=True)
def _visible_normal(vx, vy, vz, nx, ny, nz, alpha, u1, u2):
    """As renderer.methods.optics.ggx_visible_normal, one ray: the world-space microfacet normal."""
    sign = 1.0 if nz >= 0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tx, ty, tz = 1.0 + sign * nx * nx * a, sign * b, -sign * nx
    bx, by, bz = b, sign + ny * ny * a, -ny
    lx, ly = vx * tx + vy * ty + vz * tz, vx * bx + vy * by + vz * bz
    lz = max(vx * nx + vy * ny + vz * nz, 1e-7)
    hx, hy, hz = alpha * lx, alpha * ly, lz
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    lensq = hx * hx + hy * hy
    if lensq > 0:
        il = 1.0 / math.sqrt(max(lensq, 1e-30))
        t1x, t1y, t1z = -hy * il, hx * il, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x, t2y, t2z = hy * t1z - hz * t1y, hz * t1x - hx * t1z, hx * t1y - hy * t1x
    r, phi = math.sqrt(u1), 2.0 * math.pi * u2
    p1, p2 = r * math.cos(phi), r * math.sin(phi)
    s = 0.5 * (1.0 + hz)
    p2 = (1.0 - s) * math.sqrt(max(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = math.sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0))
    mx = alpha * (p1 * t1x + p2 * t2x + p3 * hx)
    my = alpha * (p1 * t1y + p2 * t2y + p3 * hy)
    mz = max(p1 * t1z + p2 * t2z + p3 * hz, 1e-7)
    inv = 1.0 / math.sqrt(mx * mx + my * my + mz * mz)
    mx, my, mz = mx * inv, my * inv, mz * inv
    return (mx * tx + my * bx + mz * nx, mx * ty + my * by + mz * ny, mx * tz + my * bz + mz * nz)


@njit(cache=True, inline="always")
def _bend(sx, sy, sz, gx, gy, gz, bent, i, off):
    """The shading normal s bent as the raster bends it (shaders/material_info.glsl m.bent):
    normalize(s + normalize(b) - g), b the baked bent normal of the side the ray meets (columns
    off .. off + 2) and g the geometric normal facing the ray; s where there is none."""
    bx, by, bz = bent[i, off], bent[i, off + 1], bent[i, off + 2]
    ll = bx * bx + by * by + bz * bz
    if ll <= 1e-12:
        return sx, sy, sz
    inv = 1.0 / math.sqrt(ll)
    x, y, z = sx + bx * inv - gx, sy + by * inv - gy, sz + bz * inv - gz
    inv = 1.0 / math.sqrt(max(x * x + y * y + z * z, 1e-30))
    return x * inv, y * inv, z * inv


@njit(cache=True, inline="always")
def _dominant(rx, ry, rz, nx, ny, nz, rough):
    """The dominant direction of a GGX lobe about mirror direction r and normal n (Lagarde &
    de Rousiers 2014, as shaders/ibl.glsl specular_dir): toward n as the lobe widens."""
    alpha = rough * rough
    s = 1.0 - alpha
    f = s * (math.sqrt(s) + alpha)
    x, y, z = nx + (rx - nx) * f, ny + (ry - ny) * f, nz + (rz - nz) * f
    inv = 1.0 / math.sqrt(max(x * x + y * y + z * z, 1e-30))
    return x * inv, y * inv, z * inv


@njit(cache=True)
def _refract(dx, dy, dz, nx, ny, nz, eta):
    cos_i = min(max(-(dx * nx + dy * ny + dz * nz), 0.0), 1.0)
    k = (1.0 - eta * eta) + eta * eta * cos_i * cos_i
    if k < 0.0:
        return 0.0, 0.0, 0.0, True
    c = eta * cos_i - math.sqrt(k)
    tx, ty, tz = eta * dx + c * nx, eta * dy + c * ny, eta * dz + c * nz
    inv = 1.0 / math.sqrt(tx * tx + ty * ty + tz * tz)
    return tx * inv, ty * inv, tz * inv, False


@njit(cache=True, parallel=True)
def shade(origins, d, prim, u, v, t, w, px, sb, sl, v_in, sh, n_in, look,
          normals, geo_normals, material, base, metallic, roughness, transmission, ior, sigma,
          thin, emission, occlusion, spec, spec_col, lut, depth, n_sub, eps, sample_lobes, split_sample, ms, min_weight,
          sobol, roulette, nee, mirror_lo, mirror_hi, probe, storm_back, storm_table, glass_e, bent):
    """One bounce's rays (prim < 0: missed) -> (children: origin, dir, weight, pix, sub,
    slot, blur, share, medium, mirror share, look; the misses' look, weight x share, blur and slot;
    emission to add and its slots; the diffuse shares' weight x share, normals and slots; TIR
    events on transmissive surfaces). The mirror share is the part of a light triangle's
    emission a reflected child counts where this hit sampled the emitters (`nee` > 0):
    trace_lights.mirror_share of the roughness, 1 at mirror_lo and below, 0 from mirror_hi;
    1 where the hit sampled none, and for refracted children. `look`: where a ray reads the
    prefiltered environment if it escapes (its direction, but for a rough reflection that is
    not a sampled glass lobe: its lobe's dominant direction, `_dominant`). With `probe` > 0
    such a child travels along a direction drawn from its lobe (a GGX visible normal of
    alpha sqrt(probe)): what it meets is seen in part, and if it escapes it still reads the
    whole lobe's prefiltered light (renderer.methods.raytrace.ROUGH_PROBE). `storm_back`
    (per ray): a back face hit by it is lit as Storm lights a single-sided USD one
    (core.storm; its (A, B) at N.E = 0 in `storm_table`): the authored normal, no refraction.
    `glass_e` (path_bsdf.glass_table, or empty: none): a sampled rough glass lobe's children
    over its single-scattering albedo, what bounces between microfacets put back. `bent` (N x 6
    per ray, or empty: none): the baked bent normals, front and back (trace_material.bent_at);
    the diffuse share's normal is the shading normal bent by them (_bend)."""
    n = len(d)
    m_d, m_w, m_blur = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    m_sl = np.empty(n, np.int64)
    e_d, e_w, e_blur = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)  # Storm back faces'
    e_sl = np.empty(n, np.int64)  # reflections: read from the environment, no child
    c_o, c_d, c_w = np.empty((2 * n, 3)), np.empty((2 * n, 3)), np.empty((2 * n, 3))
    c_px, c_sb, c_sl = np.empty(2 * n, np.int64), np.empty(2 * n, np.int64), np.empty(2 * n, np.int64)
    c_blur, c_sh, c_med = np.empty(2 * n), np.empty(2 * n), np.empty(2 * n)
    c_share = np.empty(2 * n)
    c_look = np.empty((2 * n, 3))
    direct, glow = np.empty((n, 3)), np.empty(n, np.int64)
    diffuse, dnorm, matte = np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int64)
    # Rows in a fixed number of chunks (a function of n only) over the cores, each writing its
    # outputs from its first row on; then packed in row order: the same arrays, in the same
    # order, as one serial pass gives, whatever the thread count.
    nch = max(min(CHUNKS, n), 1)
    counts = np.zeros((nch, 7), np.int64)
    for ch in prange(nch):
        lo, hi = ch * n // nch, (ch + 1) * n // nch
        r = _shade_rows(lo, hi, n, origins, d, prim, u, v, t, w, px, sb, sl, v_in, sh, n_in, look,
                        normals, geo_normals, material, base, metallic, roughness, transmission, ior, sigma,
                        thin, emission, occlusion, spec, spec_col, lut, depth, n_sub, eps, sample_lobes, split_sample, ms, min_weight,
                        sobol, roulette, nee, mirror_lo, mirror_hi, probe, storm_back, storm_table, glass_e, bent,
                        m_d, m_w, m_blur, m_sl, e_d, e_w, e_blur, e_sl, c_o, c_d, c_w, c_px, c_sb, c_sl, c_blur,
                        c_sh, c_med, c_share, c_look, direct, glow, diffuse, dnorm, matte)
        counts[ch, 0], counts[ch, 1], counts[ch, 2] = r[0] - lo, r[1] - lo, r[2] - lo
        counts[ch, 3], counts[ch, 4], counts[ch, 5] = r[3] - n - lo, r[4] - lo, r[5] - lo
        counts[ch, 6] = r[6]
    n_miss = _pack(counts, 0, nch, n, m_d, m_w, m_blur, m_sl)
    n_env = _pack(counts, 1, nch, n, e_d, e_w, e_blur, e_sl)
    n_glow = _pack_pair(counts, 4, nch, n, direct, glow)
    n_matte = _pack_matte(counts, 5, nch, n, diffuse, dnorm, matte)
    n_r = _pack_children(counts, 2, nch, n, 0, 0, c_o, c_d, c_w, c_px, c_sb, c_sl, c_blur, c_sh,
                         c_med, c_share, c_look)
    m = n_r + _pack_children(counts, 3, nch, n, n, n_r, c_o, c_d, c_w, c_px, c_sb, c_sl, c_blur,
                             c_sh, c_med, c_share, c_look)
    tir_events = 0
    for ch in range(nch):
        tir_events += counts[ch, 6]
    return (c_o[:m], c_d[:m], c_w[:m], c_px[:m], c_sb[:m], c_sl[:m], c_blur[:m], c_sh[:m],
            c_med[:m], c_share[:m], c_look[:m], m_d[:n_miss], m_w[:n_miss], m_blur[:n_miss], m_sl[:n_miss], direct[:n_glow], glow[:n_glow], diffuse[:n_matte], dnorm[:n_matte],
            matte[:n_matte], tir_events, e_d[:n_env], e_w[:n_env], e_blur[:n_env], e_sl[:n_env])


CHUNKS = 64  # shade's rows cut into this many chunks over the cores


@njit(cache=True)
def _bounds(ch, nch, n):
    return ch * n // nch, (ch + 1) * n // nch


@njit(cache=True)
def _pack(counts, q, nch, n, a3, b3, c1, d1):
    """Move chunk segments of four row outputs (each from its chunk's first row) together, in
    chunk order; the destination never passes its source (the count so far <= the row)."""
    k = 0
    for ch in range(nch):
        lo, _ = _bounds(ch, nch, n)
        for j in range(lo, lo + counts[ch, q]):
            for c in range(3):
                a3[k, c], b3[k, c] = a3[j, c], b3[j, c]
            c1[k], d1[k] = c1[j], d1[j]
            k += 1
    return k


@njit(cache=True)
def _pack_pair(counts, q, nch, n, a3, d1):
    k = 0
    for ch in range(nch):
        lo, _ = _bounds(ch, nch, n)
        for j in range(lo, lo + counts[ch, q]):
            for c in range(3):
                a3[k, c] = a3[j, c]
            d1[k] = d1[j]
            k += 1
    return k


@njit(cache=True)
def _pack_matte(counts, q, nch, n, a3, b3, d1):
    k = 0
    for ch in range(nch):
        lo, _ = _bounds(ch, nch, n)
        for j in range(lo, lo + counts[ch, q]):
            for c in range(3):
                a3[k, c], b3[k, c] = a3[j, c], b3[j, c]
            d1[k] = d1[j]
            k += 1
    return k


@njit(cache=True)
def _pack_children(counts, q, nch, n, src0, dst0, c_o, c_d, c_w, c_px, c_sb, c_sl, c_blur, c_sh,
                   c_med, c_share, c_look):
    """The children of counts[:, q] (chunk segments from src0 + the chunk's first row) to
    dst0 on, in chunk order (dst0 + count so far <= src0 + row: never past the source)."""
    k = dst0
    for ch in range(nch):
        lo, _ = _bounds(ch, nch, n)
        for j in range(src0 + lo, src0 + lo + counts[ch, q]):
            for c in range(3):
                c_o[k, c], c_d[k, c], c_w[k, c], c_look[k, c] = c_o[j, c], c_d[j, c], c_w[j, c], c_look[j, c]
            c_px[k], c_sb[k], c_sl[k] = c_px[j], c_sb[j], c_sl[j]
            c_blur[k], c_sh[k], c_med[k], c_share[k] = c_blur[j], c_sh[j], c_med[j], c_share[j]
            k += 1
    return k - dst0


@njit(cache=True)
def _shade_rows(lo, hi, n, origins, d, prim, u, v, t, w, px, sb, sl, v_in, sh, n_in, look,
                normals, geo_normals, material, base, metallic, roughness, transmission, ior, sigma,
                thin, emission, occlusion, spec, spec_col, lut, depth, n_sub, eps, sample_lobes, split_sample, ms, min_weight,
                sobol, roulette, nee, mirror_lo, mirror_hi, probe, storm_back, storm_table, glass_e, bent,
                m_d, m_w, m_blur, m_sl, e_d, e_w, e_blur, e_sl, c_o, c_d, c_w, c_px, c_sb, c_sl, c_blur,
                c_sh, c_med, c_share, c_look, direct, glow, diffuse, dnorm, matte):
    """shade's rows lo .. hi - 1, each output written from row lo on (refracted children from
    n + lo): (the next free index of misses, Storm reflections, reflected and refracted
    children, emission and diffuse rows, and the TIR events)."""
    p = np.empty(3)
    n_miss, n_env, n_r, n_t_count, n_glow, n_matte, tir_events = lo, lo, lo, n + lo, lo, lo, 0
    for i in range(lo, hi):
        tri = prim[i]
        dx, dy, dz = np.float64(d[i, 0]), np.float64(d[i, 1]), np.float64(d[i, 2])
        if tri < 0:
            m_d[n_miss, 0], m_d[n_miss, 1], m_d[n_miss, 2] = look[i, 0], look[i, 1], look[i, 2]
            for c in range(3):
                m_w[n_miss, c] = w[i, c] * sh[i]
            m_blur[n_miss], m_sl[n_miss] = v_in[i], sl[i]
            n_miss += 1
            continue
        for c in range(3):
            p[c] = origins[i, c] + d[i, c] * t[i]
        sx, sy, sz = normals[i, 0], normals[i, 1], normals[i, 2]
        gx, gy, gz = geo_normals[tri, 0], geo_normals[tri, 1], geo_normals[tri, 2]
        entering = dx * gx + dy * gy + dz * gz < 0
        side = 1.0 if entering else -1.0
        gx, gy, gz, sx, sy, sz = gx * side, gy * side, gz * side, sx * side, sy * side, sz * side
        if dx * sx + dy * sy + dz * sz >= 0:
            sx, sy, sz = gx, gy, gz
        k = material[tri]
        metal, rough, trans, n_k = metallic[i], roughness[i], transmission[i], ior[k]
        back = storm_back[i] and not entering
        if back:  # the authored normal, facing away from the ray: N.E clamps to 0
            sx, sy, sz = normals[i, 0], normals[i, 1], normals[i, 2]
        sheet = thin[k]
        entering = entering or sheet  # a thin sheet has no inside
        w0, w1, w2 = w[i, 0], w[i, 1], w[i, 2]
        if not entering and trans > 0:
            w0 *= math.exp(-sigma[k, 0] * t[i])
            w1 *= math.exp(-sigma[k, 1] * t[i])
            w2 *= math.exp(-sigma[k, 2] * t[i])
        if max(emission[i, 0], emission[i, 1], emission[i, 2]) > 0:
            direct[n_glow, 0] = w0 * emission[i, 0] * sh[i]
            direct[n_glow, 1] = w1 * emission[i, 1] * sh[i]
            direct[n_glow, 2] = w2 * emission[i, 2] * sh[i]
            glow[n_glow] = sl[i]
            n_glow += 1
        cos_i = -(dx * sx + dy * sy + dz * sz)
        eta = 1.0 / n_k if entering else n_k
        fres = _fresnel(cos_i, eta)
        f_s = fres
        cos_c = min(max(cos_i, 1e-4), 1.0)
        lobe = sample_lobes and rough > 0 and trans > 0
        f_back, a_b, b_b = 0.0, 0.0, 0.0  # a back face's: diffuse (1 - F0), Storm's (A, B)
        if back:
            f0 = ((n_k - 1) / (n_k + 1)) ** 2
            a_b, b_b = _storm_ab(storm_table, rough)
            fres, f_s, f_back = f0 * a_b + b_b, f0 * a_b + b_b, f0
            lobe = False
        elif entering and rough > 0 and not lobe:
            f0 = ((n_k - 1) / (n_k + 1)) ** 2
            a, b = _split_sum(lut, cos_c, rough)
            a0, b0s = _split_sum(lut, cos_c, 0.0)
            e_s = _spec_albedo(f0, a0, b0s, ms)
            fres = min(max(fres * _spec_albedo(f0, a, b, ms) / max(e_s, 1e-6), 0.0), 1.0)
        g_r, g_t = 1.0, 1.0
        ms_lost = 0.0  # of a sampled rough glass lobe: 1 - its albedo, put back below
        tir = False
        if lobe:
            alpha = rough * rough
            u1, u2 = _pixel_samples(px[i], sb[i], depth, sobol)
            mx, my, mz = _visible_normal(-dx, -dy, -dz, sx, sy, sz, alpha, u1, u2)
            cos_m = min(max(-(dx * mx + dy * my + dz * mz), 0.0), 1.0)
            fres = _fresnel(cos_m, eta)
            f_s = fres
            rx, ry, rz = dx + 2 * cos_m * mx, dy + 2 * cos_m * my, dz + 2 * cos_m * mz
            tx, ty, tz, tir = _refract(dx, dy, dz, mx, my, mz, eta)
            cr = rx * sx + ry * sy + rz * sz
            ct = tx * sx + ty * sy + tz * sz
            g_r = _g1(cr, alpha) if cr > 0 and rx * mx + ry * my + rz * mz > 0 else 0.0
            g_t = _g1(-ct, alpha) if ct < 0 and not tir else 0.0
            ms_lost = 1.0 - glass_albedo(glass_e, min(max(cos_i, 0.0), 1.0), alpha, eta)
        else:
            c2 = dx * sx + dy * sy + dz * sz
            rx, ry, rz = dx - 2 * c2 * sx, dy - 2 * c2 * sy, dz - 2 * c2 * sz
            tx, ty, tz, tir = _refract(dx, dy, dz, sx, sy, sz, eta)
        if not lobe and rough > 0:  # a wide lobe's light comes from nearer the normal
            rx, ry, rz = _dominant(rx, ry, rz, sx, sy, sz, rough)
        lx, ly, lz = rx, ry, rz
        if probe > 0 and not lobe and rough > 0:  # travel along a direction of the lobe
            u1, u2 = _pixel_samples(px[i], sb[i], depth, sobol)
            mx, my, mz = _visible_normal(-dx, -dy, -dz, sx, sy, sz, rough * rough * math.sqrt(probe), u1, u2)
            c2 = dx * mx + dy * my + dz * mz
            qx, qy, qz = dx - 2 * c2 * mx, dy - 2 * c2 * my, dz - 2 * c2 * mz
            if qx * sx + qy * sy + qz * sz > 0:
                rx, ry, rz = qx, qy, qz
        if sheet and not tir:  # out through the parallel back face: unbent where smooth
            if lobe:
                tx, ty, tz, tir = _refract(tx, ty, tz, sx, sy, sz, n_k)
            else:
                tx, ty, tz = dx, dy, dz
        if tir:
            tx, ty, tz = rx, ry, rz
        # reflected and transmitted throughput
        fc0, fc1, fc2 = fres, fres, fres
        s_k = spec[i]
        if entering and not back and (s_k != 1.0 or spec_col[i, 0] != 1.0 or spec_col[i, 1] != 1.0
                         or spec_col[i, 2] != 1.0):  # KHR_materials_specular: optics.specular_tint
            f0 = ((n_k - 1) / (n_k + 1)) ** 2
            x = min(max((f_s - f0) / max(1 - f0, 1e-12), 0.0), 1.0)
            ratio = fres / max(f_s, 1e-12)
            f0c = min(f0 * spec_col[i, 0], 1.0)
            fc0 = min(max(s_k * (f0c + (1 - f0c) * x) * ratio, 0.0), 1.0)
            f0c = min(f0 * spec_col[i, 1], 1.0)
            fc1 = min(max(s_k * (f0c + (1 - f0c) * x) * ratio, 0.0), 1.0)
            f0c = min(f0 * spec_col[i, 2], 1.0)
            fc2 = min(max(s_k * (f0c + (1 - f0c) * x) * ratio, 0.0), 1.0)
            fres = max(fc0, fc1, fc2)
        # the crossing's tint: base once through a sheet, sqrt(base) at each crossing of a
        # volume (Cycles' convention: base overall for one colour), as the numpy twin; what
        # bounced between a rough lobe's facets comes back in both children (path_bsdf.glass_ms)
        if sheet:
            x0, x1, x2 = base[i, 0], base[i, 1], base[i, 2]
        else:
            x0 = math.sqrt(max(base[i, 0], 0.0))
            x1 = math.sqrt(max(base[i, 1], 0.0))
            x2 = math.sqrt(max(base[i, 2], 0.0))
        ms0, ms1, ms2 = 1.0 / (1.0 - ms_lost * x0), 1.0 / (1.0 - ms_lost * x1), 1.0 / (1.0 - ms_lost * x2)
        r0 = (1 - metal) * fc0 * g_r * w0 * ms0
        r1 = (1 - metal) * fc1 * g_r * w1 * ms1
        r2 = (1 - metal) * fc2 * g_r * w2 * ms2
        if metal > 0 and back:
            r0 += metal * (base[i, 0] * a_b + b_b) * w0
            r1 += metal * (base[i, 1] * a_b + b_b) * w1
            r2 += metal * (base[i, 2] * a_b + b_b) * w2
        elif metal > 0:
            a, b = _split_sum(lut, cos_c, rough)
            r0 += metal * _spec_albedo(base[i, 0], a, b, ms) * w0
            r1 += metal * _spec_albedo(base[i, 1], a, b, ms) * w1
            r2 += metal * _spec_albedo(base[i, 2], a, b, ms) * w2
        e_ss = g_t if lobe else _lut_albedo(lut, cos_i, rough)
        ft = (1 - metal) * (1 - fres) * trans * (1.0 if sheet else eta * eta) * e_ss
        q0, q1, q2 = ft * x0 * w0 * ms0, ft * x1 * w1 * ms1, ft * x2 * w2 * ms2
        fd = (1 - metal) * (1 - (f_back if back else fres)) * (1 - trans) * occlusion[i]
        if fd > 0 and max(base[i, 0] * w0, base[i, 1] * w1, base[i, 2] * w2) > 0:
            diffuse[n_matte, 0] = fd * base[i, 0] * w0 * sh[i]
            diffuse[n_matte, 1] = fd * base[i, 1] * w1 * sh[i]
            diffuse[n_matte, 2] = fd * base[i, 2] * w2 * sh[i]
            bx, by, bz = sx, sy, sz
            if len(bent) and not back:
                bx, by, bz = _bend(sx, sy, sz, gx, gy, gz, bent, i, 0 if side > 0 else 3)
            dnorm[n_matte, 0], dnorm[n_matte, 1], dnorm[n_matte, 2] = bx, by, bz
            matte[n_matte] = sl[i]
            n_matte += 1
        alpha_b = 0.0 if lobe else rough * rough
        v_refl = v_in[i] + alpha_b ** 2
        v_refr = v_in[i] + (alpha_b * abs(1.0 - eta) / 2) ** 2
        if tir and trans > 0:
            tir_events += 1
        n_t = n_in[i] if sheet else (n_k if entering else 1.0)
        pr = max(r0, r1, r2) * n_in[i] ** 2
        pt = max(q0, q1, q2) * n_t ** 2
        keep_r = pr > min_weight
        keep_t = pt > min_weight and not tir
        if back:
            if keep_r:
                e_d[n_env, 0], e_d[n_env, 1], e_d[n_env, 2] = rx, ry, rz
                e_w[n_env, 0], e_w[n_env, 1], e_w[n_env, 2] = r0 * sh[i], r1 * sh[i], r2 * sh[i]
                e_blur[n_env], e_sl[n_env] = v_refl, sl[i]
                n_env += 1
            keep_r = False
        if split_sample and depth > 0:
            p_r = (pr if keep_r else 0.0)
            p_t = (pt if keep_t else 0.0)
            p_r = p_r / max(p_r + p_t, 1e-30)
            take_r = ((sb[i] + 0.5) / n_sub + _pixel_shift(px[i], depth)) % 1.0 < p_r
            keep_r, keep_t = keep_r and take_r, keep_t and not take_r
            sr, st = 1.0 / max(p_r, 1e-30), 1.0 / max(1.0 - p_r, 1e-30)
            r0, r1, r2, q0, q1, q2 = r0 * sr, r1 * sr, r2 * sr, q0 * st, q1 * st, q2 * st
        elif roulette > 0 and depth > 0:
            if keep_r and pr < roulette:
                keep_r = ((sb[i] + 0.5) / n_sub + _pixel_shift(px[i], depth + 500)) % 1.0 < pr / roulette
                sr = roulette / pr
                r0, r1, r2 = r0 * sr, r1 * sr, r2 * sr
            if keep_t and pt < roulette:
                keep_t = ((sb[i] + 0.5) / n_sub + _pixel_shift(px[i], depth + 700)) % 1.0 < pt / roulette
                st = roulette / pt
                q0, q1, q2 = q0 * st, q1 * st, q2 * st
        if keep_r:
            share_r = 1.0  # of a light's emission, what the mirror child counts
            if nee > 0 and not lobe and (entering or trans <= 0):
                share_r = min(max((mirror_hi - rough) / (mirror_hi - mirror_lo), 0.0), 1.0)
            c_share[n_r] = share_r
            o = eps if rx * gx + ry * gy + rz * gz >= 0 else -eps
            c_o[n_r, 0], c_o[n_r, 1], c_o[n_r, 2] = p[0] + o * gx, p[1] + o * gy, p[2] + o * gz
            c_d[n_r, 0], c_d[n_r, 1], c_d[n_r, 2] = rx, ry, rz
            c_look[n_r, 0], c_look[n_r, 1], c_look[n_r, 2] = lx, ly, lz
            c_w[n_r, 0], c_w[n_r, 1], c_w[n_r, 2] = r0, r1, r2
            c_px[n_r], c_sb[n_r], c_sl[n_r] = px[i], sb[i], sl[i]
            c_blur[n_r], c_sh[n_r], c_med[n_r] = v_refl, sh[i], n_in[i]
            n_r += 1
        if keep_t:  # refracted children in the second half, after every reflected one
            o = eps if tx * gx + ty * gy + tz * gz > 0 else -eps
            j = n_t_count
            c_o[j, 0], c_o[j, 1], c_o[j, 2] = p[0] + o * gx, p[1] + o * gy, p[2] + o * gz
            c_d[j, 0], c_d[j, 1], c_d[j, 2] = tx, ty, tz
            c_look[j, 0], c_look[j, 1], c_look[j, 2] = tx, ty, tz
            c_w[j, 0], c_w[j, 1], c_w[j, 2] = q0, q1, q2
            c_px[j], c_sb[j], c_sl[j] = px[i], sb[i], sl[i]
            c_blur[j], c_sh[j], c_med[j] = v_refr, sh[i], n_t
            c_share[j] = 1.0
            n_t_count += 1
    return n_miss, n_env, n_r, n_t_count, n_glow, n_matte, tir_events


# Cube-map faces as core.cubemap lays them out: per face, the axis and sign of s and of t.
_S_AXIS = np.array([2, 2, 0, 0, 0, 0], np.int64)
_S_SIGN = np.array([-1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
_T_AXIS = np.array([1, 1, 2, 2, 1, 1], np.int64)
_T_SIGN = np.array([-1.0, -1.0, 1.0, -1.0, -1.0, -1.0])


@njit(cache=True, parallel=True)
def sample_cube(faces, d, s_axis, s_sign, t_axis, t_sign):
    """core.cubemap.sample_cube for 6 x S x S x 3 faces: bilinear, clamped at face edges
    (rows independent: over the cores)."""
    size = faces.shape[1]
    out = np.empty((len(d), 3))
    for i in prange(len(d)):
        ax, ay, az = abs(d[i, 0]), abs(d[i, 1]), abs(d[i, 2])
        major = 0
        if ay > ax and ay >= az:
            major = 1
        elif az > ax and az > ay:
            major = 2
        m = d[i, major]
        face = major * 2 + (1 if m < 0 else 0)
        ma = abs(m)
        s = (s_sign[face] * d[i, s_axis[face]] / ma + 1) / 2
        t = (t_sign[face] * d[i, t_axis[face]] / ma + 1) / 2
        x = min(max(s * size - 0.5, 0.0), size - 1.0)
        y = min(max(t * size - 0.5, 0.0), size - 1.0)
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        x1, y1 = min(x0 + 1, size - 1), min(y0 + 1, size - 1)
        fx, fy = x - x0, y - y0
        for c in range(3):
            top = faces[face, y0, x0, c] * (1 - fx) + faces[face, y0, x1, c] * fx
            bottom = faces[face, y1, x0, c] * (1 - fx) + faces[face, y1, x1, c] * fx
            out[i, c] = top * (1 - fy) + bottom * fy
    return out


@njit(cache=True)
def sobol_pair(pix, s, key, sobol):
    """The path tracer's two uniforms of (pixel, pass s, stream `key`) for every pixel: sample
    s of the pixel's shuffled, scrambled Sobol pair seeded by (pixel, key) (_pixel_samples;
    renderer.methods.path_trace._Sampler in one loop, trace_scene.sobol_samples its twin)."""
    n = len(pix)
    a = np.empty(n)
    b = np.empty(n)
    for i in range(n):  # serial: threads cost more than this loop
        a[i], b[i] = _pixel_samples(pix[i], s, key, sobol)
    return a, b


@njit(cache=True, parallel=True)
def emitter_pick(x, u, centre, p0, normal, area, power, two_sided, pick):
    """trace_lights.emitter_choice's local odds, one point at a time (no N x E temporaries):
    with `pick`, the emitter u chooses at each point x and its probability; else u holds
    emitter indices and only their probabilities are returned (trace_lights.emitter_odds)."""
    n, e = len(x), len(centre)
    j_out = np.zeros(n, np.int64)
    prob = np.zeros(n)
    for i in prange(n):
        w = np.empty(e)
        total = 0.0
        for k in range(e):
            w[k] = 0.0
            s = ((x[i, 0] - p0[k, 0]) * normal[k, 0] + (x[i, 1] - p0[k, 1]) * normal[k, 1]
                 + (x[i, 2] - p0[k, 2]) * normal[k, 2])
            if two_sided[k] or s > 0:
                dx, dy, dz = centre[k, 0] - x[i, 0], centre[k, 1] - x[i, 1], centre[k, 2] - x[i, 2]
                w[k] = power[k] / max(dx * dx + dy * dy + dz * dz, area[k])
            total += w[k]
        if total <= 0:
            continue
        if pick:
            target, acc, j = u[i] * total, 0.0, e - 1
            for k in range(e):
                acc += w[k]
                if acc > target:
                    j = k
                    break
        else:
            j = np.int64(u[i])
        j_out[i] = j
        prob[i] = w[j] / total
    return j_out, prob


def warm() -> None:
    """Compile (or load from numba's cache) every signature the tracer calls, on empty
    arrays: `python -m renderer.methods.trace_kernel`, run by `make install` and `make test` so that
    no timed render or server deadline pays the first compile."""
    f64, f32, i64 = np.float64, np.float32, np.int64
    e3, e = np.zeros((0, 3)), np.zeros(0)
    for t_type in (f32, f64):  # Embree's distances, or float64 after culled back faces
        shade(e3, e3, np.zeros(0, np.int32), np.zeros(0, f32), np.zeros(0, f32),
              np.zeros(0, t_type), e3, np.zeros(0, i64), np.zeros(0, i64), np.zeros(0, i64),
              e, e, e, e3, e3, np.zeros((0, 3), f32), np.zeros(0, np.int32),
              e3, e, e, e, e, e3, np.zeros(0, np.bool_), e3, e, e, e3, np.zeros((2, 2, 2)), 0, 1, 1e-4, True, False, True,
              1e-3, _SOBOL_DIM1, 0.0, 0.0, 0.15, 0.3, 0.5, np.zeros(0, np.bool_), np.zeros((2, 2)),
              np.zeros((0, 1, 1, 1)), np.zeros((0, 6)))
    sample_cube(np.zeros((6, 2, 2, 3), f32), e3, _S_AXIS, _S_SIGN, _T_AXIS, _T_SIGN)
    for pick in (True, False):
        emitter_pick(e3, e, e3, e3, e3, e, e, np.zeros(0, np.bool_), pick)
    sobol_pair(np.zeros(0, i64), 0, 0, _SOBOL_DIM1)
    # the textures, the hits' material, the path BSDF
    from renderer.methods import env_kernel, material_kernel, path_kernel, texel_kernel
    env_kernel.warm()
    texel_kernel.warm()
    material_kernel.warm()
    path_kernel.warm()


if __name__ == "__main__":
    t0 = time.perf_counter()
    warm()
    print(f"renderer.methods.trace_kernel compiled or loaded in {time.perf_counter() - t0:.1f} s")


@njit(cache=True, parallel=True)
def cosine_sums(normals, dirs, le):
    """Sum over texels j of max(0, normals[i] . dirs[j]) x le[j] for every normal i (M x 3): the
    irradiance the tree's diffuse share reads (renderer.methods.env_irradiance; numpy there
    is its twin), without an M x texels temporary."""
    m, k = len(normals), len(dirs)
    out = np.zeros((m, 3))
    for i in prange(m):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        r, g, b = 0.0, 0.0, 0.0
        for j in range(k):
            c = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            if c > 0:
                r += c * le[j, 0]
                g += c * le[j, 1]
                b += c * le[j, 2]
        out[i, 0], out[i, 1], out[i, 2] = r, g, b
    return out
