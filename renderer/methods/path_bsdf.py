"""The path tracer's BSDF: glTF's layered material (the lobes of core/lobes.py) as a mixture
that renderer.methods.path_trace samples and evaluates at every surface.

Layering as the glTF specification mixes it (and the raster's shaders/lobes.glsl composes it,
view-dependent albedo scaling included):

    f = c Coat + (1 - c F_coat(n_c.v)) [Sheen + (1 - max(sheen) E_sheen(n.v)) Base]
    Base = m Metal + (1 - m)(1 - tr) Plastic + (1 - m) tr Glass

- Coat (KHR_materials_clearcoat): isotropic GGX at F0 = 0.04 about its own normal (the
  clearcoat normal map, else the interpolated normal), roughness clearcoat_roughness.
- Sheen (KHR_materials_sheen): Charlie D with Estevez & Kulla's visibility (shaders/brdf.glsl,
  same roughness floor); E_sheen is its directional albedo, tabulated here by quadrature of
  this very lobe, so a white sheen over a white base returns 1.
- Metal: GGX at F0 = base colour (Schlick), the Metal and Plastic GGX lobes anisotropic with
  KHR_materials_anisotropy (alpha_t = mix(alpha, 1, strength^2) along the grain, alpha_b =
  alpha, as the raster), sampled from the anisotropic visible normals (Heitz 2018).
- Plastic: fresnel_mix with KHR_materials_specular: F = w (f0 + (1 - f0)(1 - v.h)^5), f0 =
  min(f0_ior x specular colour, 1), w the specular factor; the diffuse under it is scaled by
  1 - max(F); KHR_materials_diffuse_transmission sends the factor's share of that diffuse to
  the other side (thin-walled Lambert, tinted, scaled by 1 - max(F(n.v))).
- KHR_materials_iridescence: the thin-film Fresnel of the raster (shaders/iridescence.glsl,
  Belcour & Barla 2017) at v.h replaces Schlick's by the iridescence factor, for Metal (over
  F0 = base colour) and Plastic (over the dielectric F0).
- Glass is the exact dielectric the integrator samples itself (its weight here: `glass_w`).

Sampling picks Coat, Sheen (uniform hemisphere: the Charlie lobe peaks at grazing) or Base by
probabilities from their view albedos, then a Base component as path_trace always did; the pdf
of a direction is the sum over every reflective component of its choice probability times its
pdf (one-sample MIS with the balance heuristic), so f / pdf is unbiased whichever was drawn.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from renderer.methods.optics import orthonormal_basis, reflect, sample_rough_dielectric

ALPHA_MIN = 1e-3      # GGX alpha floor: a smooth lobe stays finite (1e-6 of D's peak width)
SHEEN_MIN_ROUGHNESS = 0.07  # shaders/brdf.glsl's floor of the Charlie distribution
COAT_F0 = 0.04        # the clearcoat's IOR 1.5
_TABLE_N = 32


def dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def schlick(f0, cos, f90=1.0):
    """Schlick's Fresnel, rows of f0 (N x C) at cosines `cos` (N), grazing value f90 (N or 1)."""
    x = (1.0 - np.clip(cos, 0.0, 1.0)) ** 5
    f90 = np.asarray(f90, np.float64)
    if f90.ndim:
        f90 = f90[:, None]
    return f0 + (f90 - f0) * x[:, None]


# --- GGX (anisotropic in the frame t, b, n; isotropic where ax = ay) ------------------------

def ggx_d(x, y, z, ax, ay):
    """D of GGX for half vectors with local coordinates (x, y, z)."""
    k = (x / ax) ** 2 + (y / ay) ** 2 + z * z
    return np.where(z > 0, 1.0 / (math.pi * ax * ay * np.maximum(k, 1e-30) ** 2), 0.0)


def ggx_lambda(x, y, z, ax, ay):
    z2 = np.maximum(z * z, 1e-12)
    return 0.5 * (np.sqrt(1.0 + ((ax * x) ** 2 + (ay * y) ** 2) / z2) - 1.0)


def ggx_vndf(wo_l: np.ndarray, ax, ay, u1, u2) -> np.ndarray:
    """A visible normal (local coordinates, N x 3) seen from local wo (Heitz 2018)."""
    vh = np.stack([ax * wo_l[:, 0], ay * wo_l[:, 1], np.maximum(wo_l[:, 2], 1e-7)], -1)
    vh /= np.linalg.norm(vh, axis=-1, keepdims=True)
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = 1.0 / np.sqrt(np.maximum(lensq, 1e-30))
    t1 = np.where((lensq > 0)[:, None], np.stack([-vh[:, 1] * inv, vh[:, 0] * inv, np.zeros_like(lensq)], -1),
                  np.array([1.0, 0.0, 0.0]))
    t2 = np.cross(vh, t1)
    r, phi = np.sqrt(u1), 2.0 * math.pi * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    nh = p1[:, None] * t1 + p2[:, None] * t2 + np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))[:, None] * vh
    m = np.stack([ax * nh[:, 0], ay * nh[:, 1], np.maximum(nh[:, 2], 1e-7)], -1)
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


# --- sheen (Charlie, Estevez & Kulla 2017, as shaders/brdf.glsl) ------------------------------

def _sheen_l(x, a):
    t = (1.0 - a) ** 2
    ca = 21.5473 + (25.3245 - 21.5473) * t
    cb = 3.82987 + (3.32435 - 3.82987) * t
    cc = 0.19823 + (0.16801 - 0.19823) * t
    cd = -1.97760 + (-1.27393 + 1.97760) * t
    ce = -4.32054 + (-4.85967 + 4.32054) * t
    return ca / (1.0 + cb * np.power(np.maximum(x, 0.0), cc)) + cd * x + ce


