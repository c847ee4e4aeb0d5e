"""The path tracer's BSDF compiled (numba): evaluation and sampling of path_bsdf's layered
material, one ray per loop iteration, rows spread over the cores (prange).

The per-hit parameters travel as one float64 matrix, a row per hit (path_bsdf.Bsdf.packed,
columns below); `rows` selects which hits a call reads, so the integrator never copies a
subset of the matrix. path_bsdf's numpy Bsdf.eval / Bsdf.sample are the twins these are
tested against (tests/test_path_kernel.py): the same formulas in the same order, so the two
agree to rounding (the isotropic shortcut is taken per row here, per batch there).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# columns of the packed parameters (path_bsdf.Bsdf, in its field order)
N, NG, T, B, WO, BASE = 0, 3, 6, 9, 12, 15
AX, AY, P_METAL, P_PLASTIC = 18, 19, 20, 21
F0_D, F90_D, P_SPEC, MS_M, MS_D = 22, 25, 26, 27, 30
DT, DT_COLOR, IRID, IRID_IOR, IRID_THICK = 33, 34, 37, 38, 39
COAT, COAT_N, COAT_ALPHA, SHEEN, SHEEN_ROUGH = 40, 41, 44, 45, 48
KD_T, W_SHEEN, W_BASE, P_COAT, P_SHEEN, KD_O = 49, 50, 51, 52, 53, 54
WIDTH = 55
SCRATCH = 18          # floats of scratch _eval_row works in (one allocation per chunk of rows)
CHUNKS = 64           # the rows of a call, cut into this many parallel chunks

_PI = math.pi
_SHEEN_MIN = 0.07     # path_bsdf.SHEEN_MIN_ROUGHNESS
_COAT_F0 = 0.04       # path_bsdf.COAT_F0
_ROUGH_ALPHA = 0.1    # path_bsdf.ROUGH_ALPHA
_XYZ = np.array([[3.2404542, -0.9692660, 0.0556434],
                 [-1.5371385, 1.8760108, -0.2040259],
                 [-0.4985314, 0.0415560, 1.0572252]])
_FILM_VAL = np.array([5.4856e-13, 4.4201e-13, 5.2481e-13])
_FILM_POS = np.array([1.6810e+06, 1.7953e+06, 2.2084e+06])
_FILM_VAR = np.array([4.3278e+09, 9.3046e+09, 6.6121e+09])


@njit(cache=True, inline="always")
def _dot(p, i, c, x, y, z):
    return p[i, c] * x + p[i, c + 1] * y + p[i, c + 2] * z


@njit(cache=True, inline="always")
def _ggx_d(x, y, z, ax, ay):
    if z <= 0:
        return 0.0
    k = (x / ax) ** 2 + (y / ay) ** 2 + z * z
    return 1.0 / (_PI * ax * ay * max(k, 1e-30) ** 2)


@njit(cache=True, inline="always")
def _ggx_lambda(x, y, z, ax, ay):
    z2 = max(z * z, 1e-12)
    return 0.5 * (math.sqrt(1.0 + ((ax * x) ** 2 + (ay * y) ** 2) / z2) - 1.0)


@njit(cache=True, inline="always")
def _sheen_l(x, a):
    t = (1.0 - a) ** 2
    ca = 21.5473 + (25.3245 - 21.5473) * t
    cb = 3.82987 + (3.32435 - 3.82987) * t
    cc = 0.19823 + (0.16801 - 0.19823) * t
    cd = -1.97760 + (-1.27393 + 1.97760) * t
    ce = -4.32054 + (-4.85967 + 4.32054) * t
    return ca / (1.0 + cb * max(x, 0.0) ** cc) + cd * x + ce


@njit(cache=True, inline="always")
def _sheen_lambda(c, a):
    if c < 0.5:
        return math.exp(_sheen_l(c, a))
    return math.exp(2.0 * _sheen_l(0.5, a) - _sheen_l(1.0 - c, a))


@njit(cache=True, inline="always")
def _sheen_dv(n_v, n_l, n_h, roughness):
    a = max(roughness, _SHEEN_MIN) ** 2
    sin2 = max(1.0 - n_h * n_h, 0.0)
    d = (2.0 + 1.0 / a) * sin2 ** (0.5 / a) / (2.0 * _PI)
    v = 1.0 / ((1.0 + _sheen_lambda(n_v, a) + _sheen_lambda(n_l, a)) * max(4.0 * n_v * n_l, 1e-6))
    return d * min(max(v, 0.0), 1e4)


@njit(cache=True, error_model="numpy")
def _thin_film(cos1, film_ior, thickness, f0, out, tmp):
    """path_bsdf.thin_film_fresnel for one hit: reflectance into out (3) over base F0 f0 (3);
    tmp: 9 floats of scratch (no allocation per ray)."""
    t = min(max(thickness / 30.0, 0.0), 1.0)
    n2 = 1.0 + (film_ior - 1.0) * t * t * (3 - 2 * t)
    cos2_sq = 1.0 - (1.0 - cos1 * cos1) / (n2 * n2)
    if cos2_sq < 0:
        out[:] = 1.0
        return
    cos2 = math.sqrt(cos2_sq)
    r12 = ((n2 - 1.0) / (n2 + 1.0)) ** 2
    big_r12 = r12 + (1.0 - r12) * (1.0 - cos1) ** 5
    t121 = 1.0 - big_r12
    phi21 = 0.0 if n2 < 1.0 else _PI
    opd = 2.0 * n2 * thickness * cos2
    phi, cm, r123 = tmp[0:3], tmp[3:6], tmp[6:9]
    for c in range(3):
        s = math.sqrt(min(max(f0[c], 0.0), 0.9999))
        n3 = (1.0 + s) / (1.0 - s)
        r23 = ((n3 - n2) / (n3 + n2)) ** 2
        big_r23 = r23 + (1.0 - r23) * (1.0 - cos2) ** 5
        phi[c] = phi21 + (_PI if n3 < n2 else 0.0)
        r123_sq = min(max(big_r12 * big_r23, 1e-5), 0.9999)
        r123[c] = math.sqrt(r123_sq)
        rs = t121 ** 2 * big_r23 / (1.0 - r123_sq)
        out[c] = big_r12 + rs
        cm[c] = rs - t121
    for k in (1, 2):
        phase = 2.0 * _PI * 1e-9 * (k * opd)
        # the film's XYZ sensitivity, component j shifted by channel j's phase (as the raster)
        x0 = _FILM_VAL[0] * math.sqrt(2.0 * _PI * _FILM_VAR[0]) \
            * math.cos(_FILM_POS[0] * phase + k * phi[0]) * math.exp(-phase * phase * _FILM_VAR[0])
        x0 += 9.7470e-14 * math.sqrt(2.0 * _PI * 4.5282e+09) \
            * math.cos(2.2399e+06 * phase + k * phi[0]) * math.exp(-4.5282e+09 * phase * phase)
        x1 = _FILM_VAL[1] * math.sqrt(2.0 * _PI * _FILM_VAR[1]) \
            * math.cos(_FILM_POS[1] * phase + k * phi[1]) * math.exp(-phase * phase * _FILM_VAR[1])
        x2 = _FILM_VAL[2] * math.sqrt(2.0 * _PI * _FILM_VAR[2]) \
            * math.cos(_FILM_POS[2] * phase + k * phi[2]) * math.exp(-phase * phase * _FILM_VAR[2])
        for c in range(3):
            cm[c] = cm[c] * r123[c]
            rgb = (x0 * _XYZ[0, c] + x1 * _XYZ[1, c] + x2 * _XYZ[2, c]) / 1.0685e-7
            out[c] = out[c] + cm[c] * 2.0 * rgb
    for c in range(3):
        out[c] = min(max(out[c], 0.0), 1.0)


@njit(cache=True, inline="always")
def _onb(nx, ny, nz):
    """optics.orthonormal_basis (Duff et al. 2017) for one normal."""
    sign = 1.0 if nz >= 0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return 1.0 + sign * nx * nx * a, sign * b, -sign * nx, b, sign + ny * ny * a, -ny


@njit(cache=True, inline="always")
def _vndf(wx, wy, wz, ax, ay, u1, u2):
    """path_bsdf.ggx_vndf for one local wo: the local visible normal."""
    vx, vy, vz = ax * wx, ay * wy, max(wz, 1e-7)
    ln = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / ln, vy / ln, vz / ln
    lensq = vx * vx + vy * vy
    if lensq > 0:
        inv = 1.0 / math.sqrt(max(lensq, 1e-30))
        t1x, t1y, t1z = -vy * inv, vx * inv, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x, t2y, t2z = vy * t1z - vz * t1y, vz * t1x - vx * t1z, vx * t1y - vy * t1x
    r, phi = math.sqrt(u1), 2.0 * _PI * u2
    p1, p2 = r * math.cos(phi), r * math.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * math.sqrt(max(1.0 - p1 * p1, 0.0)) + s * p2
    q = math.sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0))
    hx, hy, hz = p1 * t1x + p2 * t2x + q * vx, p1 * t1y + p2 * t2y + q * vy, p1 * t1z + p2 * t2z + q * vz
    mx, my, mz = ax * hx, ay * hy, max(hz, 1e-7)
    ln = math.sqrt(mx * mx + my * my + mz * mz)
    return mx / ln, my / ln, mz / ln


@njit(cache=True, error_model="numpy")
def _eval_row(p, i, lx, ly, lz, tmp, out):
    """Bsdf.eval for row i of p and direction (lx, ly, lz): f |cos| into out (3), the pdf
    returned; tmp: SCRATCH floats (a thread's, no allocation per ray)."""
    fm, fd, film, film_tmp = tmp[0:3], tmp[3:6], tmp[6:9], tmp[9:18]
    n_l = _dot(p, i, N, lx, ly, lz)
    n_v = max(_dot(p, i, N, p[i, WO], p[i, WO + 1], p[i, WO + 2]), 1e-6)
    g_l = _dot(p, i, NG, lx, ly, lz)
    up = n_l > 1e-7 and g_l > 0
    down = n_l < -1e-7 and g_l < 0
    cl = max(n_l, 1e-7)
    hx, hy, hz = lx + p[i, WO], ly + p[i, WO + 1], lz + p[i, WO + 2]
    hl = max(math.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
    hx, hy, hz = hx / hl, hy / hl, hz / hl
    v_h = min(max(_dot(p, i, WO, hx, hy, hz), 0.0), 1.0)
    ax, ay = p[i, AX], p[i, AY]
    h_n = _dot(p, i, N, hx, hy, hz)
    if ax == ay:  # isotropic: no frame needed
        d = _ggx_d(math.sqrt(max(1 - h_n * h_n, 0.0)), 0.0, h_n, ax, ay)
        lam_v = _ggx_lambda(math.sqrt(max(1 - n_v * n_v, 0.0)), 0.0, n_v, ax, ay)
        lam_l = _ggx_lambda(math.sqrt(max(1 - cl * cl, 0.0)), 0.0, cl, ax, ay)
    else:
        d = _ggx_d(_dot(p, i, T, hx, hy, hz), _dot(p, i, B, hx, hy, hz), h_n, ax, ay)
        wx, wy, wz = p[i, WO], p[i, WO + 1], p[i, WO + 2]
        lam_v = _ggx_lambda(_dot(p, i, T, wx, wy, wz), _dot(p, i, B, wx, wy, wz),
                            max(_dot(p, i, N, wx, wy, wz), 1e-6), ax, ay)
        lam_l = _ggx_lambda(_dot(p, i, T, lx, ly, lz), _dot(p, i, B, lx, ly, lz), cl, ax, ay)
    spec = d / (1.0 + lam_v + lam_l) / (4 * n_v)
    pdf_ggx = d / (1.0 + lam_v) / (4 * n_v)
    x5 = (1.0 - v_h) ** 5
    f90 = p[i, F90_D]
    for c in range(3):
        fm[c] = p[i, BASE + c] + (1.0 - p[i, BASE + c]) * x5
        fd[c] = p[i, F0_D + c] + (f90 - p[i, F0_D + c]) * x5
    k_ir = p[i, IRID]
    if k_ir > 0:
        _thin_film(v_h, p[i, IRID_IOR], p[i, IRID_THICK], p[i, BASE:BASE + 3], film, film_tmp)
        for c in range(3):
            fm[c] += k_ir * (film[c] - fm[c])
        _thin_film(v_h, p[i, IRID_IOR], p[i, IRID_THICK], p[i, F0_D:F0_D + 3], film, film_tmp)
        for c in range(3):
            fd[c] += k_ir * (film[c] * f90 - fd[c])
    kd = 1.0 - max(fd[0], max(fd[1], fd[2]))
    dt, pm, pp, ps = p[i, DT], p[i, P_METAL], p[i, P_PLASTIC], p[i, P_SPEC]
    p_base = 1.0 - p[i, P_COAT] - p[i, P_SHEEN]
    pdf = 0.0
    for c in range(3):
        out[c] = 0.0
    if up:
        for c in range(3):
            diffuse_r = (1 - dt) * kd * p[i, BASE + c] * (cl / _PI) * p[i, KD_O]
            out[c] = p[i, W_BASE] * (pm * fm[c] * p[i, MS_M + c] * spec
                                     + pp * (diffuse_r + fd[c] * p[i, MS_D + c] * spec))
        pdf = p_base * (pm * pdf_ggx + pp * (ps * pdf_ggx + (1 - ps) * (1 - dt) * cl / _PI))
    elif down and dt > 0 and pp > 0:  # diffuse transmission: thin-walled Lambert behind
        c_t = -n_l
        for c in range(3):
            out[c] = p[i, W_BASE] * pp * dt * p[i, KD_T] * c_t / _PI * p[i, DT_COLOR + c]
        pdf = p_base * pp * (1 - ps) * dt * c_t / _PI
    if up and p[i, P_SHEEN] > 0:
        n_h = min(max(h_n, 0.0), 1.0)
        dv = _sheen_dv(n_v, cl, n_h, p[i, SHEEN_ROUGH])
        for c in range(3):
            out[c] += p[i, W_SHEEN] * dv * cl * p[i, SHEEN + c]
        pdf += p[i, P_SHEEN] / (2 * _PI)
    if p[i, P_COAT] > 0 and g_l > 0:
        c_l = _dot(p, i, COAT_N, lx, ly, lz)
        if c_l > 1e-7:
            a = p[i, COAT_ALPHA]
            c_v = max(_dot(p, i, COAT_N, p[i, WO], p[i, WO + 1], p[i, WO + 2]), 1e-6)
            c_h = min(max(_dot(p, i, COAT_N, hx, hy, hz), 0.0), 1.0)
            dc = _ggx_d(math.sqrt(max(1 - c_h * c_h, 0.0)), 0.0, c_h, a, a)
            lv = _ggx_lambda(math.sqrt(max(1 - c_v * c_v, 0.0)), 0.0, c_v, a, a)
            ll = _ggx_lambda(math.sqrt(max(1 - c_l * c_l, 0.0)), 0.0, c_l, a, a)
            fc = _COAT_F0 + (1 - _COAT_F0) * x5
            f_coat = p[i, COAT] * fc * dc / (1 + lv + ll) / (4 * c_v)
            for c in range(3):
                out[c] += f_coat
            pdf += p[i, P_COAT] * dc / (1 + lv) / (4 * c_v)
    return pdf


@njit(cache=True, parallel=True, error_model="numpy")
def eval_rows(p, rows, wi):
    """(f |cos(n, wi)| (len(rows) x 3), pdf) at hits p[rows] toward wi (len(rows) x 3):
    path_bsdf.Bsdf.eval compiled."""
    m = len(rows)
    fcos = np.empty((m, 3))
    pdf = np.empty(m)
    nch = min(CHUNKS, m)
    for ch in prange(nch):
        tmp = np.empty(SCRATCH)
        for j in range(ch * m // nch, (ch + 1) * m // nch):
            pdf[j] = _eval_row(p, rows[j], wi[j, 0], wi[j, 1], wi[j, 2], tmp, fcos[j])
    return fcos, pdf


@njit(cache=True, error_model="numpy")
def _sample_row(p, i, u_layer, u_pick, u_lobe, u1, u2):
    """Bsdf.sample for row i: (wi x, y, z, from a rough lobe, valid)."""
    wx, wy, wz = p[i, WO], p[i, WO + 1], p[i, WO + 2]
    p_coat, p_sheen = p[i, P_COAT], p[i, P_SHEEN]
    rough, valid = True, True
    if u_layer < p_coat:  # the clearcoat's GGX about its own normal
        ncx, ncy, ncz = p[i, COAT_N], p[i, COAT_N + 1], p[i, COAT_N + 2]
        a = p[i, COAT_ALPHA]
        tx, ty, tz, bx, by, bz = _onb(ncx, ncy, ncz)
        mx, my, mz = _vndf(wx * tx + wy * ty + wz * tz, wx * bx + wy * by + wz * bz,
                           wx * ncx + wy * ncy + wz * ncz, a, a, u1, u2)
        hx = mx * tx + my * bx + mz * ncx
        hy = mx * ty + my * by + mz * ncy
        hz = mx * tz + my * bz + mz * ncz
        k = 2.0 * (wx * hx + wy * hy + wz * hz)
        lx, ly, lz = -wx + k * hx, -wy + k * hy, -wz + k * hz
        rough = a >= _ROUGH_ALPHA
        valid = lx * ncx + ly * ncy + lz * ncz > 0
    elif u_layer < p_coat + p_sheen:  # sheen: uniform over the hemisphere
        z = u1
        r = math.sqrt(max(0.0, 1 - z * z))
        phi = 2 * _PI * u2
        c, s = r * math.cos(phi), r * math.sin(phi)
        lx = c * p[i, T] + s * p[i, B] + z * p[i, N]
        ly = c * p[i, T + 1] + s * p[i, B + 1] + z * p[i, N + 1]
        lz = c * p[i, T + 2] + s * p[i, B + 2] + z * p[i, N + 2]
    elif u_pick < p[i, P_METAL] or u_lobe < p[i, P_SPEC]:  # Metal or Plastic's GGX
        ax, ay = p[i, AX], p[i, AY]
        mx, my, mz = _vndf(_dot(p, i, T, wx, wy, wz), _dot(p, i, B, wx, wy, wz),
                           _dot(p, i, N, wx, wy, wz), ax, ay, u1, u2)
        hx = mx * p[i, T] + my * p[i, B] + mz * p[i, N]
        hy = mx * p[i, T + 1] + my * p[i, B + 1] + mz * p[i, N + 1]
        hz = mx * p[i, T + 2] + my * p[i, B + 2] + mz * p[i, N + 2]
        k = 2.0 * (wx * hx + wy * hy + wz * hz)
        lx, ly, lz = -wx + k * hx, -wy + k * hy, -wz + k * hz
        rough = math.sqrt(ax * ay) >= _ROUGH_ALPHA
        valid = _dot(p, i, N, lx, ly, lz) > 0
    else:  # diffuse: reflected, or with probability dt transmitted (cosine-weighted)
        ps = p[i, P_SPEC]
        u_t = (u_lobe - ps) / max(1 - ps, 1e-12)
        side = -1.0 if u_t < p[i, DT] else 1.0
        nx, ny, nz = p[i, N] * side, p[i, N + 1] * side, p[i, N + 2] * side
        tx, ty, tz, bx, by, bz = _onb(nx, ny, nz)
        r, phi = math.sqrt(u1), 2 * _PI * u2
        z = math.sqrt(max(0.0, 1 - u1))
        c, s = r * math.cos(phi), r * math.sin(phi)
        lx = c * tx + s * bx + z * nx
        ly = c * ty + s * by + z * ny
        lz = c * tz + s * bz + z * nz
    return lx, ly, lz, rough, valid


@njit(cache=True, parallel=True, error_model="numpy")
def sample_rows(p, rows, u_layer, u_pick, u_lobe, u1, u2):
    """Bsdf.sample then Bsdf.eval at its directions, compiled: (wi, rough, valid, f |cos|, pdf)
    for hits p[rows] (the uniforms one per row of `rows`)."""
    m = len(rows)
    wi = np.empty((m, 3))
    fcos = np.empty((m, 3))
    pdf = np.empty(m)
    rough = np.ones(m, np.bool_)
    valid = np.ones(m, np.bool_)
    nch = min(CHUNKS, m)
    for ch in prange(nch):
        tmp = np.empty(SCRATCH)
        for j in range(ch * m // nch, (ch + 1) * m // nch):
            i = rows[j]
            lx, ly, lz, rough[j], valid[j] = _sample_row(p, i, u_layer[j], u_pick[j], u_lobe[j], u1[j], u2[j])
            wi[j, 0], wi[j, 1], wi[j, 2] = lx, ly, lz
            pdf[j] = _eval_row(p, i, lx, ly, lz, tmp, fcos[j])
    return wi, rough, valid, fcos, pdf


@njit(cache=True, inline="always", error_model="numpy")
def _fresnel(cos_i, eta):
    """optics.fresnel_dielectric for one cosine."""
    cos_i = min(max(cos_i, 0.0), 1.0)
    cos2_t = (1.0 - eta * eta) + eta * eta * cos_i * cos_i
    if cos2_t <= 0.0:
        return 1.0
    cos_t = math.sqrt(cos2_t)
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rs2, rp2 = rs * rs, rp * rp
    return 0.5 * ((1.0 if math.isnan(rs2) else rs2) + (1.0 if math.isnan(rp2) else rp2))


@njit(cache=True, inline="always")
def _refract(dx, dy, dz, nx, ny, nz, eta):
    """optics.refract for one ray: (unit direction x, y, z, tir)."""
    cos_i = min(max(-(dx * nx + dy * ny + dz * nz), 0.0), 1.0)
    k = (1.0 - eta * eta) + eta * eta * cos_i * cos_i
    if k < 0.0:
        c = 2.0 * (dx * nx + dy * ny + dz * nz)
        tx, ty, tz = dx - c * nx, dy - c * ny, dz - c * nz
        tir = True
    else:
        c = eta * cos_i - math.sqrt(k)
        tx, ty, tz = eta * dx + c * nx, eta * dy + c * ny, eta * dz + c * nz
        tir = False
    ln = math.sqrt(tx * tx + ty * ty + tz * tz)
    return tx / ln, ty / ln, tz / ln, tir


@njit(cache=True, inline="always")
def _g1(cos_v, alpha):
    c2 = min(max(cos_v * cos_v, 1e-12), 1.0)
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2))


@njit(cache=True, parallel=True, error_model="numpy")
def scatter(p, d, pos, ng, ns, entering, lit, thin, ior, roughness, alpha, base, w, medium,
            u_layer, u_pick, u_lobe, u1, u2, u_rr, roulette, eps, glass_e):
    """path_trace's BSDF-sampling step for every hit of a bounce (row i of p is hit i): a
    reflective component (Bsdf.sample) or Glass (the exact dielectric, smooth or Walter's
    rough, thin-walled sheets crossed; a rough one's children over its albedo from
    `glass_e`, path_bsdf.glass_table, or uncompensated where that is empty), Russian
    roulette when `roulette`, and the next ray's origin off the surface. Returns (origins, directions, throughput, BSDF pdf for MIS, medium
    IOR, alive, rough, tir)."""
    m = len(d)
    o_new = np.empty((m, 3))
    d_new = np.empty((m, 3))
    w_new = np.empty((m, 3))
    pdf_new = np.zeros(m)
    med_new = np.empty(m)
    alive = np.ones(m, np.bool_)
    rough = np.zeros(m, np.bool_)
    tir_out = np.zeros(m, np.bool_)
    nch = min(CHUNKS, m)
    for ch in prange(nch):
        tmp = np.empty(SCRATCH + 3)
        out = tmp[SCRATCH:]
        for i in range(ch * m // nch, (ch + 1) * m // nch):
            dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
            med = medium[i]
            glass = (u_layer[i] >= p[i, P_COAT] + p[i, P_SHEEN]
                     and u_pick[i] >= p[i, P_METAL] + p[i, P_PLASTIC]) or not lit[i]
            if not glass:
                lx, ly, lz, rough[i], valid = _sample_row(p, i, u_layer[i], u_pick[i], u_lobe[i], u1[i], u2[i])
                pdf = _eval_row(p, i, lx, ly, lz, tmp, out)
                ok = pdf > 0 and valid
                for c in range(3):
                    w_new[i, c] = w[i, c] * out[c] / max(pdf, 1e-300) if ok else 0.0
                pdf_new[i] = pdf if ok else 0.0
                alive[i] = ok
            else:
                nx, ny, nz = ns[i, 0], ns[i, 1], ns[i, 2]
                eta = 1.0 / ior[i] if entering[i] else ior[i]
                smooth = roughness[i] <= 0
                g_r, g_t, e_ss = 1.0, 1.0, 1.0
                if smooth:
                    c = 2.0 * (dx * nx + dy * ny + dz * nz)
                    rx, ry, rz = dx - c * nx, dy - c * ny, dz - c * nz
                    tx, ty, tz, tir = _refract(dx, dy, dz, nx, ny, nz, eta)
                    fres = _fresnel(-(dx * nx + dy * ny + dz * nz), eta)
                else:  # a visible microfacet normal (optics.sample_rough_dielectric)
                    a = alpha[i]
                    bx_, by_, bz_, cx_, cy_, cz_ = _onb(nx, ny, nz)
                    vx, vy, vz = -dx, -dy, -dz
                    mx, my, mz = _vndf(vx * bx_ + vy * by_ + vz * bz_, vx * cx_ + vy * cy_ + vz * cz_,
                                       max(vx * nx + vy * ny + vz * nz, 1e-7), a, a, u1[i], u2[i])
                    hx = mx * bx_ + my * cx_ + mz * nx
                    hy = mx * by_ + my * cy_ + mz * ny
                    hz = mx * bz_ + my * cz_ + mz * nz
                    fres = _fresnel(-(dx * hx + dy * hy + dz * hz), eta)
                    c = 2.0 * (dx * hx + dy * hy + dz * hz)
                    rx, ry, rz = dx - c * hx, dy - c * hy, dz - c * hz
                    tx, ty, tz, tir = _refract(dx, dy, dz, hx, hy, hz, eta)
                    cr, ct = rx * nx + ry * ny + rz * nz, tx * nx + ty * ny + tz * nz
                    w_r = fres * _g1(cr, a) if (cr > 0 and rx * hx + ry * hy + rz * hz > 0) else 0.0
                    w_t = (1.0 - fres) * _g1(-ct, a) if (ct < 0 and not tir) else 0.0
                    g_r = w_r / max(fres, 1e-30)
                    g_t = w_t / max(1 - fres, 1e-30)
                    e_ss = glass_albedo(glass_e, vx * nx + vy * ny + vz * nz, a, eta)
                if thin[i]:  # out through the sheet's parallel back face: unbent where smooth
                    tx, ty, tz, tir2 = _refract(tx, ty, tz, nx, ny, nz, ior[i])
                    if smooth:
                        tx, ty, tz = dx, dy, dz
                    tir = tir or tir2
                if tir:
                    fres = 1.0
                take_r = u_lobe[i] < fres
                factor = g_r if take_r else g_t * (1.0 if thin[i] else eta * eta)
                if lit[i]:  # what the coat and sheen over it leave, over the choice's odds
                    factor *= p[i, W_BASE] / max(1.0 - p[i, P_COAT] - p[i, P_SHEEN], 1e-12)
                # a refraction takes sqrt(base) at each crossing of a volume (Cycles'
                # convention: c overall for one colour), base once through a thin sheet; what
                # bounced between the microfacets comes back too (path_bsdf.glass_ms)
                for c in range(3):
                    cross = base[i, c] if thin[i] else math.sqrt(max(base[i, c], 0.0))
                    tint = 1.0 if take_r else cross
                    w_new[i, c] = w[i, c] * tint * factor / (1.0 - (1.0 - e_ss) * cross)
                if take_r:
                    lx, ly, lz = rx, ry, rz
                else:
                    lx, ly, lz = tx, ty, tz
                if not (take_r or thin[i]):
                    med = ior[i] if entering[i] else 1.0
                rough[i] = not smooth and alpha[i] >= _ROUGH_ALPHA
                tir_out[i] = tir
            if roulette:
                q = min(max(max(w_new[i, 0], max(w_new[i, 1], w_new[i, 2])) * med * med, 0.0), 1.0)
                if not u_rr[i] < q:
                    alive[i] = False
                for c in range(3):
                    w_new[i, c] = w_new[i, c] / max(q, 1e-30)
            if not max(w_new[i, 0], max(w_new[i, 1], w_new[i, 2])) > 0:
                alive[i] = False
            off = eps if lx * ng[i, 0] + ly * ng[i, 1] + lz * ng[i, 2] > 0 else -eps
            for c in range(3):
                o_new[i, c] = pos[i, c] + off * ng[i, c]
            d_new[i, 0], d_new[i, 1], d_new[i, 2] = lx, ly, lz
            med_new[i] = med
    return o_new, d_new, w_new, pdf_new, med_new, alive, rough, tir_out


_ALPHA_MIN = 1e-3     # path_bsdf.ALPHA_MIN


@njit(cache=True, inline="always")
def _bilinear(t, x, x_lo, y, y_lo):
    """path_bsdf._bilinear at one point."""
    n = t.shape[0]
    x = min(max((x - x_lo) / (1 - x_lo) * (n - 1), 0.0), n - 1.0)
    y = min(max((y - y_lo) / (1 - y_lo) * (n - 1), 0.0), n - 1.0)
    x0, y0 = min(int(x), n - 2), min(int(y), n - 2)
    fx, fy = x - x0, y - y0
    return ((t[x0, y0] * (1 - fx) + t[x0 + 1, y0] * fx) * (1 - fy)
            + (t[x0, y0 + 1] * (1 - fx) + t[x0 + 1, y0 + 1] * fx) * fy)


@njit(cache=True)
def _aniso_albedo(table, cos_v, azimuth, ax, ay):
    """path_bsdf.ggx_albedo_aniso at one point (multilinear over the 4-D table)."""
    sizes = table.shape
    sa = math.sqrt(_ALPHA_MIN)
    c = (min(max((cos_v - 0.02) / 0.98, 0.0), 1.0) * (sizes[0] - 1),
         min(max(azimuth / (_PI / 2), 0.0), 1.0) * (sizes[1] - 1),
         min(max((math.sqrt(ax) - sa) / (1 - sa), 0.0), 1.0) * (sizes[2] - 1),
         min(max((math.sqrt(ay) - sa) / (1 - sa), 0.0), 1.0) * (sizes[3] - 1))
    lo = (min(int(c[0]), sizes[0] - 2), min(int(c[1]), sizes[1] - 2),
          min(int(c[2]), sizes[2] - 2), min(int(c[3]), sizes[3] - 2))
    fr = (c[0] - lo[0], c[1] - lo[1], c[2] - lo[2], c[3] - lo[3])
    out = 0.0
    for corner in range(16):
        b0, b1, b2, b3 = corner & 1, (corner >> 1) & 1, (corner >> 2) & 1, (corner >> 3) & 1
        wgt = (fr[0] if b0 else 1 - fr[0]) * (fr[1] if b1 else 1 - fr[1]) \
            * (fr[2] if b2 else 1 - fr[2]) * (fr[3] if b3 else 1 - fr[3])
        out += wgt * table[lo[0] + b0, lo[1] + b1, lo[2] + b2, lo[3] + b3]
    return out


_GLASS_Z_MAX = 0.8     # path_bsdf.GLASS_Z_MAX
_GLASS_E_MIN = 0.05    # path_bsdf.GLASS_E_MIN


@njit(cache=True)
def glass_albedo(table, cos_v, alpha, eta):
    """path_bsdf.glass_albedo at one point (trilinear in the side's 3-D table), floored at
    path_bsdf.GLASS_E_MIN; 1 where `table` is empty (no multiple-scattering compensation)."""
    if table.shape[0] == 0:
        return 1.0
    inside = eta > 1.0
    ior = eta if inside else 1.0 / max(eta, 1e-12)
    z = math.sqrt(max(ior - 1.0, 0.0) / (ior + 1.0))
    t = table[1 if inside else 0]
    sizes = t.shape
    c = (min(max(z / _GLASS_Z_MAX, 0.0), 1.0) * (sizes[0] - 1),
         min(max((cos_v - 0.02) / 0.98, 0.0), 1.0) * (sizes[1] - 1),
         min(max((alpha - _ALPHA_MIN) / (1 - _ALPHA_MIN), 0.0), 1.0) * (sizes[2] - 1))
    lo = (min(int(c[0]), sizes[0] - 2), min(int(c[1]), sizes[1] - 2), min(int(c[2]), sizes[2] - 2))
    fr = (c[0] - lo[0], c[1] - lo[1], c[2] - lo[2])
    out = 0.0
    for corner in range(8):
        b0, b1, b2 = corner & 1, (corner >> 1) & 1, (corner >> 2) & 1
        wgt = (fr[0] if b0 else 1 - fr[0]) * (fr[1] if b1 else 1 - fr[1]) * (fr[2] if b2 else 1 - fr[2])
        out += wgt * t[lo[0] + b0, lo[1] + b1, lo[2] + b2]
    return max(out, _GLASS_E_MIN)


@njit(cache=True, inline="always")
def _ms_scale(f0, e_ss):
    e_ms = 1.0 - e_ss
    f_avg = f0 + (1.0 - f0) / 21.0
    return 1.0 + e_ms * f_avg / (1.0 - e_ms * f_avg)


@njit(cache=True, parallel=True, error_model="numpy")
def build_rows(ns, ng, wo, ior, base, metallic, transmission, roughness, anisotropy, grain,
               specular, specular_color, diffuse_t, diffuse_t_color, irid, irid_ior, irid_thick,
               clearcoat, clearcoat_normal, clearcoat_roughness, sheen_color, sheen_roughness,
               opacity, multiscatter, ggx_e, ggx_b, aniso_e, sheen_e):
    """path_bsdf.build compiled, straight to the packed matrix (Bsdf.packed's columns)."""
    m = len(ns)
    p = np.empty((m, WIDTH))
    for i in prange(m):
        nx, ny, nz = ns[i, 0], ns[i, 1], ns[i, 2]
        for c in range(3):
            p[i, N + c] = ns[i, c]
            p[i, NG + c] = ng[i, c]
            p[i, WO + c] = wo[i, c]
            p[i, BASE + c] = base[i, c]
            p[i, DT_COLOR + c] = diffuse_t_color[i, c]
            p[i, SHEEN + c] = sheen_color[i, c]
        alpha = max(roughness[i] ** 2, _ALPHA_MIN)
        an = min(max(anisotropy[i], 0.0), 1.0)
        ax = alpha + (1.0 - alpha) * an * an
        tx, ty, tz, bx, by, bz = _onb(nx, ny, nz)
        gd = grain[i, 0] * nx + grain[i, 1] * ny + grain[i, 2] * nz
        gx, gy, gz = grain[i, 0] - nx * gd, grain[i, 1] - ny * gd, grain[i, 2] - nz * gd
        ln = math.sqrt(gx * gx + gy * gy + gz * gz)
        if ln > 1e-6:  # the grain projected onto the shading plane
            tx, ty, tz = gx / ln, gy / ln, gz / ln
            bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
        p[i, T], p[i, T + 1], p[i, T + 2] = tx, ty, tz
        p[i, B], p[i, B + 1], p[i, B + 2] = bx, by, bz
        p[i, AX], p[i, AY] = ax, alpha
        metal, trans = metallic[i], transmission[i]
        p[i, P_METAL], p[i, P_PLASTIC] = metal, (1 - metal) * (1 - trans)
        f0_ior = ((ior[i] - 1) / (ior[i] + 1)) ** 2
        f90 = specular[i]
        n_v = min(max(nx * wo[i, 0] + ny * wo[i, 1] + nz * wo[i, 2], 1e-6), 1.0)
        x5 = (1.0 - n_v) ** 5
        top = 0.0
        for c in range(3):
            f0 = min(f0_ior * specular_color[i, c], 1.0) * f90
            p[i, F0_D + c] = f0
            top = max(top, f0 + (f90 - f0) * x5)
        p[i, F90_D] = f90
        p[i, P_SPEC] = min(max(top, 0.1), 0.9)
        if multiscatter:  # energy lost between microfacets, put back (Turquin 2019)
            if ax > alpha:
                wx, wy, wz = wo[i, 0], wo[i, 1], wo[i, 2]
                az = math.atan2(abs(wx * bx + wy * by + wz * bz), abs(wx * tx + wy * ty + wz * tz))
                e = _aniso_albedo(aniso_e, n_v, az, ax, alpha)
            else:
                e = _bilinear(ggx_e, n_v, 0.02, alpha, _ALPHA_MIN)
            e_ss = min(max(e, 0.05), 1.0)
            for c in range(3):
                p[i, MS_M + c] = _ms_scale(base[i, c], e_ss)
                p[i, MS_D + c] = _ms_scale(p[i, F0_D + c], e_ss)
        else:
            for c in range(3):
                p[i, MS_M + c] = 1.0
                p[i, MS_D + c] = 1.0
        dt = min(max(diffuse_t[i], 0.0), 1.0)
        p[i, DT] = dt
        kd_t = 1.0
        if dt > 0:  # the GGX lobe's directional albedo E_spec = f0 (E - B) + f90 B, x its ms scale
            e_f1 = _bilinear(ggx_e, n_v, 0.02, alpha, _ALPHA_MIN)
            e_b = _bilinear(ggx_b, n_v, 0.02, alpha, _ALPHA_MIN)
            top = 0.0
            for c in range(3):
                e_spec = p[i, F0_D + c] * (e_f1 - e_b) + f90 * e_b
                if multiscatter:
                    e_spec *= p[i, MS_D + c]
                top = max(top, e_spec)
            kd_t = min(max(1.0 - top, 0.0), 1.0)
        p[i, KD_T] = kd_t
        p[i, IRID], p[i, IRID_IOR], p[i, IRID_THICK] = irid[i], irid_ior[i], irid_thick[i]
        coat = min(max(clearcoat[i], 0.0), 1.0)
        cx, cy, cz = clearcoat_normal[i, 0], clearcoat_normal[i, 1], clearcoat_normal[i, 2]
        if cx * ng[i, 0] + cy * ng[i, 1] + cz * ng[i, 2] < 0:
            cx, cy, cz = -cx, -cy, -cz
        if cx * wo[i, 0] + cy * wo[i, 1] + cz * wo[i, 2] <= 0:
            cx, cy, cz = ng[i, 0], ng[i, 1], ng[i, 2]
        p[i, COAT_N], p[i, COAT_N + 1], p[i, COAT_N + 2] = cx, cy, cz
        c_v = min(max(cx * wo[i, 0] + cy * wo[i, 1] + cz * wo[i, 2], 0.0), 1.0)
        fc_v = _COAT_F0 + (1 - _COAT_F0) * (1 - c_v) ** 5
        w_sheen = 1.0 - coat * fc_v
        peak = max(sheen_color[i, 0], max(sheen_color[i, 1], sheen_color[i, 2]))
        e_sheen = 0.0
        if peak > 0:  # the Charlie lobe's albedo passes 1 at grazing: the base never goes negative
            e_sheen = min(_bilinear(sheen_e, n_v, 0.02, sheen_roughness[i], 0.0), 1.0)
        p[i, COAT] = coat
        p[i, COAT_ALPHA] = max(clearcoat_roughness[i] ** 2, _ALPHA_MIN)
        p[i, SHEEN_ROUGH] = sheen_roughness[i]
        p[i, W_SHEEN] = w_sheen
        p[i, W_BASE] = w_sheen * (1.0 - peak * e_sheen)
        p[i, KD_O] = opacity[i]
        p_coat = min(max(coat * max(fc_v, 0.1), 0.0), 0.9) if coat > 0 else 0.0
        p[i, P_COAT] = p_coat
        p[i, P_SHEEN] = (1 - p_coat) * min(max(peak * max(e_sheen, 0.1), 0.0), 0.9) if peak > 0 else 0.0
    return p


@njit(cache=True, inline="always")
def _texel_pdf(p_texel, n, x, y, z, s_axis, s_sign, t_axis, t_sign):
    ax, ay, az = abs(x), abs(y), abs(z)
    major = 0  # np.argmax: the first of equal maxima
    if ay > ax and ay >= az:
        major = 1
    elif az > ax and az > ay:
        major = 2
    m = x if major == 0 else (y if major == 1 else z)
    face = major * 2 + (1 if m < 0 else 0)
    ma = abs(m)
    d = (x, y, z)
    s = (s_sign[face] * d[s_axis[face]] / ma + 1) / 2
    t = (t_sign[face] * d[t_axis[face]] / ma + 1) / 2
    ix = min(max(int(s * n), 0), n - 1)
    iy = min(max(int(t * n), 0), n - 1)
    sc, tc = s * 2 - 1, t * 2 - 1
    return p_texel[(face * n + iy) * n + ix] * n * n / 4.0 * (1 + sc * sc + tc * tc) ** 1.5


@njit(cache=True, parallel=True)
def env_pdf(p_texel, n, d, to_env, uniform, s_axis, s_sign, t_axis, t_sign):
    """path_trace.EnvSampler.pdf compiled: world directions d, to_env the world-to-environment
    rotation (rows: d_env = to_env @ d), `uniform` the share drawn over the sphere."""
    m = len(d)
    out = np.empty(m)
    for i in prange(m):
        x = to_env[0, 0] * d[i, 0] + to_env[0, 1] * d[i, 1] + to_env[0, 2] * d[i, 2]
        y = to_env[1, 0] * d[i, 0] + to_env[1, 1] * d[i, 1] + to_env[1, 2] * d[i, 2]
        z = to_env[2, 0] * d[i, 0] + to_env[2, 1] * d[i, 1] + to_env[2, 2] * d[i, 2]
        out[i] = (1 - uniform) * _texel_pdf(p_texel, n, x, y, z, s_axis, s_sign, t_axis, t_sign) \
            + uniform / (4 * _PI)
    return out


@njit(cache=True, parallel=True)
def env_sample(cdf, p_texel, n, u1, u2, u3, to_env, uniform, s_axis, s_sign, t_axis, t_sign):
    """path_trace.EnvSampler.sample compiled: world directions (d_world = d_env @ to_env)."""
    m = len(u1)
    out = np.empty((m, 3))
    last = len(cdf) - 1
    for i in prange(m):
        if u3[i] < uniform:  # uniform on the sphere from (u1, u2)
            z = 1 - 2 * u1[i]
            r = math.sqrt(max(0.0, 1 - z * z))
            phi = 2 * _PI * u2[i]
            e0, e1, e2 = r * math.cos(phi), r * math.sin(phi), z
        else:
            lo_i, hi_i = 0, len(cdf)  # searchsorted(cdf, u1, side="right")
            while lo_i < hi_i:
                mid = (lo_i + hi_i) // 2
                if cdf[mid] <= u1[i]:
                    lo_i = mid + 1
                else:
                    hi_i = mid
            idx = min(lo_i, last)
            face, rest = idx // (n * n), idx % (n * n)
            y, x = rest // n, rest % n
            lo = cdf[idx - 1] if idx > 0 else 0.0
            fx = min(max((u1[i] - lo) / max(p_texel[idx], 1e-300), 0.0), 1.0 - 1e-9)
            sc = (x + fx) / n * 2 - 1
            tc = (y + u2[i]) / n * 2 - 1
            v = np.zeros(3)
            v[face // 2] = 1.0 if face % 2 == 0 else -1.0
            v[s_axis[face]] = s_sign[face] * sc
            v[t_axis[face]] = t_sign[face] * tc
            ln = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
            e0, e1, e2 = v[0] / ln, v[1] / ln, v[2] / ln
        for k in range(3):
            out[i, k] = e0 * to_env[0, k] + e1 * to_env[1, k] + e2 * to_env[2, k]
    return out


def warm() -> None:
    """Compile (or load from numba's cache) both kernels on empty arrays."""
    p, rows, e = np.zeros((0, WIDTH)), np.zeros(0, np.int64), np.zeros(0)
    eval_rows(p, rows, np.zeros((0, 3)))
    sample_rows(p, rows, e, e, e, e, e)
    e3, b = np.zeros((0, 3)), np.zeros(0, np.bool_)
    t2, t4 = np.zeros((2, 2)), np.zeros((2, 2, 2, 2))
    build_rows(e3, e3, e3, e, e3, e, e, e, e, e3, e, e3, e, e3, e, e, e, e, e3, e, e3, e, e, True, t2, t2, t4, t2)
    scatter(p, e3, e3, e3, e3, b, b, b, e, e, e, e3, e3, e, e, e, e, e, e, e, True, 1e-4, np.zeros((0, 1, 1, 1)))
    i64, eye = np.zeros(6, np.int64), np.eye(3)
    env_pdf(np.ones(6), 1, np.zeros((0, 3)), eye, 0.1, i64, e, i64, e)
    env_sample(np.ones(6), np.ones(6), 1, e, e, e, eye, 0.1, i64, e, i64, e)
