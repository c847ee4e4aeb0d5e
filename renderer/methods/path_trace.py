"""The path-tracing integrator of method raytrace (`integrator="path"`).

Unbiased paths through the same baked material the Fresnel tree and the raster read
(trace_material: textures, normal maps, vertex colours, alpha). The BSDF is glTF's
metal-rough model as a mixture with wo-independent weights, so that choosing a component
and dividing by its weight is exact:

    f = m * Metal + (1 - m)(1 - tr) * Plastic + (1 - m) tr * Glass

- Metal: GGX reflection (alpha = roughness^2, height-correlated Smith G2), Schlick F at F0 =
  base colour; sampled from the visible normals (Heitz 2018). With `multiscatter` (the
  default) the lobe is scaled by the multiply-scattered share of Fdez-Aguera 2019 (as the
  raster's shaders/ibl.glsl), E_ss the single-scattering albedo of this very lobe
  (ggx_albedo): a white rough metal keeps its energy (single-scattering GGX at roughness 1
  returns only 0.31 at normal incidence).
- Plastic: glTF's fresnel_mix: (1 - F(v.h)) * base / pi + F(v.h) * D G2 / (4 n.v n.l) with
  Schlick F at F0 from the IOR; the GGX lobe is sampled with probability F(n.v) (at least
  0.1), the cosine-weighted diffuse otherwise; the component's pdf is the mixture of both.
- Glass: the exact dielectric (smooth: mirror / refraction with exact Fresnel, TIR included;
  rough: Walter et al. about a sampled visible normal, renderer.methods.optics), tinted by
  sqrt(base colour) at each crossing of a volume (Cycles' convention; a thin sheet: base once), radiance scaled by eta^2 across the interface (as the tree),
  Beer-Lambert attenuation inside. It is only BSDF-sampled (no light sampling).

Light: the environment is importance-sampled from a luminance x solid-angle CDF over the
texels of the bake's sharpest cube-map level (90%, mixed with 10% uniform over the sphere
so that no direction with radiance has zero pdf), combined with BSDF sampling of Metal and
Plastic by the power heuristic (Veach 1995); rays that escape after Glass or a smooth lobe
take the environment at full weight. Punctual lights are deltas: next-event estimation
alone, with an occlusion-only shadow ray (a glass occluder blocks them: its caustic is not
a path BSDF sampling can find). Emissive triangles are lights as well (`_emitter_nee`, with
the Fresnel tree's sampler trace_lights.emitter_choice): one point a vertex wherever the
environment is sampled, a shadow ray, power heuristic against BSDF rays that meet them
(`_emitter_hit_mis`); emission met after glass or a delta, and by camera rays, counts in full
(docs/raytrace.md, "Emitters in the path integrator"). Russian roulette from the fourth surface on (survival = the path's throughput in
max-RGB x eta^2, at most 1: a survivor's throughput is raised to 1 and never above what it
carried, so no sample of a lossless glass outshines the environment; a cap below 1 would
kill full-throughput paths and boost the rest, measured +11% on single pixels of the
stability suite's TIR prism at 128 passes); a path still alive after `bounces` surfaces
reads the environment along its direction, as the tree does.

Samples: one path per pixel per pass, the camera ray jittered within the pixel; every
dimension pair of pass s is the R2 low-discrepancy point s (Roberts 2018) rotated by a hash
of (pixel, dimension): deterministic, stratified over a pixel's passes, independent across
pixels. Passes run until every pixel's relative standard error (of luminance, over its
passes) is under `noise`, or `samples` passes, or until the next pass would overrun
`budget_ms` (the granularity is one pass; the first pass always runs). Pixels that have
reached the noise target stop being traced. Background pixels away from the object keep
one centre ray (as the tree).

Firefly clamp: once a path has scattered off a rough lobe (diffuse, or GGX with alpha >=
ROUGH_ALPHA), what any later vertex adds is clamped to FIREFLY in max-RGB (colour kept):
direct light (first rough vertex, by NEE or by MIS'd BSDF sampling) is never clamped; this
is the only bias besides the closing environment read. Every pixel is finite (NaN and
infinities are zeroed and counted in the plan).
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from core import storm
from core.cubemap import direction_to_face
from core.options import RenderOptions
from renderer.methods import path_bsdf, trace_lights, trace_material
from renderer.methods.optics import (
    fresnel_dielectric,
    reflect,
    refract,
    sample_rough_dielectric,
)
from renderer.methods.path_bsdf import ALPHA_MIN, ROUGH_ALPHA, ggx_albedo  # noqa: F401  # ggx_albedo: re-exported
from renderer.methods.trace_scene import (
    EPSILON,
    coverage,
    hit_material,
    intersect_front,
    opacity,
    sobol_samples,
    storm_back,
)

FIREFLY = 16.0        # max-RGB clamp of indirect contributions (linear radiance)
UNIFORM_SHARE = 0.1   # of environment samples drawn uniformly over the sphere
RR_START = 3          # Russian roulette from this surface index on
MIN_PASSES = 4        # before the noise target is tested
# A path's sample streams: each (kind, surface index, light) its own shuffled, scrambled Sobol
# pair per pixel (_dim keys it; trace_scene.sobol_samples), so any two are independent and
# each converges on its own.
(K_JITTER, K_ALPHA, K_ENV, K_ENV_PICK, K_EMITTER_PICK, K_EMITTER_POINT, K_LIGHT, K_LOBE,
 K_DIRECTION, K_LAYER, K_ROULETTE, K_PASS, K_SHADOW_ALPHA, K_EMITTER_ALPHA) = range(14)
_KINDS = 16
_DEPTHS = 1 << 16  # more than RenderOptions.bounces allows
_KEY_BASE = 1 << 32  # clear of the tree's keys (a bounce index plus 0, 400 or 700)


_NO_TABLE = np.zeros((0, 1, 1, 1))  # path_kernel.glass_albedo's "no compensation"


def _dim(kind: int, depth: int, i: int = 0) -> int:
    """The key of stream `kind` at surface index `depth` (light i): distinct for every triple."""
    return _KEY_BASE + ((i * _DEPTHS + depth) * _KINDS + kind)


KERNEL = True         # the BSDF compiled (path_kernel, numba); False: path_bsdf's numpy twin
EMITTER_NEE = True    # emissive triangles sampled as lights at every non-specular vertex (False: BSDF hits alone)


class _Lobes:
    """The BSDF at a bounce's hits, evaluated and sampled by rows (indices into the hits):
    compiled (path_kernel over the packed parameters, built compiled too) or, with KERNEL
    off, path_bsdf's numpy Bsdf."""

    def __init__(self, hits, ns, ng, wo, ior, multiscatter: bool, opacity: np.ndarray | None = None):
        if KERNEL:
            from renderer.methods import path_kernel as k
            self.kernel = k
            self.bsdf: path_bsdf.Bsdf | None = None
            p = path_bsdf.build_packed(hits, ns, ng, wo, ior, multiscatter, opacity)
            self.packed: np.ndarray | None = p
            layers = p[:, k.P_COAT] + p[:, k.P_SHEEN]
            self.p_reflective = layers + (1 - layers) * (p[:, k.P_METAL] + p[:, k.P_PLASTIC])
        else:
            self.bsdf = path_bsdf.build(hits, ns, ng, wo, ior, multiscatter, opacity)
            self.packed = None
            self.p_reflective = self.bsdf.p_reflective

    def eval(self, rows: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.bsdf is not None:
            return self.bsdf.rows(rows).eval(wi)
        return self.kernel.eval_rows(self.packed, np.ascontiguousarray(rows, np.int64),
                                     np.ascontiguousarray(wi, np.float64))

    def sample(self, rows, u_layer, u_pick, u_lobe, u1, u2):
        """(wi, rough, valid, f |cos|, pdf) drawn at rows."""
        if self.bsdf is not None:
            sub = self.bsdf.rows(rows)
            wi, rough, valid = sub.sample(u_layer, u_pick, u_lobe, u1, u2)
            return (wi, rough, valid, *sub.eval(wi))
        c = np.ascontiguousarray
        return self.kernel.sample_rows(self.packed, c(rows, np.int64), c(u_layer), c(u_pick),
                                       c(u_lobe), c(u1), c(u2))


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class EnvSampler:
    """Importance sampling of a cube-map environment: a CDF over texels of luminance x
    solid angle, texels drawn uniformly in face coordinates (the pdf accounts for the
    cube's Jacobian), mixed with uniform sphere sampling."""

    def __init__(self, faces: np.ndarray, to_env: np.ndarray | None):
        faces = np.asarray(faces, np.float64)
        self.size = s = faces.shape[1]
        c = (np.arange(s) + 0.5) / s * 2 - 1
        tc, sc = np.meshgrid(c, c, indexing="ij")
        domega = (2.0 / s) ** 2 / (1 + sc * sc + tc * tc) ** 1.5      # texel solid angle
        lum = faces[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        w = (np.maximum(lum, 0) * domega[None]).reshape(-1)
        total = w.sum()
        self.p_texel = w / total if total > 0 else np.full(w.size, 1.0 / w.size)
        self.cdf = np.cumsum(self.p_texel)
        self.cdf[-1] = 1.0
        self.to_env = to_env
        self.faces = faces
        from core import cubemap
        self._faces_def = (cubemap._S_AXIS, cubemap._S_SIGN, cubemap._T_AXIS, cubemap._T_SIGN)

    def _texel_pdf(self, d_env: np.ndarray) -> np.ndarray:
        face, s, t = direction_to_face(d_env)
        n = self.size
        x = np.clip((s * n).astype(np.int64), 0, n - 1)
        y = np.clip((t * n).astype(np.int64), 0, n - 1)
        p = self.p_texel[(face * n + y) * n + x]
        sc, tc = s * 2 - 1, t * 2 - 1
        return p * n * n / 4.0 * (1 + sc * sc + tc * tc) ** 1.5

    def _kernel_args(self):
        from core import cubemap
        from renderer.methods import path_kernel
        rot = np.eye(3) if self.to_env is None else np.ascontiguousarray(self.to_env, np.float64)
        axes = (cubemap._S_AXIS.astype(np.int64), cubemap._S_SIGN.astype(np.float64),
                cubemap._T_AXIS.astype(np.int64), cubemap._T_SIGN.astype(np.float64))
        return path_kernel, rot, axes

    def pdf(self, d_world: np.ndarray) -> np.ndarray:
        if KERNEL:
            kernel, rot, axes = self._kernel_args()
            return kernel.env_pdf(self.p_texel, self.size, np.ascontiguousarray(d_world, np.float64),
                                  rot, UNIFORM_SHARE, *axes)
        return self.pdf_numpy(d_world)

    def sample(self, u1: np.ndarray, u2: np.ndarray, u3: np.ndarray) -> np.ndarray:
        """World directions; u3 picks uniform (below UNIFORM_SHARE) or the CDF."""
        if KERNEL:
            kernel, rot, axes = self._kernel_args()
            c = np.ascontiguousarray
            return kernel.env_sample(self.cdf, self.p_texel, self.size, c(u1), c(u2), c(u3), rot,
                                     UNIFORM_SHARE, *axes)
        return self.sample_numpy(u1, u2, u3)

    def pdf_numpy(self, d_world: np.ndarray) -> np.ndarray:
        d = d_world if self.to_env is None else d_world @ self.to_env.T
        return (1 - UNIFORM_SHARE) * self._texel_pdf(d) + UNIFORM_SHARE / (4 * math.pi)

    def sample_numpy(self, u1: np.ndarray, u2: np.ndarray, u3: np.ndarray) -> np.ndarray:
        """sample in numpy (path_kernel.env_sample's twin)."""
        n = self.size
        idx = np.minimum(np.searchsorted(self.cdf, u1, side="right"), self.cdf.size - 1)
        face, rest = np.divmod(idx, n * n)
        y, x = np.divmod(rest, n)
        # u1's position inside its CDF bin is a fresh uniform for the texel's first axis
        lo = np.where(idx > 0, self.cdf[np.maximum(idx - 1, 0)], 0.0)
        fx = np.clip((u1 - lo) / np.maximum(self.p_texel[idx], 1e-300), 0.0, 1.0 - 1e-9)
        sc = (x + fx) / n * 2 - 1
        tc = (y + u2) / n * 2 - 1
        s_axis, s_sign, t_axis, t_sign = self._faces_def
        major, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
        d = np.zeros((len(u1), 3))
        rows = np.arange(len(u1))
        d[rows, major] = sign
        d[rows, s_axis[face]] = s_sign[face] * sc
        d[rows, t_axis[face]] = t_sign[face] * tc
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        uni = u3 < UNIFORM_SHARE
        if np.any(uni):  # uniform on the sphere from (u1, u2)
            z = 1 - 2 * u1[uni]
            r = np.sqrt(np.maximum(0.0, 1 - z * z))
            phi = 2 * math.pi * u2[uni]
            d[uni] = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
        return d if self.to_env is None else d @ self.to_env


class _Sampler:
    """Uniforms for (pixel, pass, stream): pass s of the pixel's Sobol pair keyed by the
    stream (_dim): a (0, 2)-sequence per (pixel, stream), shuffled apart from the others."""

    def __call__(self, pix: np.ndarray, s: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
        # compiled (trace_kernel.sobol_pair): numpy's took ~7% of a warm frame
        from renderer.methods import trace_kernel
        return trace_kernel.sobol_pair(np.ascontiguousarray(pix, np.int64), s, dim, trace_kernel._SOBOL_DIM1)

    def single(self, pix: np.ndarray, s: int, dim: int) -> np.ndarray:
        """One uniform for (pixel, pass, stream): the pair's first (a scrambled van der Corput
        stream of its own)."""
        return self(pix, s, dim)[0]

    def numpy(self, pix: np.ndarray, s: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
        """The same uniforms in numpy (the compiled loop's twin, for tests)."""
        return sobol_samples(np.asarray(pix, np.int64), np.full(len(pix), s, np.uint32), dim)


def _clamp(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    m = rgb.max(axis=1)
    scale = np.where(mask & (m > FIREFLY), FIREFLY / np.maximum(m, 1e-30), 1.0)
    return rgb * scale[:, None]


def trace_pass(ts, env, options: RenderOptions, eye: np.ndarray, dirs: np.ndarray,
               pix: np.ndarray, s: int, env_sampler: EnvSampler, stats: dict) -> tuple[np.ndarray, np.ndarray]:
    """One path per camera ray `dirs` (pixel `pix`, pass `s`): (N x 3 radiance, N bool: the
    camera ray hit the object)."""

    sample = _Sampler()
    eps = EPSILON * ts.radius
    n = len(dirs)
    out = np.zeros((n, 3))
    origins = np.broadcast_to(eye, dirs.shape).astype(np.float64)
    d = dirs.astype(np.float64)
    w = np.ones((n, 3))
    slot = np.arange(n)
    medium = np.ones(n)            # IOR around the ray
    mis_pdf = np.zeros(n)          # BSDF pdf of the last scatter (0: delta or glass: no MIS)
    prev_x = np.zeros((n, 3))      # where the last scatter was (an emitter hit's light-sampling pdf)
    em = ts.emitters if EMITTER_NEE else None
    clamp_esc = np.zeros(n, bool)  # what the next vertex or escape adds is indirect
    n_rough = np.zeros(n, np.int64)
    show_env = options.background == "env"
    stats.setdefault("paths", 0)
    stats["paths"] += n
    max_depth = max(int(options.bounces), 1)
    hit0 = np.zeros(n)
    # A premultiplied blend (USD, as Storm blends it) is met, not passed by its alpha: its
    # BSDF's diffuse share takes the opacity a (the specular stays whole), and the path goes
    # on straight through it with probability P = min(1 - a, PASS_MAX), weighted
    # (1 - a) / P, or scatters, weighted 1 / (1 - P). `clear`: the weight of a path still on
    # its camera ray's line through such layers (0 off it), which sees the background only
    # where it is shown; coverage walks the line at once (trace_scene.coverage: no noise).
    split = ts.premultiplied.any()
    clear = np.ones(n) if split else np.zeros(0)
    for depth in range(max_depth + 1):
        if not len(d):
            break
        if depth == max_depth:  # out of surfaces: the environment along the ray (as the tree)
            add = w * (medium ** 2)[:, None] * env.radiance(d, np.zeros(len(d)))
            if split and not show_env:  # still the camera's ray: no background
                add[clear > 0] = 0.0
            out[slot] += _clamp(add, clamp_esc)
            break
        u_alpha, _ = sample(pix[slot], s, _dim(K_ALPHA, depth))
        prim, u, v, t = _timed(stats, "traversal", intersect_front, ts, origins, d, u_alpha, True)
        stats["rays"] += len(d)
        miss = prim < 0
        cover = opacity(ts, origins, d, prim, u, v, t)
        if depth == 0:  # through premultiplied layers: what they let through is uncovered
            hit0 = coverage(ts, origins, d, prim, t, cover, u_alpha)
        # a camera ray behind the layers it went through sees the background only if shown
        esc = miss & ~(clear > 0) if split and depth > 0 and not show_env else miss
        if np.any(esc) and (depth > 0 or show_env):
            dm = d[esc]
            le = env.radiance(dm, np.zeros(len(dm)))
            p_b = mis_pdf[esc]
            mis = np.ones(len(dm))
            has = p_b > 0
            if np.any(has):
                p_l = env_sampler.pdf(dm[has])
                mis[has] = p_b[has] ** 2 / (p_b[has] ** 2 + p_l ** 2)
            out[slot[esc]] += _clamp(w[esc] * (mis * medium[esc] ** 2)[:, None] * le, clamp_esc[esc])
        hit = np.flatnonzero(~miss)
        if not len(hit):
            break
        fetch0 = trace_material.FETCH_MS[0]
        hits = _timed(stats, "material", hit_material, ts, origins[hit], d[hit], prim[hit], u[hit], v[hit], t[hit])
        stats["split_ms"]["textures"] += trace_material.FETCH_MS[0] - fetch0
        origins, d, w, slot, medium = origins[hit], d[hit], w[hit], slot[hit], medium[hit]
        clamp_esc, n_rough, prim, t = clamp_esc[hit], n_rough[hit], prim[hit], t[hit]
        mis_pdf, prev_x = mis_pdf[hit], prev_x[hit]
        if split:
            assert cover is not None
            clear, cover = clear[hit], cover[hit]
        px = pix[slot]
        k = ts.material[prim]
        p = origins + d * t[:, None]
        ng = ts.geo_normals[prim].astype(np.float64)
        entering = _dot(d, ng) < 0
        side = np.where(entering, 1.0, -1.0)[:, None]
        ng = ng * side
        ns = hits.normal * side
        flip = _dot(d, ns) >= 0
        ns[flip] = ng[flip]
        # a single-sided USD surface's back face is lit as Storm lights it (core.storm), in
        # closed form under the environment (no BSDF there to sample): the authored normal,
        # facing away; specular F0 A + B along its mirror direction, diffuse (1 - F0) base
        # about that normal (opacity-faded); the path ends there (or goes on through it)
        on_line = (clear > 0) | (depth == 0) if split else np.full(len(k), depth == 0)
        back = storm_back(ts)[k] & ~entering & on_line  # what the camera sees, not a bounce
        if np.any(back):
            nb = hits.normal[back]
            a_b, b_b = storm.back_face_albedo(hits.roughness[back])
            f0 = ((ts.ior[k[back]] - 1) / (ts.ior[k[back]] + 1)) ** 2
            metal = hits.metallic[back][:, None]
            spec = (1 - metal) * (f0 * a_b + b_b)[:, None] + metal * (hits.base[back] * a_b[:, None] + b_b[:, None])
            fade = (cover[back] if split and cover is not None else 1.0) * hits.occlusion[back]
            diff = ((1 - metal[:, 0]) * (1 - f0) * fade)[:, None] * hits.base[back]
            out[slot[back]] += _clamp(w[back] * (spec * env.radiance(reflect(d[back], nb), hits.roughness[back])
                                                 + diff * env.irradiance(nb)), clamp_esc[back])
            if ts.lights is not None and len(ts.lights):  # the lights: diffuse about nb alone
                sb = np.flatnonzero(back)
                ng_b = -ng[back]  # the authored side, away from the ray

                def unoccluded(o, ldir, dist, nrm, _depth=depth):  # alpha draws unhashed by pixel
                    return np.repeat(_unoccluded(ts, _off(o, nrm, ldir, eps), ldir, dist,
                                                 np.zeros(len(o), np.int64), s, _depth)[:, None], 3, axis=1)

                def spec_albedo(f0, cos_v, rough):
                    return (env.specular_albedo(f0, cos_v, rough, False),) * 2
                rgb = trace_lights.direct(ts.lights, unoccluded, p[back], nb, ng_b, -d[back], hits.base[back],
                                          hits.metallic[back], hits.roughness[back], hits.transmission[back],
                                          ts.ior[k[back]], spec_albedo, cover[back] if split and cover is not None else None,
                                          back=np.ones(len(sb), bool))
                out[slot[back]] += _clamp(w[back] * rgb, clamp_esc[back])
        trans = hits.transmission
        thin = ts.thin[k]
        entering = entering | thin  # a thin-walled sheet has no inside
        # Beer-Lambert over the segment just travelled inside a volume
        inside = ~entering & (trans > 0)
        if np.any(inside) and ts.sigma.any():
            w[inside] *= np.exp(-ts.sigma[k[inside]] * t[inside, None])
        glow = hits.emission.max(axis=1) > 0
        if np.any(glow):
            le = hits.emission[glow]
            if em is not None:  # a light triangle the last scatter's NEE could have drawn
                le = le * _emitter_hit_mis(em, prim[glow], d[glow], p[glow], prev_x[glow], mis_pdf[glow])[:, None]
            out[slot[glow]] += _clamp(w[glow] * le, clamp_esc[glow])
        ior = ts.ior[k]
        wo = -d
        alpha = np.maximum(hits.roughness ** 2, ALPHA_MIN)
        lobes = _Lobes(hits, ns, ng, wo, ior, options.multiscatter, cover)
        # hits from inside a transmissive object see only Glass (light reaches them refracted)
        surface_lit = entering | (trans <= 0)
        reflective = surface_lit & (lobes.p_reflective > 0) & ~back
        nee_clamp = n_rough > 0
        # --- next-event estimation: the environment, MIS with BSDF sampling
        ua, ub = sample(px, s, _dim(K_ENV, depth))
        uc = sample.single(px, s, _dim(K_ENV_PICK, depth))
        ls = np.flatnonzero(reflective)
        if len(ls):
            wi = env_sampler.sample(ua[ls], ub[ls], uc[ls])
            fcos, p_b = lobes.eval(ls, wi)
            p_l = env_sampler.pdf(wi)
            good = fcos.max(axis=1) > 0
            ls, wi, fcos, p_b, p_l = ls[good], wi[good], fcos[good], p_b[good], p_l[good]
            if len(ls):
                vis = _timed(stats, "traversal", _unoccluded, ts, _off(p[ls], ng[ls], wi, eps), wi, np.full(len(ls), np.inf), px[ls], s, depth)
                mis = p_l ** 2 / (p_l ** 2 + p_b ** 2)
                contrib = w[ls] * fcos * (vis * mis / np.maximum(p_l, 1e-300))[:, None] \
                    * env.radiance(wi, np.zeros(len(wi)))
                out[slot[ls]] += _clamp(contrib, nee_clamp[ls])
        # --- next-event estimation: the emissive triangles, MIS with BSDF hits on them
        if em is not None:
            ls = np.flatnonzero(reflective)
            if len(ls):
                u_e = sample.single(px[ls], s, _dim(K_EMITTER_PICK, depth))
                ue1, ue2 = sample(px[ls], s, _dim(K_EMITTER_POINT, depth))
                contrib = _emitter_nee(ts, em, lobes, ls, p[ls], ng[ls], u_e, ue1, ue2, px[ls], s,
                                       depth, eps, stats)
                out[slot[ls]] += _clamp(w[ls] * contrib, nee_clamp[ls])
        # --- next-event estimation: punctual lights (deltas: no MIS; a USD light's extent is
        # sampled, one point a pass, and BSDF sampling cannot hit it: NEE alone again)
        if ts.lights is not None and len(ts.lights):
            ls = np.flatnonzero(reflective)
            for i in range(len(ts.lights)):
                if not len(ls):
                    break
                u_l = sample(px[ls], s, _dim(K_LIGHT, depth, i)) if ts.lights.extended(i) else None
                ldir, dist, radiance = _light(ts.lights, i, p[ls], u_l)
                fcos, _ = lobes.eval(ls, ldir)
                live = np.flatnonzero((fcos.max(axis=1) > 0) & (radiance.max(axis=1) > 0))
                if not len(live):
                    continue
                sel = ls[live]
                vis = _timed(stats, "traversal", _unoccluded, ts, _off(p[sel], ng[sel], ldir[live], eps), ldir[live], dist[live], px[sel], s, depth)
                out[slot[sel]] += _clamp(w[sel] * fcos[live] * radiance[live] * vis[:, None], nee_clamp[sel])
        # --- BSDF sampling: a layer (coat, sheen, base), then Metal, Plastic or Glass
        u_pick, u_lobe = sample(px, s, _dim(K_LOBE, depth))
        u1, u2 = sample(px, s, _dim(K_DIRECTION, depth))
        u_layer = sample.single(px, s, _dim(K_LAYER, depth))
        u_rr = sample.single(px, s, _dim(K_ROULETTE, depth)) if depth >= RR_START else u1
        glass_e = path_bsdf.glass_table() if options.multiscatter else _NO_TABLE
        args = (d, p, ng, ns, entering, surface_lit, thin, ior, alpha, w, medium,
                u_layer, u_pick, u_lobe, u1, u2, u_rr, depth >= RR_START, eps, options.multiscatter)
        if KERNEL:
            f8 = _f64
            nxt = lobes.kernel.scatter(lobes.packed, f8(d), f8(p), f8(ng), f8(ns), _b(entering), _b(surface_lit),
                                       _b(thin), f8(ior), f8(hits.roughness), f8(alpha), f8(hits.base), f8(w),
                                       f8(medium), f8(u_layer), f8(u_pick), f8(u_lobe), f8(u1), f8(u2), f8(u_rr),
                                       depth >= RR_START, eps, glass_e)
        else:
            nxt = _scatter_numpy(lobes.bsdf, hits, *args, lobes)
        o_all, new_d, new_w, new_pdf, new_medium, alive, rough, tir = nxt
        alive = alive & ~back  # shaded in closed form above
        if split:
            assert cover is not None
            go_w = np.where(cover < 1, 1.0 - cover, 0.0)
            off = (cover < 1) & (clear <= 0)  # met by a scattered path: as raytrace._pass_share
            if np.any(off):
                cos_o = np.abs(_dot(d[off], ng[off]))
                go_w[off] = np.minimum(go_w[off], 1.0 - fresnel_dielectric(cos_o, 1.0 / ior[off]))
            o_all, new_d, new_w, new_pdf, new_medium, alive, rough, clear = _pass_on(
                sample.single(px, s, _dim(K_PASS, depth)), cover, go_w, clear, p, d, w, medium, eps,
                (o_all, new_d, new_w, new_pdf, new_medium, alive, rough))
        stats["tir"] += int(np.sum(tir))
        clamp_esc = n_rough > 0
        n_rough = n_rough + rough
        keep = np.flatnonzero(alive)
        origins = o_all[keep]
        d, w, slot, medium = new_d[keep], new_w[keep], slot[keep], new_medium[keep]
        mis_pdf, clamp_esc, n_rough = new_pdf[keep], clamp_esc[keep], n_rough[keep]
        prev_x = p[keep]
        if split:
            clear = clear[keep]
    return out, hit0


PASS_MAX = 0.9  # most probability of going on through a premultiplied blend (the rest scatters)


def _pass_on(u: np.ndarray, cover: np.ndarray, go_w: np.ndarray, clear: np.ndarray, p, d, w,
             medium, eps: float, scattered: tuple) -> tuple:
    """At premultiplied blends (opacity `cover` < 1), the paths that go on straight through
    (carrying `go_w`: 1 - opacity, or less off the camera's line) instead of their sampled
    scatter (trace_pass), both reweighted; `clear` of the next segment (the camera's line
    kept only by those that go on)."""
    o_all, new_d, new_w, new_pdf, new_medium, alive, rough = (np.array(a) for a in scattered)
    go_p = np.where(cover < 1, np.minimum(1 - cover, PASS_MAX), 0.0)
    go = u < go_p
    scat = np.flatnonzero(~go & (go_p > 0))
    new_w[scat] /= (1 - go_p[scat])[:, None]
    g = np.flatnonzero(go)
    o_all[g] = p[g] + d[g] * eps
    new_d[g] = d[g]
    share = go_w[g] / go_p[g]
    new_w[g] = w[g] * share[:, None]
    new_pdf[g] = 0.0  # a delta: no MIS at what it meets
    new_medium[g] = medium[g]
    alive[g], rough[g] = True, False
    clear_out = np.zeros(len(cover))
    clear_out[g] = clear[g] * share
    return o_all, new_d, new_w, new_pdf, new_medium, alive, rough, clear_out


def _scatter_numpy(bsdf, hits, d, p, ng, ns, entering, surface_lit, thin, ior, alpha, w, medium,
                   u_layer, u_pick, u_lobe, u1, u2, u_rr, roulette: bool, eps: float, multiscatter: bool,
                   lobes):
    """path_kernel.scatter's numpy twin: the BSDF-sampling step of a bounce."""
    tir_all = np.zeros(len(d), bool)

    base_pick = u_layer >= bsdf.p_coat + bsdf.p_sheen
    glass = (base_pick & (u_pick >= bsdf.p_metal + bsdf.p_plastic)) | ~surface_lit
    new_d = np.zeros_like(d)
    new_w = w.copy()
    new_pdf = np.zeros(len(d))
    rough = np.zeros(len(d), bool)
    new_medium = medium.copy()
    alive = np.ones(len(d), bool)
    # the reflective components (and diffuse transmission)
    mp = np.flatnonzero(~glass)
    if len(mp):
        wi, rough[mp], valid, fcos, p_b = lobes.sample(mp, u_layer[mp], u_pick[mp], u_lobe[mp],
                                                      u1[mp], u2[mp])
        ok = (p_b > 0) & valid
        new_w[mp] = w[mp] * np.where(ok[:, None], fcos / np.maximum(p_b, 1e-300)[:, None], 0.0)
        new_d[mp] = wi
        # a near-delta lobe's pdf is huge and the environment pdf negligible: no MIS needed
        new_pdf[mp] = np.where(ok, p_b, 0.0)
        alive[mp] = ok
    # Glass: exact dielectric, conditioned on the choice (weight (1 - m) tr / P = 1)
    gl = np.flatnonzero(glass)
    if len(gl):
        eta = np.where(entering[gl], 1.0 / ior[gl], ior[gl])
        dg, ng_g = d[gl], ns[gl]
        smooth = hits.roughness[gl] <= 0
        r_dir = reflect(dg, ng_g)
        t_dir, tir = refract(dg, ng_g, eta)
        fres = fresnel_dielectric(np.clip(_dot(-dg, ng_g), 0.0, 1.0), eta)
        g_r = np.ones(len(gl))
        g_t = np.ones(len(gl))
        e_ss = np.ones(len(gl))
        rs = np.flatnonzero(~smooth)
        if len(rs):
            _, f_m, r_m, wr_m, t_m, wt_m, tir_m = sample_rough_dielectric(
                dg[rs], ng_g[rs], alpha[gl[rs]], eta[rs], u1[gl[rs]], u2[gl[rs]])
            r_dir[rs], t_dir[rs], tir[rs], fres[rs] = r_m, t_m, tir_m, f_m
            g_r[rs] = wr_m / np.maximum(f_m, 1e-30)
            g_t[rs] = wt_m / np.maximum(1 - f_m, 1e-30)
            if multiscatter:
                e_ss[rs] = path_bsdf.glass_albedo(np.clip(_dot(-dg[rs], ng_g[rs]), 0.0, 1.0), alpha[gl[rs]], eta[rs])
        sheet = thin[gl]
        if np.any(sheet):  # out through the sheet's parallel back face: unbent where smooth
            t_dir[sheet], tir_out = refract(t_dir[sheet], ng_g[sheet], ior[gl][sheet])
            t_dir[sheet & smooth] = dg[sheet & smooth]
            tir[sheet] |= tir_out
        fres = np.where(tir, 1.0, fres)
        # what is not transmitted of this component is the dielectric's reflection
        take_r = u_lobe[gl] < fres
        # sqrt(base) at each crossing of a volume, base once through a thin sheet (as the
        # kernel), and what bounced between the microfacets (path_bsdf.glass_ms)
        cross = np.where(sheet[:, None], hits.base[gl], np.sqrt(np.maximum(hits.base[gl], 0.0)))
        tint = np.where(take_r[:, None], 1.0, cross) * path_bsdf.glass_ms(e_ss[:, None], cross)
        # a surface seen from inside with no transmission still refracts out as glass
        new_d[gl] = np.where(take_r[:, None], r_dir, t_dir)
        factor = np.where(take_r, g_r, g_t * np.where(sheet, 1.0, eta * eta))
        # what the coat and sheen over it leave (from outside), over the choice's odds
        factor *= np.where(surface_lit[gl], bsdf.glass_w[gl], 1.0)
        new_w[gl] = w[gl] * tint * factor[:, None]
        new_medium[gl] = np.where(take_r | sheet, medium[gl], np.where(entering[gl], ior[gl], 1.0))
        new_pdf[gl] = 0.0
        rough[gl] = ~smooth & (alpha[gl] >= ROUGH_ALPHA)
        tir_all[gl] = tir
    # Russian roulette
    if roulette:
        q = np.clip(new_w.max(axis=1) * new_medium ** 2, 0.0, 1.0)
        survive = u_rr < q
        alive &= survive
        new_w = new_w / np.maximum(q, 1e-30)[:, None]
    alive &= new_w.max(axis=1) > 0
    side_t = np.where(_dot(new_d, ng) > 0, eps, -eps)
    return p + side_t[:, None] * ng, new_d, new_w, new_pdf, new_medium, alive, rough, tir_all


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64)


def _b(a) -> np.ndarray:
    return np.ascontiguousarray(a, np.bool_)


def _timed(stats: dict, key: str, fn, *args):
    """fn(*args), its wall time added to stats["split_ms"][key]."""
    t0 = time.perf_counter()
    try:
        return fn(*args)
    finally:
        stats["split_ms"][key] += (time.perf_counter() - t0) * 1e3


def _off(p: np.ndarray, ng: np.ndarray, wi: np.ndarray, eps: float) -> np.ndarray:
    """Shadow-ray origins off the surface on wi's side (diffuse transmission looks behind)."""
    return p + (np.where(_dot(wi, ng) >= 0, eps, -eps))[:, None] * ng


def _light(lights, i: int, p: np.ndarray, u=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(direction to light i, distance, incident radiance x attenuation) at points p (as
    renderer.methods.trace_lights, the raster's falloffs; with uniforms u, toward a sample of a
    light's extent: its soft shadow)."""
    ldir, dist, atten = trace_lights.falloff(lights, i, p, u)
    return ldir, dist, lights.color[i] * atten[:, None]


def _unoccluded(ts, o: np.ndarray, wi: np.ndarray, dist: np.ndarray, pix: np.ndarray,
                s: int, depth: int, dim: int | None = None) -> np.ndarray:
    """1 where nothing (alpha cut-outs and culled back faces excepted) lies within dist
    (`dim`: the alpha draws' stream, default _dim(K_SHADOW_ALPHA, depth))."""

    u_alpha = _Sampler().single(pix, s, _dim(K_SHADOW_ALPHA, depth) if dim is None else dim)
    prim, _, _, t = intersect_front(ts, o, wi, u_alpha, shadow=True)
    eps = EPSILON * ts.radius
    return ((prim < 0) | (np.asarray(t, np.float64) >= dist - 2 * eps)).astype(np.float64)


def _power(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The power heuristic's weight of the strategy of pdf a against that of pdf b (Veach 1995)."""
    return a * a / np.maximum(a * a + b * b, 1e-300)


def _emitter_pdf(em, j: np.ndarray, x: np.ndarray, dist2: np.ndarray, cos_e: np.ndarray) -> np.ndarray:
    """Solid-angle density, seen from x, of _emitter_nee drawing a point on emitter j at squared
    distance dist2 whose normal makes |cos_e| with the direction: the emitter's odds
    (trace_lights.emitter_odds, the tree's sampler) over its area, times dist2 / |cos_e|."""
    odds = trace_lights.emitter_odds(em, x, j)
    return odds / em.area[j] * dist2 / np.maximum(np.abs(cos_e), 1e-12)


def _emitter_hit_mis(em, prim: np.ndarray, d: np.ndarray, p: np.ndarray, prev_x: np.ndarray,
                     p_b: np.ndarray) -> np.ndarray:
    """Power-heuristic weights of emission met by BSDF-sampled rays (pdf p_b, left from
    prev_x) against _emitter_nee at prev_x; 1 off the light triangles and after a scatter
    with no NEE (p_b 0: camera rays, glass, a straight pass through a blend)."""
    wgt = np.ones(len(prim))
    j = em.index[prim]
    sel = np.flatnonzero((p_b > 0) & (j >= 0))
    if len(sel):
        j = j[sel]
        to = p[sel] - prev_x[sel]
        p_l = _emitter_pdf(em, j, prev_x[sel], _dot(to, to), _dot(d[sel], em.normal[j]))
        wgt[sel] = _power(p_b[sel], p_l)
    return wgt


def _emitter_nee(ts, em, lobes: _Lobes, rows: np.ndarray, x: np.ndarray, ng: np.ndarray,
                 u0: np.ndarray, u1: np.ndarray, u2: np.ndarray, pix: np.ndarray, s: int,
                 depth: int, eps: float, stats: dict) -> np.ndarray:
    """Next-event estimation toward the emissive triangles at hits x (the BSDF's `rows`): one
    point a path, the triangle drawn by trace_lights.emitter_choice (the Fresnel tree's
    sampler) from u0, uniform on it from (u1, u2); a shadow ray; f |cos| x emission (read at
    the point, textures included) over the point's solid-angle pdf, power-heuristic weighted
    against BSDF sampling (_emitter_hit_mis is the other half). Len(rows) x 3."""
    out = np.zeros((len(rows), 3))
    j, odds = trace_lights.emitter_choice(em, x, u0)
    r1 = np.sqrt(u1)
    bu, bv = r1 * (1 - u2), r1 * u2  # Embree's barycentrics of a uniform point
    to = em.p0[j] + bu[:, None] * em.e1[j] + bv[:, None] * em.e2[j] - x
    dist2 = _dot(to, to)
    dist = np.sqrt(dist2)
    ldir = to / np.maximum(dist, 1e-30)[:, None]
    cos_e = -_dot(ldir, em.normal[j])
    idx = np.flatnonzero((odds > 0) & (dist > 0) & (np.abs(cos_e) > 1e-9) & ((cos_e > 0) | em.two_sided[j]))
    if not len(idx):
        return out
    fcos, p_b = lobes.eval(rows[idx], ldir[idx])
    idx, fcos, p_b = (a[live] for a, live in zip((idx, fcos, p_b), [fcos.max(axis=1) > 0] * 3))
    if not len(idx):
        return out
    tri = em.tri[j[idx]].astype(np.int32)
    le = _timed(stats, "material", hit_material, ts, x[idx], ldir[idx], tri, bu[idx].astype(np.float32),
                bv[idx].astype(np.float32), dist[idx], False).emission
    live = le.max(axis=1) > 0
    idx, fcos, p_b, le = idx[live], fcos[live], p_b[live], le[live]
    if not len(idx):
        return out
    # off the surface by eps along ng, the ray meets the emitter up to eps / cos_e early
    short = dist[idx] - eps / np.maximum(np.abs(cos_e[idx]), 1e-3)
    vis = _timed(stats, "traversal", _unoccluded, ts, _off(x[idx], ng[idx], ldir[idx], eps), ldir[idx],
                 short, pix[idx], s, depth, _dim(K_EMITTER_ALPHA, depth))
    p_l = odds[idx] / em.area[j[idx]] * dist2[idx] / np.abs(cos_e[idx])
    mis = _power(p_l, p_b)
    out[idx] = fcos * le * (vis * mis / p_l)[:, None]
    return out


def trace(ts, sky, options: RenderOptions, camera, first_near: np.ndarray,
          stats: dict[str, Any], deadline: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Progressive passes over the pixels `first_near` (flat indices): (mean radiance per
    pixel, N x 3; coverage per pixel, N). Fills stats with passes, samples and timings.
    `deadline` (time.perf_counter seconds): no pass starts that the last one's time says would
    end past it (the first always runs); None: options.budget_ms from now."""

    t0 = time.perf_counter()
    env_sampler = EnvSampler(sky.baked.specular[0], sky.to_env)
    pixels = np.asarray(first_near, np.int64)
    npix = len(pixels)
    total = np.zeros((npix, 3))
    lum_sum = np.zeros(npix)
    lum_sq = np.zeros(npix)
    cover = np.zeros(npix)
    count = np.zeros(npix)
    active = np.ones(npix, bool)
    if deadline is None and options.budget_ms is not None:
        deadline = t0 + options.budget_ms / 1e3
    max_passes = int(options.samples)
    stats.update(rays=stats.get("rays", 0), tir=stats.get("tir", 0))
    # where a pass's time goes: ray casts (camera, bounce and shadow rays: Embree and the
    # alpha / back-face walk), the material at hits (textures: of which the texel fetches),
    # and the rest: BSDF, environment sampling, bookkeeping ("shading", filled in below)
    split = stats.setdefault("split_ms", {"traversal": 0.0, "material": 0.0, "textures": 0.0, "shading": 0.0})
    before = split["traversal"] + split["material"]  # a dispersive frame calls trace once per channel
    pass_ms: list[float] = []
    lum_w = np.array([0.2126, 0.7152, 0.0722])
    stop = "samples"
    r_, u_, f_ = camera.basis()
    th = math.tan(math.radians(camera.fov) / 2)
    rows, cols = np.divmod(pixels, camera.width)
    for s in range(max_passes):
        ps = time.perf_counter()
        idx = np.flatnonzero(active)
        jx, jy = _Sampler()(pixels[idx], s, _dim(K_JITTER, 0))
        sx = ((cols[idx] + jx) / camera.width * 2 - 1) * th * camera.aspect
        sy = (1 - (rows[idx] + jy) / camera.height * 2) * th
        dirs = f_ + sx[:, None] * r_ + sy[:, None] * u_
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
        rgb, first = trace_pass(ts, sky, options, np.asarray(camera.position, np.float64), dirs,
                         pixels[idx], s, env_sampler, stats)
        cover[idx] += first
        bad = ~np.isfinite(rgb).all(axis=1)
        if np.any(bad):
            stats["nonfinite"] = stats.get("nonfinite", 0) + int(bad.sum())
            rgb[bad] = 0.0
        total[idx] += rgb
        lum = rgb @ lum_w
        lum_sum[idx] += lum
        lum_sq[idx] += lum * lum
        count[idx] += 1
        pass_ms.append((time.perf_counter() - ps) * 1e3)
        if s + 1 >= MIN_PASSES:
            c = count[idx]
            mean = lum_sum[idx] / c
            var = np.maximum(lum_sq[idx] / c - mean * mean, 0.0) * c / np.maximum(c - 1, 1)
            rel = np.sqrt(var / c) / np.maximum(mean, 1e-3)
            active[idx[rel < options.noise]] = False  # under: noise 0 runs every pass
            if not active.any():
                stop = "noise"
                break
        if deadline is not None and time.perf_counter() + pass_ms[-1] / 1e3 > deadline:
            stop = "budget"
            break
    split["shading"] += sum(pass_ms) - (split["traversal"] + split["material"] - before)
    # a dispersive frame traces once per channel: passes and times add up over the channels,
    # samples_mean is a channel's mean, and a budget stop in any channel is the frame's
    k = stats.get("channels", 0)
    stats.update(channels=k + 1, passes=stats.get("passes", 0) + len(pass_ms),
                 samples_mean=(stats.get("samples_mean", 0.0) * k + (float(count.mean()) if npix else 0.0)) / (k + 1),
                 stop="budget" if stats.get("stop") == "budget" else stop,
                 pass_ms_max=max(stats.get("pass_ms_max", 0.0), max(pass_ms, default=0.0)),
                 path_ms=stats.get("path_ms", 0.0) + (time.perf_counter() - t0) * 1e3)
    safe = np.maximum(count, 1)
    return total / safe[:, None], cover / safe