def _sheen_lambda(c, a):
    return np.where(c < 0.5, np.exp(_sheen_l(c, a)), np.exp(2.0 * _sheen_l(0.5, a) - _sheen_l(1.0 - c, a)))


def sheen_dv(n_v, n_l, n_h, roughness):
    """D V of the sheen lobe (already over 4 n.l n.v), white."""
    a = np.maximum(roughness, SHEEN_MIN_ROUGHNESS) ** 2
    sin2 = np.maximum(1.0 - n_h * n_h, 0.0)
    d = (2.0 + 1.0 / a) * np.power(sin2, 0.5 / a) / (2.0 * math.pi)
    v = 1.0 / ((1.0 + _sheen_lambda(n_v, a) + _sheen_lambda(n_l, a)) * np.maximum(4.0 * n_v * n_l, 1e-6))
    return d * np.clip(v, 0.0, 1e4)


# The BSDF's directional albedos, tabulated by quadrature of the very lobes this module
# samples (_sheen_table, _ggx_tables, _aniso_table: ~25 s of numpy together), stored in
# path_bsdf_tables.npz beside this file (`python -m renderer.methods.path_bsdf` rewrites it;
# tests/test_raytrace_lobes.py checks cells against fresh quadrature) and loaded on first use.
TABLES = Path(__file__).with_name("path_bsdf_tables.npz")
_TABLES: dict[str, np.ndarray] = {}


def _table(name: str) -> np.ndarray:
    if not _TABLES:
        if TABLES.is_file():
            with np.load(TABLES) as z:
                _TABLES.update({k: z[k].astype(np.float64) for k in z.files})
        else:  # a checkout without the file: build (and keep) them in this process
            _TABLES.update(build_tables())
    return _TABLES[name]


def build_tables() -> dict[str, np.ndarray]:
    ggx_e, ggx_b = _ggx_tables()
    return {"ggx_e": ggx_e, "ggx_b": ggx_b, "aniso_e": _aniso_table(), "sheen_e": _sheen_table(),
            "glass_e": _glass_table()}


def sheen_albedo(cos_v, roughness):
    """E_sheen(n.v, roughness) of a white sheen lobe, bilinear in a 32 x 32 table (_sheen_table)."""
    return _bilinear(_table("sheen_e"), cos_v, 0.02, roughness, 0.0)


def _sheen_table() -> np.ndarray:
    """E_sheen by stratified quadrature over the hemisphere (48 x 48 points, denser toward
    grazing where the Charlie lobe lives), 32 x 32 over (n.v, roughness)."""
    k = 48
    g = (np.arange(k) + 0.5) / k
    # cos(theta_i) = 1 - (1 - g)^2... as g^2 puts half the points below cos 0.25
    q, ph = (a.reshape(-1) for a in np.meshgrid(g, g * 2 * math.pi, indexing="ij"))
    ct, jac = q * q, 2 * q                     # d cos = 2 q dq
    st = np.sqrt(1 - ct * ct)
    wi = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)
    rough = np.linspace(0.0, 1.0, _TABLE_N)
    table = np.zeros((_TABLE_N, _TABLE_N))
    for i, mu in enumerate(np.linspace(0.02, 1.0, _TABLE_N)):
        h = wi + np.array([math.sqrt(1 - mu * mu), 0.0, mu])
        n_h = h[:, 2] / np.linalg.norm(h, axis=-1)
        m = len(ct)
        f = sheen_dv(np.full(m * _TABLE_N, mu), np.tile(ct, _TABLE_N), np.tile(n_h, _TABLE_N),
                     np.repeat(rough, m)) * np.tile(ct * jac, _TABLE_N)
        table[i] = 2 * math.pi * f.reshape(_TABLE_N, m).mean(axis=1)
    return table


def _bilinear(t, x, x_lo, y, y_lo):
    n = t.shape[0]
    x = np.clip((np.asarray(x) - x_lo) / (1 - x_lo) * (n - 1), 0, n - 1)
    y = np.clip((np.asarray(y) - y_lo) / (1 - y_lo) * (n - 1), 0, n - 1)
    x0, y0 = np.minimum(x.astype(int), n - 2), np.minimum(y.astype(int), n - 2)
    fx, fy = x - x0, y - y0
    return ((t[x0, y0] * (1 - fx) + t[x0 + 1, y0] * fx) * (1 - fy)
            + (t[x0, y0 + 1] * (1 - fx) + t[x0 + 1, y0 + 1] * fx) * fy)


def ggx_albedo(cos_v, alpha):
    """Single-scattering albedo E_ss of the GGX lobe at F = 1 (height-correlated G2), bilinear
    in a 32 x 32 table over (cos_v, alpha) (_ggx_tables): the same lobe the paths sample, so
    that the multiple-scattering scale 1 / E_ss makes a white lobe lossless at wo."""
    return _bilinear(_table("ggx_e"), cos_v, 0.02, alpha, ALPHA_MIN)


