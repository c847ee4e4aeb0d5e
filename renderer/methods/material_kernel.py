"""The material at the tracer's hits, compiled (numba): what renderer.methods.trace_material.evaluate
computes for the core model and KHR_materials_specular (the fields the Fresnel tree's shading
kernel reads), one loop over the rays of a bounce instead of some 60 numpy passes a material
and their temporaries.

Per hit: the interpolated vertex normal, the ray cone's footprint, every core texture slot
(base colour, metal-rough, transmission, emissive, occlusion, normal, specular, specular
colour) with its KHR_texture_transform, UV set and sampler, trilinear on the baked mips at
that footprint (trace_kernel's texel reads), vertex colours, the normal map in the baked (or
UV-derived) tangent frame, unlit, and the baked per-vertex AO of the side the ray meets. Same
arithmetic as the numpy (tests/test_material_kernel.py compares the two on textured assets);
the path integrator's extension lobes (clearcoat, sheen, iridescence, anisotropy, diffuse
transmission) stay with the numpy evaluate.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from renderer.methods.texel_kernel import SRGB_LUT, UNIT_LUT, texel_level

# Slot order of the packed tables (renderer.methods.trace_material.pack).
SLOTS = ("base_color", "metallic_roughness", "transmission", "emissive", "occlusion", "normal",
         "specular", "specular_color")
_BASE, _MR, _TRANS, _EMIS, _OCC, _NORMAL, _SPEC, _SPEC_COL = range(8)
# Per-material factors (mat_f columns).
F_BASE, F_METAL, F_ROUGH, F_TRANS, F_EMIS, F_OCC, F_NSCALE, F_SPEC, F_SPEC_COL = 0, 3, 4, 5, 6, 9, 10, 11, 12
N_F = 15


@njit(cache=True)
def _fetch(k, s, prim, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m, texels, lv_off,
           lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, out):
    """out[:4] = the RGBA of material k's slot s at the hit (trace_material._lookup)."""
    c = slot_chain[k, s]
    uvs = uv0 if slot_uv[k, s] == 0 else uv1
    dens = dens0 if slot_uv[k, s] == 0 else dens1
    iu = bw * uvs[prim, 0, 0] + bu * uvs[prim, 1, 0] + bv * uvs[prim, 2, 0]
    iv = bw * uvs[prim, 0, 1] + bu * uvs[prim, 1, 1] + bv * uvs[prim, 2, 1]
    foot = width * dens[prim] / max(cos_d, 0.05)
    m = slot_m[k, s]
    x = m[0] * iu + m[1] * iv + m[2]
    y = m[3] * iu + m[4] * iv + m[5]
    first = ch_lv0[c]
    top = ch_nlv[c] - 1
    scale = math.sqrt(abs(m[0] * m[4] - m[1] * m[3]) * lv_w[first] * lv_h[first])
    lod = math.log2(max(foot * scale, 1e-30))
    mip_mode = ch_i[c, 5]
    level_f = min(max(lod, 0.0), float(top))
    if mip_mode == 0:
        level_f = 0.0
    elif mip_mode == 1:
        level_f = float(round(level_f))
    lo = int(math.floor(level_f))
    frac = level_f - lo
    nearest = (ch_i[c, 4] != 0) if lod > 0 else (ch_i[c, 3] != 0)
    for q in range(4):
        out[q] = 0.0
    table = SRGB_LUT if ch_i[c, 0] != 0 else UNIT_LUT
    for level, weight in ((lo, 1.0 - frac), (min(lo + 1, top), frac)):
        if weight <= 0.0:
            continue
        g = first + level
        h, w = lv_h[g], lv_w[g]
        texel_level(texels, lv_off[g], h, w, x * w - 0.5, y * h - 0.5, nearest, ch_i[c, 1],
                     ch_i[c, 2], table, out, weight)