def _ggx_tables() -> tuple[np.ndarray, np.ndarray]:
    """E and B (ggx_schlick_share) by stratified VNDF quadrature (E = mean of G2 / G1)."""
    k = 32
    g = (np.arange(k) + 0.5) / k
    u1, u2 = (np.tile(a.reshape(-1), _TABLE_N) for a in np.meshgrid(g, g, indexing="ij"))
    a = np.repeat(np.linspace(ALPHA_MIN, 1.0, _TABLE_N), k * k)
    table = np.zeros((_TABLE_N, _TABLE_N))
    share = np.zeros((_TABLE_N, _TABLE_N))
    for i, mu in enumerate(np.linspace(0.02, 1.0, _TABLE_N)):
        wo = np.tile([math.sqrt(1 - mu * mu), 0.0, mu], (len(a), 1))
        wi = reflect(-wo, ggx_vndf(wo, a, a, u1, u2))
        lv = ggx_lambda(wo[:, 0], wo[:, 1], wo[:, 2], a, a)
        ll = ggx_lambda(wi[:, 0], wi[:, 1], np.maximum(wi[:, 2], 1e-7), a, a)
        ratio = np.where(wi[:, 2] > 0, (1 + lv) / (1 + lv + ll), 0.0)
        table[i] = ratio.reshape(_TABLE_N, k * k).mean(axis=1)
        v_h = np.clip(np.einsum("ij,ij->i", wo, (wo + wi) / np.linalg.norm(wo + wi, axis=-1, keepdims=True)), 0, 1)
        share[i] = (ratio * (1 - v_h) ** 5).reshape(_TABLE_N, k * k).mean(axis=1)
    return table, share


def ggx_schlick_share(cos_v, alpha):
    """B of the split sum: the GGX lobe's albedo weighted by Schlick's (1 - v.h)^5, so that
    E_spec = f0 (E - B) + f90 B (tabulated with ggx_albedo)."""
    return _bilinear(_table("ggx_b"), cos_v, 0.02, alpha, ALPHA_MIN)


# Rough glass: the single-scattering albedo R + T of the rough dielectric both tracers sample
# (optics.sample_rough_dielectric: F G1 reflected, (1 - F) G1 refracted about a visible
# normal), from outside (eta = 1 / ior) and from inside (eta = ior). With `multiscatter` both
# children take glass_ms(E, tint), 1 / E for white glass, so a white interface loses nothing
# between its microfacets: light a facet sends into its neighbours leaves in the end, as in
# Cycles' multiscatter GGX glass. Single scattering alone dims a rough pane by a factor of
# 2-4 at roughness 1 (several rough crossings and internal bounces).
_GLASS = (2, 16, 32, 32)  # side (outside, inside), z = sqrt((ior - 1) / (ior + 1)), n.v, alpha
GLASS_Z_MAX = 0.8         # z's last row: IOR 4.56 (beyond it, that row)
GLASS_E_MIN = 0.05        # E's floor: 1 / E stays bounded at grazing


def glass_albedo(cos_v, alpha, eta):
    """E_ss = R + T of the rough dielectric at incidence cosine cos_v (to the normal on the
    incident side), GGX alpha and eta = n_incident / n_transmitted, trilinear in _glass_table,
    at least GLASS_E_MIN."""
    table = _table("glass_e")
    eta = np.asarray(eta, np.float64)
    inside = eta > 1.0
    ior = np.where(inside, eta, 1.0 / np.maximum(eta, 1e-12))
    z = np.sqrt(np.maximum(ior - 1.0, 0.0) / (ior + 1.0))
    _, n_z, n_mu, n_a = _GLASS
    coords = [np.clip(z / GLASS_Z_MAX, 0, 1) * (n_z - 1),
              np.clip((np.asarray(cos_v, np.float64) - 0.02) / 0.98, 0, 1) * (n_mu - 1),
              np.clip((np.asarray(alpha, np.float64) - ALPHA_MIN) / (1 - ALPHA_MIN), 0, 1) * (n_a - 1)]
    coords = [np.broadcast_to(c, np.broadcast_shapes(*(c.shape for c in coords))) for c in coords]
    lo = [np.minimum(c.astype(int), size - 2) for c, size in zip(coords, _GLASS[1:])]
    fr = [c - c0 for c, c0 in zip(coords, lo)]
    side = np.broadcast_to(inside, coords[0].shape).astype(int)
    out = np.zeros(coords[0].shape)
    for corner in range(8):
        idx, wgt = [side], np.ones(coords[0].shape)
        for axis in range(3):
            bit = (corner >> axis) & 1
            idx.append(lo[axis] + bit)
            wgt = wgt * (fr[axis] if bit else 1 - fr[axis])
        out += wgt * table[tuple(idx)]
    return np.maximum(out, GLASS_E_MIN)


def glass_ms(e_ss, tint):
    """The multiple-scattering scale of a rough glass lobe (both children) of albedo e_ss
    whose crossing tints by `tint`: 1 / (1 - (1 - E) tint), the sum over the bounces between
    facets, each of which loses 1 - E of what is left and crosses (Kulla & Conty 2017 with the
    tint for the Fresnel average, as Cycles' and Eevee's multiscatter glass): 1 / E for white
    glass, so nothing is lost; a tinted pane keeps less of its red than of its blue."""
    return 1.0 / (1.0 - (1.0 - np.asarray(e_ss)) * np.asarray(tint))


def glass_table() -> np.ndarray:
    """The 2 x 16 x 32 x 32 table glass_albedo reads (for the compiled kernels:
    path_kernel.glass_albedo)."""
    return _table("glass_e")


def _glass_table() -> np.ndarray:
    """E_ss per cell by 32 x 32 stratified visible-normal quadrature of the tracers' own
    weights (TIR on a facet reflects all of it)."""
    k = 32
    g = (np.arange(k) + 0.5) / k
    u1, u2 = (a.reshape(-1) for a in np.meshgrid(g, g, indexing="ij"))
    _, n_z, n_mu, n_a = _GLASS
    alphas = np.linspace(ALPHA_MIN, 1.0, n_a)
    a = np.repeat(alphas, k * k)
    uu1, uu2 = np.tile(u1, n_a), np.tile(u2, n_a)
    n = np.tile([0.0, 0.0, 1.0], (len(a), 1))
    table = np.zeros(_GLASS)
    for iz, z in enumerate(np.linspace(0.0, GLASS_Z_MAX, n_z)):
        ior = (1 + z * z) / (1 - z * z)
        for side, eta in enumerate((1.0 / ior, ior)):
            for i, mu in enumerate(np.linspace(0.02, 1.0, n_mu)):
                d = np.tile([-math.sqrt(1 - mu * mu), 0.0, -mu], (len(a), 1))
                _, _, _, w_r, _, w_t, _ = sample_rough_dielectric(d, n, a, np.full(len(a), eta), uu1, uu2)
                table[side, iz, i] = (w_r + w_t).reshape(n_a, k * k).mean(axis=1)
    return table


_AN = (12, 7, 12, 12)  # grid of the anisotropic albedo: n.v, azimuth to the grain, sqrt(ax), sqrt(ay)


def ggx_albedo_aniso(cos_v, azimuth, ax, ay):
    """E_ss of the anisotropic GGX lobe at F = 1: `azimuth` of wo from the grain t (folded
    into 0..pi/2 by the lobe's symmetry), alphas ax along t and ay along b, multilinear in the
    table of _aniso_table: the isotropic table at any single alpha misses the grain's share by
    up to 0.1."""
    n_mu, n_phi, n_a, _ = _AN
    table = _table("aniso_e")
    coords = [np.clip((np.asarray(cos_v) - 0.02) / 0.98, 0, 1) * (n_mu - 1),
              np.clip(np.asarray(azimuth) / (math.pi / 2), 0, 1) * (n_phi - 1),
              np.clip((np.sqrt(ax) - math.sqrt(ALPHA_MIN)) / (1 - math.sqrt(ALPHA_MIN)), 0, 1) * (n_a - 1),
              np.clip((np.sqrt(ay) - math.sqrt(ALPHA_MIN)) / (1 - math.sqrt(ALPHA_MIN)), 0, 1) * (n_a - 1)]
    lo = [np.minimum(c.astype(int), size - 2) for c, size in zip(coords, _AN)]
    fr = [c - c0 for c, c0 in zip(coords, lo)]
    out = np.zeros(len(coords[0]))
    for corner in range(16):
        idx, wgt = [], np.ones(len(out))
        for axis in range(4):
            bit = (corner >> axis) & 1
            idx.append(lo[axis] + bit)
            wgt = wgt * (fr[axis] if bit else 1 - fr[axis])
        out += wgt * table[tuple(idx)]
    return out


def _aniso_table() -> np.ndarray:
    """12 x 7 x 12 x 12 over (n.v, azimuth 0..pi/2, sqrt(ax), sqrt(ay)), 16 x 16 stratified
    VNDF quadrature per cell."""
    n_mu, n_phi, n_a, _ = _AN
    k = 16
    g = (np.arange(k) + 0.5) / k
    u1, u2 = (a.reshape(-1) for a in np.meshgrid(g, g, indexing="ij"))
    ra = np.linspace(math.sqrt(ALPHA_MIN), 1.0, n_a)
    axg, ayg = (a.reshape(-1) for a in np.meshgrid(ra * ra, ra * ra, indexing="ij"))
    ax_s, ay_s = np.repeat(axg, k * k), np.repeat(ayg, k * k)
    uu1, uu2 = np.tile(u1, len(axg)), np.tile(u2, len(axg))
    table = np.zeros(_AN)
    for i, mu in enumerate(np.linspace(0.02, 1.0, n_mu)):
        for j, phi in enumerate(np.linspace(0.0, math.pi / 2, n_phi)):
            st = math.sqrt(1 - mu * mu)
            wo = np.tile([st * math.cos(phi), st * math.sin(phi), mu], (len(ax_s), 1))
            wi = reflect(-wo, ggx_vndf(wo, ax_s, ay_s, uu1, uu2))
            lv = ggx_lambda(wo[:, 0], wo[:, 1], wo[:, 2], ax_s, ay_s)
            ll = ggx_lambda(wi[:, 0], wi[:, 1], np.maximum(wi[:, 2], 1e-7), ax_s, ay_s)
            ratio = np.where(wi[:, 2] > 0, (1 + lv) / (1 + lv + ll), 0.0)
            table[i, j] = ratio.reshape(n_a, n_a, k * k).mean(axis=-1)
    return table


def ms_scale(f0, e_ss):
    """The multiply-scattered share over the single-scattered one, as the raster's
    Fdez-Aguera 2019 term: 1 + E_ms F_avg / (1 - E_ms F_avg), E_ms = 1 - E_ss."""
    e_ms = 1.0 - e_ss
    f_avg = f0 + (1.0 - f0) / 21.0
    return 1.0 + e_ms * f_avg / (1.0 - e_ms * f_avg)


# --- thin film (KHR_materials_iridescence, a port of shaders/iridescence.glsl) --------------

_XYZ_TO_REC709 = np.array([[3.2404542, -0.9692660, 0.0556434],
                           [-1.5371385, 1.8760108, -0.2040259],
                           [-0.4985314, 0.0415560, 1.0572252]])