@njit(cache=True)
def _perturb(tex, tx, ty, tz, tw, gx, gy, gz, scale):
    """trace_material._perturb for one hit: the normal map's texel in the frame (t, w) about g."""
    dot = gx * tx + gy * ty + gz * tz
    ax, ay, az = tx - gx * dot, ty - gy * dot, tz - gz * dot
    inv = 1.0 / max(math.sqrt(ax * ax + ay * ay + az * az), 1e-20)
    ax, ay, az = ax * inv, ay * inv, az * inv
    sgn = 1.0 if tw > 0 else (-1.0 if tw < 0 else 0.0)
    bx, by, bz = (gy * az - gz * ay) * sgn, (gz * ax - gx * az) * sgn, (gx * ay - gy * ax) * sgn
    nx, ny, nz = (tex[0] * 2.0 - 1.0) * scale, (tex[1] * 2.0 - 1.0) * scale, tex[2] * 2.0 - 1.0
    px = nx * ax + ny * bx + nz * gx
    py = nx * ay + ny * by + nz * gy
    pz = nx * az + ny * bz + nz * gz
    inv = 1.0 / max(math.sqrt(px * px + py * py + pz * pz), 1e-20)
    px, py, pz = px * inv, py * inv, pz * inv
    if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
        return gx, gy, gz
    return px, py, pz


CHUNKS = 64  # rows of a call cut into this many chunks over the cores (each its own scratch)


@njit(cache=True, parallel=True)
def evaluate(prim, u, v, t, origins, d, eye, spread, normals, tri_mat, mat_f, mat_i,
             slot_chain, slot_uv, slot_m, texels, lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i,
             uv0, uv1, dens0, dens1, has_uv0, tangents, has_tan, corners, colors, has_col,
             ao, has_ao, o_n, o_base, o_metal, o_rough, o_trans, o_emis, o_occ, o_spec, o_spec_col):
    """Every ray of a bounce (prim < 0: missed, given trace_material.Hits.empty's row) -> its
    material in the o_* arrays. mat_i columns: unlit, uses specular. Rows are independent."""
    n = len(prim)
    nch = max(min(CHUNKS, n), 1)
    for ch in prange(nch):
        _rows(ch * n // nch, (ch + 1) * n // nch, prim, u, v, t, origins, d, eye, spread, normals,
              tri_mat, mat_f, mat_i, slot_chain, slot_uv, slot_m, texels, lv_off, lv_h, lv_w,
              ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, has_uv0, tangents, has_tan, corners,
              colors, has_col, ao, has_ao, o_n, o_base, o_metal, o_rough, o_trans, o_emis, o_occ,
              o_spec, o_spec_col)