_FILM_VAL = np.array([5.4856e-13, 4.4201e-13, 5.2481e-13])
_FILM_POS = np.array([1.6810e+06, 1.7953e+06, 2.2084e+06])
_FILM_VAR = np.array([4.3278e+09, 9.3046e+09, 6.6121e+09])


def _film_sensitivity(opd, shift):
    phase = (2.0 * math.pi * 1e-9 * opd)[:, None]
    xyz = _FILM_VAL * np.sqrt(2.0 * math.pi * _FILM_VAR) * np.cos(_FILM_POS * phase + shift) \
        * np.exp(-phase * phase * _FILM_VAR)
    xyz[:, 0] += 9.7470e-14 * math.sqrt(2.0 * math.pi * 4.5282e+09) * np.cos(2.2399e+06 * phase[:, 0] + shift[:, 0]) \
        * np.exp(-4.5282e+09 * phase[:, 0] ** 2)
    return (xyz / 1.0685e-7) @ _XYZ_TO_REC709


def thin_film_fresnel(cos1, film_ior, thickness, base_f0):
    """N x 3 reflectance at incidence cosine cos1 of a film (index film_ior, thickness nm)
    over a base of normal-incidence reflectance base_f0 (N x 3), as the raster's."""
    t = np.clip(thickness / 30.0, 0.0, 1.0)
    n2 = 1.0 + (film_ior - 1.0) * t * t * (3 - 2 * t)
    cos2_sq = 1.0 - (1.0 - cos1 * cos1) / (n2 * n2)
    tir = cos2_sq < 0
    cos2 = np.sqrt(np.maximum(cos2_sq, 0.0))
    r12 = ((n2 - 1.0) / (n2 + 1.0)) ** 2
    big_r12 = r12 + (1.0 - r12) * (1.0 - cos1) ** 5
    t121 = 1.0 - big_r12
    phi21 = np.where(n2 < 1.0, 0.0, math.pi)
    s = np.sqrt(np.clip(base_f0, 0.0, 0.9999))
    n3 = (1.0 + s) / (1.0 - s)
    r23 = ((n3 - n2[:, None]) / (n3 + n2[:, None])) ** 2
    big_r23 = r23 + (1.0 - r23) * ((1.0 - cos2) ** 5)[:, None]
    phi = phi21[:, None] + np.where(n3 < n2[:, None], math.pi, 0.0)
    opd = 2.0 * n2 * thickness * cos2
    r123_sq = np.clip(big_r12[:, None] * big_r23, 1e-5, 0.9999)
    r123 = np.sqrt(r123_sq)
    rs = t121[:, None] ** 2 * big_r23 / (1.0 - r123_sq)
    out = big_r12[:, None] + rs
    cm = rs - t121[:, None]
    for k in (1, 2):
        cm = cm * r123
        out = out + cm * 2.0 * _film_sensitivity(k * opd, k * phi)
    return np.where(tir[:, None], 1.0, np.clip(out, 0.0, 1.0))


# --- the layered BSDF at a batch of hits -----------------------------------------------------