@njit(cache=True)
def _rows(lo, hi, prim, u, v, t, origins, d, eye, spread, normals, tri_mat, mat_f, mat_i,
          slot_chain, slot_uv, slot_m, texels, lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i,
          uv0, uv1, dens0, dens1, has_uv0, tangents, has_tan, corners, colors, has_col,
          ao, has_ao, o_n, o_base, o_metal, o_rough, o_trans, o_emis, o_occ, o_spec, o_spec_col):
    """evaluate's rows lo .. hi - 1."""
    px = np.empty(4)
    for i in range(lo, hi):
        p = prim[i]
        if p < 0:
            for c in range(3):
                o_n[i, c] = 0.0
                o_base[i, c] = 0.0
                o_emis[i, c] = 0.0
                o_spec_col[i, c] = 1.0
            o_metal[i] = o_rough[i] = o_trans[i] = 0.0
            o_occ[i] = o_spec[i] = 1.0
            continue
        bu, bv = np.float64(u[i]), np.float64(v[i])
        bw = 1 - bu - bv
        nx = bw * np.float64(normals[p, 0, 0]) + bu * np.float64(normals[p, 1, 0]) + bv * np.float64(normals[p, 2, 0])
        ny = bw * np.float64(normals[p, 0, 1]) + bu * np.float64(normals[p, 1, 1]) + bv * np.float64(normals[p, 2, 1])
        nz = bw * np.float64(normals[p, 0, 2]) + bu * np.float64(normals[p, 1, 2]) + bv * np.float64(normals[p, 2, 2])
        side_dot = d[i, 0] * nx + d[i, 1] * ny + d[i, 2] * nz  # unnormalised: the AO's side
        inv = 1.0 / max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-20)
        nx, ny, nz = nx * inv, ny * inv, nz * inv
        cos_d = abs(d[i, 0] * nx + d[i, 1] * ny + d[i, 2] * nz)
        ex, ey, ez = origins[i, 0] - eye[0], origins[i, 1] - eye[1], origins[i, 2] - eye[2]
        width = spread * (math.sqrt(ex * ex + ey * ey + ez * ez) + t[i])
        k = tri_mat[p]
        b0, b1, b2 = mat_f[k, F_BASE], mat_f[k, F_BASE + 1], mat_f[k, F_BASE + 2]
        if slot_chain[k, _BASE] >= 0:
            _fetch(k, _BASE, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m, texels,
                   lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, px)
            b0, b1, b2 = b0 * px[0], b1 * px[1], b2 * px[2]
        if has_col:
            b0 *= bw * colors[p, 0, 0] + bu * colors[p, 1, 0] + bv * colors[p, 2, 0]
            b1 *= bw * colors[p, 0, 1] + bu * colors[p, 1, 1] + bv * colors[p, 2, 1]
            b2 *= bw * colors[p, 0, 2] + bu * colors[p, 1, 2] + bv * colors[p, 2, 2]
        metal, rough = mat_f[k, F_METAL], mat_f[k, F_ROUGH]
        if slot_chain[k, _MR] >= 0:
            _fetch(k, _MR, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m, texels,
                   lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, px)
            metal, rough = metal * px[2], rough * px[1]
        metal, rough = min(max(metal, 0.0), 1.0), min(max(rough, 0.0), 1.0)
        trans = mat_f[k, F_TRANS]
        if slot_chain[k, _TRANS] >= 0:
            _fetch(k, _TRANS, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m, texels,
                   lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, px)
            trans *= px[0]
        e0, e1, e2 = mat_f[k, F_EMIS], mat_f[k, F_EMIS + 1], mat_f[k, F_EMIS + 2]
        if slot_chain[k, _EMIS] >= 0:
            _fetch(k, _EMIS, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m, texels,
                   lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, px)
            e0, e1, e2 = e0 * px[0], e1 * px[1], e2 * px[2]
        occ, spec, s0, s1, s2 = 1.0, 1.0, 1.0, 1.0, 1.0
        sx, sy, sz = nx, ny, nz
        if mat_i[k, 0]:  # unlit: the colour as it is, emitted; nothing reflected
            e0, e1, e2, b0, b1, b2, metal, trans = b0, b1, b2, 0.0, 0.0, 0.0, 0.0, 0.0
        else:
            if slot_chain[k, _OCC] >= 0:
                _fetch(k, _OCC, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m, texels,
                       lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0, dens1, px)
                occ = 1.0 + mat_f[k, F_OCC] * (px[0] - 1.0)
            if slot_chain[k, _NORMAL] >= 0 and (has_tan or has_uv0):
                tx = ty = tz = tw = 0.0
                if has_tan:
                    tx = bw * tangents[p, 0, 0] + bu * tangents[p, 1, 0] + bv * tangents[p, 2, 0]
                    ty = bw * tangents[p, 0, 1] + bu * tangents[p, 1, 1] + bv * tangents[p, 2, 1]
                    tz = bw * tangents[p, 0, 2] + bu * tangents[p, 1, 2] + bv * tangents[p, 2, 2]
                    tw = bw * tangents[p, 0, 3] + bu * tangents[p, 1, 3] + bv * tangents[p, 2, 3]
                if abs(tw) <= 0.5 and has_uv0:  # the triangle's dP/du (trace_material._tangents)
                    e1x, e1y, e1z = (corners[p, 1, 0] - corners[p, 0, 0], corners[p, 1, 1] - corners[p, 0, 1],
                                     corners[p, 1, 2] - corners[p, 0, 2])
                    e2x, e2y, e2z = (corners[p, 2, 0] - corners[p, 0, 0], corners[p, 2, 1] - corners[p, 0, 1],
                                     corners[p, 2, 2] - corners[p, 0, 2])
                    d1u, d1v = uv0[p, 1, 0] - uv0[p, 0, 0], uv0[p, 1, 1] - uv0[p, 0, 1]
                    d2u, d2v = uv0[p, 2, 0] - uv0[p, 0, 0], uv0[p, 2, 1] - uv0[p, 0, 1]
                    det = d1u * d2v - d2u * d1v
                    if abs(det) > 1e-12:
                        gtx, gty, gtz = (d2v * e1x - d1v * e2x) / det, (d2v * e1y - d1v * e2y) / det, \
                            (d2v * e1z - d1v * e2z) / det
                        gbx, gby, gbz = (d1u * e2x - d2u * e1x) / det, (d1u * e2y - d2u * e1y) / det, \
                            (d1u * e2z - d2u * e1z) / det
                        if math.sqrt(gtx * gtx + gty * gty + gtz * gtz) > 0:
                            cx, cy, cz = ny * gtz - nz * gty, nz * gtx - nx * gtz, nx * gty - ny * gtx
                            tx, ty, tz = gtx, gty, gtz
                            tw = -1.0 if cx * gbx + cy * gby + cz * gbz < 0 else 1.0
                if abs(tw) > 0.5:
                    _fetch(k, _NORMAL, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m,
                           texels, lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0,
                           dens1, px)
                    sx, sy, sz = _perturb(px, tx, ty, tz, tw, nx, ny, nz, mat_f[k, F_NSCALE])
            if mat_i[k, 1]:  # KHR_materials_specular
                spec = mat_f[k, F_SPEC]
                s0, s1, s2 = mat_f[k, F_SPEC_COL], mat_f[k, F_SPEC_COL + 1], mat_f[k, F_SPEC_COL + 2]
                if slot_chain[k, _SPEC] >= 0:
                    _fetch(k, _SPEC, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m,
                           texels, lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0,
                           dens1, px)
                    spec *= px[3]
                if slot_chain[k, _SPEC_COL] >= 0:
                    _fetch(k, _SPEC_COL, p, bu, bv, bw, width, cos_d, slot_chain, slot_uv, slot_m,
                           texels, lv_off, lv_h, lv_w, ch_lv0, ch_nlv, ch_i, uv0, uv1, dens0,
                           dens1, px)
                    s0, s1, s2 = s0 * px[0], s1 * px[1], s2 * px[2]
        if has_ao:  # the baked visibility of the side the ray meets (core.lobes.ao_multibounce)
            f = 0 if side_dot < 0 else 1
            a = bw * ao[p, 0, f] + bu * ao[p, 1, f] + bv * ao[p, 2, f]
            albedo = (b0 * (1.0 - metal) + b1 * (1.0 - metal) + b2 * (1.0 - metal)) / 3.0
            ca, cb, cc = 2.0404 * albedo - 0.3324, -4.7951 * albedo + 0.6417, 2.7552 * albedo + 0.6903
            occ = min(occ, max(a, ((a * ca + cb) * a + cc) * a))
        o_n[i, 0], o_n[i, 1], o_n[i, 2] = sx, sy, sz
        o_base[i, 0], o_base[i, 1], o_base[i, 2] = b0, b1, b2
        o_emis[i, 0], o_emis[i, 1], o_emis[i, 2] = e0, e1, e2
        o_spec_col[i, 0], o_spec_col[i, 1], o_spec_col[i, 2] = s0, s1, s2
        o_metal[i], o_rough[i], o_trans[i], o_occ[i], o_spec[i] = metal, rough, trans, occ, spec