@dataclass
class Bsdf:
    """Per-hit parameters of the reflective part (Coat, Sheen, Metal, Plastic), the choice
    probabilities, and the weight of the Glass component the integrator samples itself."""
    n: np.ndarray        # shading normal on the side of wo
    ng: np.ndarray       # geometric normal on the side of wo
    t: np.ndarray        # tangent frame about n (the grain, for anisotropy)
    b: np.ndarray
    wo: np.ndarray
    base: np.ndarray     # N x 3
    ax: np.ndarray       # GGX alpha along t and b
    ay: np.ndarray
    p_metal: np.ndarray  # m (within Base)
    p_plastic: np.ndarray  # (1 - m)(1 - tr)
    f0_d: np.ndarray     # N x 3 dielectric F0 (IOR x specular colour, clamped, x factor)
    f90_d: np.ndarray    # N specular factor
    p_spec: np.ndarray   # within Plastic: probability of sampling its GGX lobe
    ms_m: np.ndarray     # N x 3 multiple-scattering scale of Metal (1: off)
    ms_d: np.ndarray     # N x 3 the same for Plastic's GGX lobe
    dt: np.ndarray       # N diffuse transmission factor
    dt_color: np.ndarray  # N x 3
    irid: np.ndarray     # N iridescence factor
    irid_ior: np.ndarray
    irid_thick: np.ndarray
    coat: np.ndarray     # N clearcoat factor
    coat_n: np.ndarray   # N x 3 on the side of wo
    coat_alpha: np.ndarray
    sheen: np.ndarray    # N x 3 sheen colour
    sheen_rough: np.ndarray
    kd_t: np.ndarray     # N: what Plastic's GGX lobe leaves to diffuse transmission, 1 - max(E_spec(v))
    w_sheen: np.ndarray  # N: what the coat leaves to sheen and base, 1 - c F_coat(n_c.v)
    w_base: np.ndarray   # N: what coat and sheen leave to Base
    p_coat: np.ndarray   # choice probabilities of the layers (Base: 1 - p_coat - p_sheen)
    p_sheen: np.ndarray
    kd_o: np.ndarray     # N: a premultiplied blend's opacity, which scales the diffuse alone (1: none)

    @property
    def p_base(self) -> np.ndarray:
        return 1.0 - self.p_coat - self.p_sheen

    @property
    def glass_w(self) -> np.ndarray:
        """Weight of the Glass component given that it was chosen (probability p_base (1 - m) tr)."""
        return self.w_base / np.maximum(self.p_base, 1e-12)

    @property
    def p_reflective(self) -> np.ndarray:
        """Probability of choosing a reflective component (not Glass)."""
        return self.p_coat + self.p_sheen + self.p_base * (self.p_metal + self.p_plastic)

    def packed(self) -> np.ndarray:
        """The parameters as one N x path_kernel.WIDTH float64 matrix, the fields in order (a
        vector field three columns): what the compiled eval / sample read."""
        cols = []
        for f in fields(self):
            a = np.asarray(getattr(self, f.name), np.float64)
            cols.append(a[:, None] if a.ndim == 1 else a)
        return np.ascontiguousarray(np.concatenate(cols, axis=1))

    def rows(self, sel: np.ndarray) -> "Bsdf":
        if len(sel) == len(self.wo) and (len(sel) == 0 or (sel[0] == 0 and sel[-1] == len(sel) - 1)):
            return self  # every row, in order (sel from flatnonzero): no copies
        return Bsdf(*(getattr(self, f.name)[sel] for f in fields(self)))

    def _local(self, w):
        return dot(w, self.t), dot(w, self.b), dot(w, self.n)

    def _fresnel(self, v_h):
        """(Metal F, Plastic F) at v.h, iridescence mixed in."""
        f_m = schlick(self.base, v_h)
        f_d = schlick(self.f0_d, v_h, self.f90_d)
        ir = np.flatnonzero(self.irid > 0)
        if len(ir):
            c, k = v_h[ir], self.irid[ir, None]
            film_m = thin_film_fresnel(c, self.irid_ior[ir], self.irid_thick[ir], self.base[ir])
            film_d = thin_film_fresnel(c, self.irid_ior[ir], self.irid_thick[ir], self.f0_d[ir]) \
                * self.f90_d[ir, None]
            f_m[ir] += k * (film_m - f_m[ir])
            f_d[ir] += k * (film_d - f_d[ir])
        return f_m, f_d

    def eval(self, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f * |cos(n, wi)|, pdf of wi under the reflective components' sampling, both
        unconditioned on choosing them)."""
        n_l = dot(self.n, wi)
        n_v = np.maximum(dot(self.n, self.wo), 1e-6)
        g_l = dot(self.ng, wi)
        up = (n_l > 1e-7) & (g_l > 0)
        down = (n_l < -1e-7) & (g_l < 0)
        cl = np.maximum(n_l, 1e-7)
        h = wi + self.wo
        h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
        v_h = np.clip(dot(self.wo, h), 0.0, 1.0)
        if np.array_equal(self.ax, self.ay):  # isotropic everywhere: no frame needed
            hz = dot(self.n, h)
            d = ggx_d(np.sqrt(np.maximum(1 - hz * hz, 0.0)), 0.0, hz, self.ax, self.ay)
            lam_v = ggx_lambda(np.sqrt(np.maximum(1 - n_v * n_v, 0.0)), 0.0, n_v, self.ax, self.ay)
            lam_l = ggx_lambda(np.sqrt(np.maximum(1 - cl * cl, 0.0)), 0.0, cl, self.ax, self.ay)
        else:
            hx, hy, hz = self._local(h)
            vx, vy, vz = self._local(self.wo)
            lx, ly, _ = self._local(wi)
            d = ggx_d(hx, hy, hz, self.ax, self.ay)
            lam_v = ggx_lambda(vx, vy, np.maximum(vz, 1e-6), self.ax, self.ay)
            lam_l = ggx_lambda(lx, ly, cl, self.ax, self.ay)
        spec = d / (1.0 + lam_v + lam_l) / (4 * n_v)             # x cos(n, wi) already
        pdf_ggx = d / (1.0 + lam_v) / (4 * n_v)
        f_m, f_d = self._fresnel(v_h)
        kd = 1.0 - f_d.max(axis=1)
        diffuse_r = (1 - self.dt)[:, None] * kd[:, None] * self.base * (cl / math.pi)[:, None] \
            * self.kd_o[:, None]
        base = (self.p_metal[:, None] * f_m * self.ms_m * spec[:, None]
                + self.p_plastic[:, None] * (diffuse_r + f_d * self.ms_d * spec[:, None]))
        pdf_base = (self.p_metal * pdf_ggx
                    + self.p_plastic * (self.p_spec * pdf_ggx
                                        + (1 - self.p_spec) * (1 - self.dt) * cl / math.pi))
        fcos = np.where(up[:, None], self.w_base[:, None] * base, 0.0)
        pdf = np.where(up, self.p_base * pdf_base, 0.0)
        # diffuse transmission: the other side, thin-walled Lambert
        tr = np.flatnonzero(down & (self.dt > 0) & (self.p_plastic > 0))
        if len(tr):
            c = -n_l[tr]
            kd_v = self.kd_t[tr]
            fcos[tr] = (self.w_base[tr] * self.p_plastic[tr] * self.dt[tr] * kd_v * c / math.pi)[:, None] \
                * self.dt_color[tr]
            pdf[tr] = self.p_base[tr] * self.p_plastic[tr] * (1 - self.p_spec[tr]) * self.dt[tr] * c / math.pi
        sh = np.flatnonzero(up & (self.p_sheen > 0))
        if len(sh):
            n_h = np.clip(dot(self.n[sh], h[sh]), 0.0, 1.0)
            dv = sheen_dv(n_v[sh], cl[sh], n_h, self.sheen_rough[sh])
            fcos[sh] += (self.w_sheen[sh] * dv * cl[sh])[:, None] * self.sheen[sh]
            pdf[sh] += self.p_sheen[sh] / (2 * math.pi)
        ct = np.flatnonzero((self.p_coat > 0) & (g_l > 0))
        if len(ct):
            nc, a = self.coat_n[ct], self.coat_alpha[ct]
            c_l = dot(nc, wi[ct])
            c_v = np.maximum(dot(nc, self.wo[ct]), 1e-6)
            ok = c_l > 1e-7
            c_l = np.maximum(c_l, 1e-7)
            c_h = np.clip(dot(nc, h[ct]), 0.0, 1.0)
            dc = ggx_d(np.sqrt(np.maximum(1 - c_h * c_h, 0.0)), 0.0, c_h, a, a)
            lv = ggx_lambda(np.sqrt(np.maximum(1 - c_v * c_v, 0.0)), 0.0, c_v, a, a)
            ll = ggx_lambda(np.sqrt(np.maximum(1 - c_l * c_l, 0.0)), 0.0, c_l, a, a)
            fc = COAT_F0 + (1 - COAT_F0) * (1 - v_h[ct]) ** 5
            f_coat = self.coat[ct] * fc * dc / (1 + lv + ll) / (4 * c_v)
            fcos[ct] += np.where(ok, f_coat, 0.0)[:, None]
            pdf[ct] += np.where(ok, self.p_coat[ct] * dc / (1 + lv) / (4 * c_v), 0.0)
        return fcos, pdf

    def sample(self, u_layer, u_pick, u_lobe, u1, u2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions drawn from the reflective components (rows that chose Glass are the
        integrator's: not here), whether each came from a rough component, and whether it is
        valid: a microfacet reflection that leaves below its lobe's surface is not (the
        mixture pdf there counts only the lobes that sample it: diffuse transmission's)."""
        n = len(u_pick)
        wi = np.empty((n, 3))
        rough = np.ones(n, bool)
        valid = np.ones(n, bool)
        coat = u_layer < self.p_coat
        sheen = ~coat & (u_layer < self.p_coat + self.p_sheen)
        base = ~coat & ~sheen
        # Base: Metal with probability m, else Plastic (GGX with p_spec, else diffuse)
        ggx = base & ((u_pick < self.p_metal) | (u_lobe < self.p_spec))
        g = np.flatnonzero(ggx)
        if len(g):
            r = self.rows(g)
            m_l = ggx_vndf(np.stack(r._local(r.wo), -1), r.ax, r.ay, u1[g], u2[g])
            m = m_l[:, :1] * r.t + m_l[:, 1:2] * r.b + m_l[:, 2:] * r.n
            wi[g] = reflect(-r.wo, m)
            rough[g] = np.sqrt(r.ax * r.ay) >= ROUGH_ALPHA
            valid[g] = dot(wi[g], r.n) > 0
        c = np.flatnonzero(base & ~ggx)
        if len(c):
            # diffuse: reflected, or with probability dt transmitted
            u_t = (u_lobe[c] - self.p_spec[c]) / np.maximum(1 - self.p_spec[c], 1e-12)
            side = np.where(u_t < self.dt[c], -1.0, 1.0)[:, None]
            wi[c] = cosine(self.n[c] * side, u1[c], u2[c])
        s = np.flatnonzero(sheen)
        if len(s):  # uniform over the hemisphere
            z = u1[s]
            r_ = np.sqrt(np.maximum(0.0, 1 - z * z))
            phi = 2 * math.pi * u2[s]
            t, b = self.t[s], self.b[s]
            wi[s] = (r_ * np.cos(phi))[:, None] * t + (r_ * np.sin(phi))[:, None] * b + z[:, None] * self.n[s]
        k = np.flatnonzero(coat)
        if len(k):
            nc, a = self.coat_n[k], self.coat_alpha[k]
            t, b = orthonormal_basis(nc)
            wo = self.wo[k]
            m_l = ggx_vndf(np.stack([dot(wo, t), dot(wo, b), dot(wo, nc)], -1), a, a, u1[k], u2[k])
            m = m_l[:, :1] * t + m_l[:, 1:2] * b + m_l[:, 2:] * nc
            wi[k] = reflect(-wo, m)
            rough[k] = a >= ROUGH_ALPHA
            valid[k] = dot(wi[k], nc) > 0
        return wi, rough, valid