def warm() -> None:
    """Compile (or load from numba's cache) the signatures the tracer calls, on empty arrays."""
    f64, f32, i64 = np.float64, np.float32, np.int64
    e3, e = np.zeros((0, 3)), np.zeros(0)
    tab = (np.zeros((1, N_F)), np.zeros((1, 2), i64), np.full((1, 8), -1, i64), np.zeros((1, 8), i64),
           np.zeros((1, 8, 6)), np.zeros((1, 4), np.uint8), np.zeros(1, i64), np.ones(1, i64),
           np.ones(1, i64), np.zeros(1, i64), np.ones(1, i64), np.zeros((1, 6), i64),
           np.zeros((0, 3, 2)), np.zeros((0, 3, 2)), e, e, False, np.zeros((0, 3, 4)), False,
           np.zeros((0, 3, 3)), np.zeros((0, 3, 4)), False, np.zeros((0, 3, 2)), False)
    for t_type in (f32, f64):  # Embree's distances, or float64 after culled back faces
        evaluate(np.zeros(0, np.int32), np.zeros(0, f32), np.zeros(0, f32), np.zeros(0, t_type),
                 e3, e3, np.zeros(3), 0.0, np.zeros((0, 3, 3), f32), np.zeros(0, np.int32), *tab,
                 e3, e3, e, e, e, e3, e, e, e3)