ROUGH_ALPHA = 0.1     # lobes at least this wide count as rough for the firefly clamp


def cosine(n, u1, u2):
    t, b = orthonormal_basis(n)
    r, phi = np.sqrt(u1), 2 * math.pi * u2
    z = np.sqrt(np.maximum(0.0, 1 - u1))
    return (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * n


def frame(n: np.ndarray, grain: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(t, b) about n: t the grain projected onto n's plane where it has one, else any."""
    t, b = orthonormal_basis(n)
    if grain is None:
        return t, b
    g = grain - n * dot(grain, n)[:, None]
    ln = np.linalg.norm(g, axis=-1)
    ok = ln > 1e-6
    t[ok] = g[ok] / ln[ok, None]
    b[ok] = np.cross(n[ok], t[ok])
    return t, b


def build_packed(hits, ns, ng, wo, ior, multiscatter: bool,
                 opacity: np.ndarray | None = None) -> np.ndarray:
    """build's packed matrix (Bsdf.packed), compiled (path_kernel.build_rows)."""
    from renderer.methods import path_kernel

    def f8(a):
        return np.ascontiguousarray(a, np.float64)

    return path_kernel.build_rows(
        f8(ns), f8(ng), f8(wo), f8(ior), f8(hits.base), f8(hits.metallic), f8(hits.transmission),
        f8(hits.roughness), f8(hits.anisotropy), f8(hits.anisotropy_t), f8(hits.specular),
        f8(hits.specular_color), f8(hits.diffuse_transmission), f8(hits.diffuse_transmission_color),
        f8(hits.iridescence), f8(hits.iridescence_ior), f8(hits.iridescence_thickness),
        f8(hits.clearcoat), f8(hits.clearcoat_normal), f8(hits.clearcoat_roughness),
        f8(hits.sheen_color), f8(hits.sheen_roughness),
        f8(np.ones(len(wo)) if opacity is None else opacity), bool(multiscatter),
        _table("ggx_e"), _table("ggx_b"), _table("aniso_e"), _table("sheen_e"))


def build(hits, ns, ng, wo, ior, multiscatter: bool, opacity: np.ndarray | None = None) -> Bsdf:
    """The BSDF at hits (trace_material.Hits rows) with shading normal ns and geometric ng
    on wo's side, IOR per hit; `opacity` (None: 1) scales the diffuse share of a
    premultiplied blend (its specular stays whole, as Storm blends it)."""
    n = len(wo)
    metal, trans = hits.metallic, hits.transmission
    alpha = np.maximum(hits.roughness ** 2, ALPHA_MIN)
    aniso = np.clip(hits.anisotropy, 0.0, 1.0)
    ax = alpha + (1.0 - alpha) * aniso * aniso
    has_grain = np.linalg.norm(hits.anisotropy_t, axis=-1) > 0
    t, b = frame(ns, np.where(has_grain[:, None], hits.anisotropy_t, 0.0) if has_grain.any() else None)
    f0_ior = ((ior - 1) / (ior + 1)) ** 2
    f0_d = np.minimum(f0_ior[:, None] * hits.specular_color, 1.0) * hits.specular[:, None]
    f90_d = hits.specular.copy()
    n_v = np.clip(dot(ns, wo), 1e-6, 1.0)
    p_spec = np.clip(schlick(f0_d, n_v, f90_d).max(axis=1), 0.1, 0.9)
    e_spec_avail = False
    if multiscatter:  # energy lost between microfacets, put back (Turquin 2019)
        e = ggx_albedo(n_v, alpha)
        an = np.flatnonzero(ax > alpha)
        if len(an):
            azimuth = np.arctan2(np.abs(dot(wo[an], b[an])), np.abs(dot(wo[an], t[an])))
            e[an] = ggx_albedo_aniso(n_v[an], azimuth, ax[an], alpha[an])
        e_ss = np.clip(e, 0.05, 1.0)[:, None]
        ms_m, ms_d = ms_scale(hits.base, e_ss), ms_scale(f0_d, e_ss)
        e_spec_avail = True
    else:
        ms_m = ms_d = np.ones((n, 3))
    dt = np.clip(hits.diffuse_transmission, 0.0, 1.0)
    kd_t = np.ones(n)
    tr = np.flatnonzero(dt > 0)
    if len(tr):  # the GGX lobe's directional albedo E_spec = f0 (E - B) + f90 B, x its ms scale
        e_f1, e_b = ggx_albedo(n_v[tr], alpha[tr]), ggx_schlick_share(n_v[tr], alpha[tr])
        e_spec = f0_d[tr] * (e_f1 - e_b)[:, None] + (f90_d[tr] * e_b)[:, None]
        if e_spec_avail:
            e_spec = e_spec * ms_d[tr]
        kd_t[tr] = np.clip(1.0 - e_spec.max(axis=1), 0.0, 1.0)
    coat = np.clip(hits.clearcoat, 0.0, 1.0)
    cn = hits.clearcoat_normal * np.where(dot(hits.clearcoat_normal, ng) < 0, -1.0, 1.0)[:, None]
    bad = dot(cn, wo) <= 0
    cn[bad] = ng[bad]
    fc_v = COAT_F0 + (1 - COAT_F0) * (1 - np.clip(dot(cn, wo), 0.0, 1.0)) ** 5
    w_sheen = 1.0 - coat * fc_v
    peak = hits.sheen_color.max(axis=1)
    e_sheen = np.zeros(n)
    sh = np.flatnonzero(peak > 0)
    if len(sh):
        # the Charlie lobe's albedo passes 1 at grazing: the base never goes negative
        e_sheen[sh] = np.minimum(sheen_albedo(n_v[sh], hits.sheen_roughness[sh]), 1.0)
    w_base = w_sheen * (1.0 - peak * e_sheen)
    p_coat = np.where(coat > 0, np.clip(coat * np.maximum(fc_v, 0.1), 0.0, 0.9), 0.0)
    p_sheen = np.where(peak > 0, (1 - p_coat) * np.clip(peak * np.maximum(e_sheen, 0.1), 0.0, 0.9), 0.0)
    return Bsdf(ns, ng, t, b, wo, hits.base, ax, alpha, metal, (1 - metal) * (1 - trans), f0_d, f90_d,
                p_spec, ms_m, ms_d, dt, hits.diffuse_transmission_color,
                hits.iridescence, hits.iridescence_ior, hits.iridescence_thickness,
                coat, cn, np.maximum(hits.clearcoat_roughness ** 2, ALPHA_MIN), hits.sheen_color,
                hits.sheen_roughness, kd_t, w_sheen, w_base, p_coat, p_sheen,
                np.ones(n) if opacity is None else np.asarray(opacity, np.float64))


if __name__ == "__main__":
    arrays = {k: v.astype(np.float32) for k, v in build_tables().items()}
    np.savez_compressed(TABLES, **arrays)  # type: ignore[arg-type]  # numpy's stub: allow_pickle
    print(f"wrote {TABLES}")
