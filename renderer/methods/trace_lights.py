"""The asset's punctual lights (KHR_lights_punctual, USD lights mapped to them) in the ray
tracer, by next-event estimation: at every surface a path meets, a shadow ray to each light
and the BRDF the raster's shaders/punctual.glsl evaluates (Lambert diffuse under the GGX
lobe's directional albedo, GGX specular with Schlick Fresnel and Smith masking, the range
and cone falloffs). A punctual light is a delta: BSDF sampling can never hit it, so NEE alone
is unbiased and needs no MIS weight. Shadow rays pass alpha cut-outs and culled back faces as
camera rays do, pass a blended surface with probability 1 - alpha (a uniform draw per ray;
the tree tracer's cross a premultiplied one by 1 - opacity, untinted),
and go straight through transmissive surfaces scaled by transmission x (1 - metallic) x the
crossed texel's base colour c per thin sheet, x sqrt(c) per crossing of volume glass (so a
closed solid of one colour gives c, as its camera rays; the caustic a refracting surface
focuses is not traced).

USD lights with extent (Light.shape, issue 25) are sampled for visibility and irradiance, so
their shadows have penumbrae: each shadow ray goes to a point of a rect (uniform over its
area), a disk (uniform over its area), a cylinder (uniform over the half of its side that
faces the receiver) or a sphere (uniform in the solid angle of its visible cap), or along a
direction uniform in a distant light's cone of half-angle t. The radiometry is the punctual
light's: a rect or disk point emits with the whole light's profile (the spot's cone, range
and inverse square from that point), a sphere of radiance L = I / (pi r^2) seen in a cap of
half-angle a gives L x 2 pi (1 - cos a) x cos per sample (on average I cos / d^2, the point
light's value while the cap is above the horizon), a cylinder's side of radiance L = I /
(2 r l) (pi / 2) cos_e cos / d^2 (on average I / d^2 broadside), a cone E x 2 (1 - cos t) /
sin^2 t x cos (on average E cos, the directional light's value). Far from the light, or
unoccluded within a cap above the horizon, a receiver gets what the punctual light gives it.
The raster's light shadows
(renderer/raster/light_shadows.py) agree on all three; the path tracer's NEE
(renderer/methods/path_trace.py) is stopped by a transmissive surface.

Emissive triangles are lights too (`Emitters`, issue 30): the Fresnel tree samples a point on
one (chosen by power over distance, uniform over its area) per ray at every surface and
splits the glossy share with its mirror child, which also meets emitters, by roughness
(`mirror_share`; renderer.methods.raytrace, `_emitter_hits`). The path integrator draws from
the same `emitter_choice` at every non-specular vertex and weighs its samples against BSDF
hits by `emitter_odds` (renderer.methods.path_trace, `_emitter_nee`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.scene import Light

MAX_LAYERS = 8  # transmissive surfaces a shadow ray passes through


@dataclass
class Lights:
    kind: np.ndarray       # L int: 0 directional, 1 point, 2 spot
    position: np.ndarray   # L x 3
    axis: np.ndarray       # L x 3 direction the light travels
    range: np.ndarray      # L (inf: none)
    color: np.ndarray      # L x 3 colour x intensity
    cone: np.ndarray       # L x 2 angle scale, offset (as the raster's u_light_cone)
    shadow: np.ndarray     # L bool: casts shadows (UsdLux shadow:enable)
    shadow_color: np.ndarray  # L x 3: what shadowed light is multiplied by
    shape: np.ndarray | None = None  # L int: SHAPES' index of Light.shape (0: a point / direction)
    size: np.ndarray | None = None   # L x 2 Light.size
    right: np.ndarray | None = None  # L x 3 the light's x axis (a rect's width, a cylinder's length)
    up: np.ndarray | None = None     # L x 3 its y axis

    def __len__(self) -> int:
        return len(self.kind)

    def extended(self, i: int) -> bool:
        """Light i has an extent to sample."""
        return self.shape is not None and bool(self.shape[i])

    def narrow(self, i: int) -> bool:
        """Light i is a distant light's cone narrower than NARROW_CONE."""
        return (self.shape is not None and self.size is not None and SHAPES[int(self.shape[i])] == "cone"
                and float(self.size[i, 0]) < NARROW_CONE)


SHAPES = ("", "rect", "disk", "sphere", "cylinder", "cone")
# half-angle (radians, 0.57 degrees) under which a distant light's cone takes one sample a
# shadow ray, not every pair given: UsdLux's default 0.53 degree sun (half 0.0046) blurs a
# shadow 1 m from its caster by 9 mm
NARROW_CONE = 0.01


def lights_of(lights: list[Light], shadows: bool = True) -> Lights:
    """The lights as arrays; `shadows` False: none casts a shadow (RenderOptions.light_shadows)."""
    kind, pos, axis, rng, color, cone, right, up = [], [], [], [], [], [], [], []
    for light in lights:
        mtx = np.asarray(light.matrix, np.float64)
        a = -mtx[:3, 2]
        axis.append(a / max(float(np.linalg.norm(a)), 1e-12))
        right.append(mtx[:3, 0] / max(float(np.linalg.norm(mtx[:3, 0])), 1e-12))
        up.append(mtx[:3, 1] / max(float(np.linalg.norm(mtx[:3, 1])), 1e-12))
        kind.append({"directional": 0, "point": 1, "spot": 2}[light.type])
        pos.append(mtx[:3, 3])
        rng.append(float(light.range))
        color.append(np.asarray(light.color, np.float64) * light.intensity)
        scale = 1.0 / max(1e-3, math.cos(light.inner_cone) - math.cos(light.outer_cone))
        cone.append([scale, -math.cos(light.outer_cone) * scale])
    return Lights(np.asarray(kind, np.int64), np.asarray(pos, np.float64).reshape(-1, 3),
                  np.asarray(axis, np.float64).reshape(-1, 3), np.asarray(rng, np.float64),
                  np.asarray(color, np.float64).reshape(-1, 3), np.asarray(cone, np.float64).reshape(-1, 2),
                  np.asarray([shadows and light.shadow for light in lights], bool),
                  np.asarray([light.shadow_color for light in lights], np.float64).reshape(-1, 3),
                  np.asarray([SHAPES.index(light.shape) if light.shape in SHAPES and max(light.size) > 0
                              else 0 for light in lights], np.int64),
                  np.asarray([light.size for light in lights], np.float64).reshape(-1, 2),
                  np.asarray(right, np.float64).reshape(-1, 3), np.asarray(up, np.float64).reshape(-1, 3))


def ggx_spec(f0, alpha, n_v, n_l, n_h, v_h):
    """F D V of the GGX lobe (height-correlated Smith visibility), per row."""
    a2 = alpha * alpha
    d = a2 / (math.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)
    gv = n_l * np.sqrt(n_v * n_v * (1.0 - a2) + a2)
    gl = n_v * np.sqrt(n_l * n_l * (1.0 - a2) + a2)
    vis = 0.5 / np.maximum(gv + gl, 1e-12)
    f = f0 + (1.0 - f0) * ((1.0 - v_h) ** 5)[:, None]
    return f * (d * vis)[:, None]


def falloff(lights: Lights, i: int, p: np.ndarray, u: tuple[np.ndarray, np.ndarray] | None = None,
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unit direction to light i, distance, attenuation) at points p: inverse square with
    glTF's range window and the spot cone's smooth edge, as the raster's lights fall off;
    a directional light is at infinity, unattenuated. With uniforms `u` (two per point), a
    light with extent is sampled there (`_sample`): a point on it or a direction in its cone."""
    if u is not None and lights.extended(i):
        return _sample(lights, i, p, u)
    return _from(lights, i, p, lights.position[i])


def _from(lights: Lights, i: int, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """falloff of light i as if it sat at q (one point or one per p)."""
    if lights.kind[i] == 0:
        return np.broadcast_to(-lights.axis[i], p.shape).copy(), np.full(len(p), np.inf), np.ones(len(p))
    d = q - p
    dist2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    dist = np.sqrt(dist2)
    ldir = d / dist[:, None]
    atten = 1.0 / dist2
    if math.isfinite(lights.range[i]) and lights.range[i] > 0:
        r = dist2 / lights.range[i] ** 2
        atten *= np.clip(1.0 - r * r, 0.0, 1.0)
    if lights.kind[i] == 2:
        cd = -ldir @ lights.axis[i]
        s = np.clip(cd * lights.cone[i, 0] + lights.cone[i, 1], 0.0, 1.0)
        atten *= s * s
    return ldir, dist, atten


def _frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit rows a to an orthonormal frame (Duff et al. 2017)."""
    sign = np.where(a[:, 2] >= 0, 1.0, -1.0)
    k = -1.0 / (sign + a[:, 2])
    m = a[:, 0] * a[:, 1] * k
    b1 = np.stack([1.0 + sign * a[:, 0] ** 2 * k, sign * m, -sign * a[:, 0]], -1)
    b2 = np.stack([m, sign + a[:, 1] ** 2 * k, -a[:, 1]], -1)
    return b1, b2


def _in_cone(axis: np.ndarray, cos_max: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Unit directions uniform in the cones about unit rows `axis` of half-angle acos(cos_max)."""
    cos_t = 1.0 - u1 * (1.0 - cos_max)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2 * math.pi * u2
    b1, b2 = _frame(axis)
    return (b1 * (sin_t * np.cos(phi))[:, None] + b2 * (sin_t * np.sin(phi))[:, None]
            + axis * cos_t[:, None])


def _sample(lights: Lights, i: int, p: np.ndarray, u: tuple[np.ndarray, np.ndarray],
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """falloff's (direction, distance, attenuation) toward a sample of light i's extent (the
    module docstring's radiometry): colour x attenuation x cos is a one-sample estimate of
    what the light gives, whose mean is the punctual light's value where that is exact."""
    assert lights.shape is not None and lights.size is not None
    assert lights.right is not None and lights.up is not None
    u1, u2 = np.asarray(u[0], np.float64), np.asarray(u[1], np.float64)
    shape = SHAPES[int(lights.shape[i])]
    a, b = lights.size[i]
    if shape == "cone":
        t = min(float(a), math.pi / 2)
        axis = np.broadcast_to(-lights.axis[i], p.shape)
        ldir = _in_cone(axis, np.full(len(p), math.cos(t)), u1, u2)
        return ldir, np.full(len(p), np.inf), np.full(len(p), 2 * (1 - math.cos(t)) / math.sin(t) ** 2)
    c, right, up = lights.position[i], lights.right[i], lights.up[i]
    if shape == "sphere":
        to = c - p
        d2 = np.einsum("ij,ij->i", to, to)
        far = d2 > (a * 1.0001) ** 2  # inside the sphere: its centre (as the point light)
        dist_c = np.sqrt(d2)
        ldir_c, _, atten_c = _from(lights, i, p, c)  # the profile at the centre
        sin2 = np.where(far, a * a / np.maximum(d2, 1e-30), 0.0)
        cos_a = np.sqrt(np.maximum(0.0, 1.0 - sin2))
        ldir = np.where(far[:, None], _in_cone(ldir_c, cos_a, u1, u2), ldir_c)
        cos_l = np.einsum("ij,ij->i", ldir, ldir_c)
        # the nearer intersection with the sphere along ldir
        dist = dist_c * cos_l - np.sqrt(np.maximum(0.0, a * a - d2 * (1.0 - cos_l * cos_l)))
        dist = np.where(far, np.maximum(dist, 0.0), dist_c)
        atten = np.where(far, atten_c * d2 * 2.0 * (1.0 - cos_a) / (a * a), atten_c)
        return ldir, dist, atten
    if shape == "rect":
        q = c + ((u1 - 0.5) * a)[:, None] * right + ((u2 - 0.5) * b)[:, None] * up
        return _from(lights, i, p, q)
    if shape == "disk":
        r, phi = np.sqrt(u1), 2 * math.pi * u2
        q = c + (r * np.cos(phi) * a)[:, None] * right + (r * np.sin(phi) * b)[:, None] * up
        return _from(lights, i, p, q)
    # cylinder of radius a, length b along `right`: the half of its side facing p
    fwd = np.cross(right, up)
    rel = p - c
    phi0 = np.arctan2(rel @ fwd, rel @ up)
    phi = phi0 + math.pi * (u2 - 0.5)
    normal = np.cos(phi)[:, None] * up + np.sin(phi)[:, None] * fwd
    q = c + ((u1 - 0.5) * b)[:, None] * right + a * normal
    ldir, dist, atten = _from(lights, i, p, q)
    if a > 0:
        cos_e = np.maximum(-np.einsum("ij,ij->i", ldir, normal), 0.0)
        return ldir, dist, atten * (math.pi / 2) * cos_e
    # a line: its projected width goes as the sine from its axis (1 broadside)
    return ldir, dist, atten * np.sqrt(np.maximum(0.0, 1.0 - (ldir @ right) ** 2))


def direct(lights: Lights, occlusion_test, p: np.ndarray, n: np.ndarray, ng: np.ndarray,
           v: np.ndarray, base: np.ndarray, metallic: np.ndarray, roughness: np.ndarray,
           transmission: np.ndarray, ior: np.ndarray, spec_albedo,
           opacity: np.ndarray | None = None,
           samples: list[tuple[np.ndarray, np.ndarray]] | None = None,
           back: np.ndarray | None = None) -> np.ndarray:
    """N x 3 radiance reflected toward v (unit, pointing away from the surface) by surfaces at
    p (shading normal n and geometric normal ng both on v's side) from every light.
    `occlusion_test(origins, dirs, dist, normals)` -> N x 3 transmittance of the segments
    (rays leave off the surface along `normals`);
    `spec_albedo(f0, cos_v, roughness)` -> (single-scattering, total) N x 3 directional
    albedos of the lobe: the diffuse base gets what the total leaves, and the lobe is scaled
    by total / single (its multiple scattering, as the raster). `opacity` (per hit, None: 1)
    scales the diffuse share alone: a premultiplied blend's (its specular stays whole).
    `samples`: pairs of uniforms per point; a light with extent takes the mean over one sample
    of it per pair (falloff; a narrow cone the first pair only), None: every light a point or
    a direction. `back` (per hit, None: none): Storm's single-sided back faces (core.storm),
    n and ng the authored normals facing away from v: no specular (N.E = 0), the diffuse
    x (1 - F(V.H))."""
    out = np.zeros((len(p), 3))
    n_v = np.clip(np.einsum("ij,ij->i", n, v), 1e-4, 1.0)
    dielectric = ((ior - 1) / (ior + 1)) ** 2
    f0 = dielectric[:, None] * (1 - metallic[:, None]) + base * metallic[:, None]
    e_ss, e_spec = spec_albedo(f0, n_v, roughness)
    ms_scale = e_spec / np.maximum(e_ss, 1e-4)
    diffuse = base * ((1 - metallic) * (1 - transmission))[:, None] / math.pi * (1 - e_spec)
    if opacity is not None:
        diffuse = diffuse * opacity[:, None]
    alpha = np.maximum(roughness * roughness, 1e-3)
    for i in range(len(lights)):
        draws: list = list(samples) if samples and lights.extended(i) else [None]
        if lights.narrow(i):  # a sun-sized disc: one sample is enough for its sliver of penumbra
            draws = draws[:1]
        for u in draws:
            ldir, dist, atten = falloff(lights, i, p, u)
            n_l = np.einsum("ij,ij->i", n, ldir)
            lit = np.flatnonzero((n_l > 0) & (atten > 0) & (np.einsum("ij,ij->i", ng, ldir) > 0))
            if not len(lit):
                continue
            if lights.shadow[i]:
                vis = occlusion_test(p[lit], ldir[lit], dist[lit], ng[lit])
                vis = vis + (1.0 - vis) * lights.shadow_color[i]  # shadowed light tinted, not black
            else:
                vis = np.ones((len(lit), 3))
            h = ldir[lit] + v[lit]
            h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
            n_h = np.clip(np.einsum("ij,ij->i", n[lit], h), 0.0, 1.0)
            v_h = np.clip(np.einsum("ij,ij->i", v[lit], h), 0.0, 1.0)
            spec = ggx_spec(f0[lit], alpha[lit], n_v[lit], n_l[lit], n_h, v_h) * ms_scale[lit]
            lobe = diffuse[lit]
            if back is not None and back[lit].any():
                b = back[lit]
                spec[b] = 0.0
                fresnel = f0[lit][b] + (1 - f0[lit][b]) * ((1 - v_h[b]) ** 5)[:, None]
                lobe = lobe.copy()
                lobe[b] = lobe[b] / np.maximum(1 - e_spec[lit][b], 1e-6) * (1 - fresnel)
            radiance = lights.color[i] * (atten[lit] / len(draws))[:, None]
            out[lit] += (lobe + spec) * radiance * (n_l[lit])[:, None] * vis
    return out


LOCAL_EMITTERS = 256   # up to this many emissive triangles, each point weighs them by distance
_CHUNK = 1 << 22       # points x emitters weighed at once


@dataclass
class Emitters:
    """The emissive triangles as area lights: a point uniform on a triangle chosen by
    `emitter_choice`."""
    tri: np.ndarray        # E triangle indices
    p0: np.ndarray         # E x 3 corner 0 (world)
    e1: np.ndarray         # E x 3 corner 1 - corner 0
    e2: np.ndarray         # E x 3 corner 2 - corner 0
    normal: np.ndarray     # E x 3 unit geometric normal (winding order)
    two_sided: np.ndarray  # E bool: emits from its back as well (double-sided material)
    area: np.ndarray       # E
    power: np.ndarray      # E luminance of emissive factor x strength x area (x 2 two-sided)
    cdf: np.ndarray        # E cumulative power share (last 1)
    index: np.ndarray      # T the emitter of every triangle (-1: not a light)

    def __len__(self) -> int:
        return len(self.tri)


def emitters_of(tri: np.ndarray, material: np.ndarray, emission: np.ndarray, lit: np.ndarray,
                two_sided: np.ndarray) -> Emitters | None:
    """Emitters of a T x 3 x 3 world triangle soup (material per triangle; per material the
    emissive radiance, whether it is a light (unlit colours are not: they are shown, not
    shone) and whether it has two sides), or None when nothing emits. A texture can only
    darken the factor: the power is an upper bound, the emission is read at the point."""
    lum = emission @ np.array([0.2126, 0.7152, 0.0722]) * lit
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    cross = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(cross, axis=-1)
    power = lum[material] * area * np.where(two_sided[material], 2.0, 1.0)
    sel = np.flatnonzero(power > 0)
    if not len(sel):
        return None
    cdf = np.cumsum(power[sel])
    index = np.full(len(tri), -1, np.int64)
    index[sel] = np.arange(len(sel))
    return Emitters(sel, tri[sel, 0].astype(np.float64), e1[sel].astype(np.float64),
                    e2[sel].astype(np.float64), cross[sel] / (2 * area[sel, None]),
                    two_sided[material[sel]], area[sel], power[sel], cdf / cdf[-1], index)


def _weights(em: Emitters, x: np.ndarray) -> np.ndarray:
    """N x E unnormalised odds of each emitter seen from points x: its power over the squared
    distance to its centroid (at least its area, so a point on a big one does not single it
    out), 0 where a one-sided emitter turns its back (it cannot light x)."""
    centre = em.p0 + (em.e1 + em.e2) / 3.0
    to = centre[None, :, :] - x[:, None, :]
    d2 = np.maximum(np.einsum("nej,nej->ne", to, to), em.area[None, :])
    front = em.two_sided[None, :] | (np.einsum("nej,ej->ne", x[:, None, :] - em.p0[None], em.normal) > 0)
    return np.where(front, em.power[None, :] / d2, 0.0)


KERNEL = True  # the local odds compiled (trace_kernel.emitter_pick; False: the numpy `_weights`)


def _compiled(em: Emitters, x: np.ndarray, u: np.ndarray, pick: bool):
    from renderer.methods import trace_kernel  # numba loads only in a process that traces
    return trace_kernel.emitter_pick(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(u, np.float64),
                                     em.p0 + (em.e1 + em.e2) / 3.0, em.p0, em.normal, em.area,
                                     em.power, em.two_sided, pick)


def emitter_choice(em: Emitters, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(emitter index, its choice probability) for points x and uniforms u: with up to
    LOCAL_EMITTERS triangles by `_weights` (the nearer and brighter, the likelier: a grey
    card between two emitters samples mostly the near one), else by power alone. A point
    that no emitter can light gets index 0 and probability 0."""
    if len(em) > LOCAL_EMITTERS:
        j = np.minimum(np.searchsorted(em.cdf, u, side="right"), len(em) - 1)
        return j, em.power[j] / em.power.sum()
    if KERNEL:
        return _compiled(em, x, u, True)
    j, prob = np.zeros(len(x), np.int64), np.zeros(len(x))
    step = max(1, _CHUNK // len(em))
    for a in range(0, len(x), step):
        w = _weights(em, x[a:a + step])
        cum = np.cumsum(w, axis=1)
        total = cum[:, -1]
        pick = np.minimum((cum < (u[a:a + step] * total)[:, None]).sum(axis=1), len(em) - 1)
        j[a:a + step] = pick
        prob[a:a + step] = np.where(total > 0, w[np.arange(len(pick)), pick] / np.maximum(total, 1e-300), 0.0)
    return j, prob


def emitter_odds(em: Emitters, x: np.ndarray, j: np.ndarray) -> np.ndarray:
    """The probability emitter_choice gives emitter j[i] from point x[i]."""
    if len(em) > LOCAL_EMITTERS:
        return em.power[j] / em.power.sum()
    if KERNEL:
        return _compiled(em, x, j.astype(np.float64), False)[1]
    out = np.zeros(len(x))
    step = max(1, _CHUNK // len(em))
    for a in range(0, len(x), step):
        w = _weights(em, x[a:a + step])
        total = w.sum(axis=1)
        out[a:a + step] = w[np.arange(len(w)), j[a:a + step]] / np.maximum(total, 1e-300)
    return out


MIRROR_ROUGH = (0.15, 0.3)  # roughness up to which the mirror child takes a light's glossy share, from which NEE does


def mirror_share(roughness):
    """Of the glossy light from the emitters, the share the tree's mirror child counts (the
    rest is the emitter samples'): 1 up to MIRROR_ROUGH[0], 0 from MIRROR_ROUGH[1], linear
    between. The same at every direction, so the two never count one light twice. The mirror
    child stands for its whole lobe as if the emitter filled it: near exact on a narrow lobe,
    where emitter samples are noisy (a GGX lobe of roughness 0.05 sampled at 9 points a pixel
    missed a quarter of the highlight); the samples are exact on a wide one, where the mirror
    would show a sharp emitter in a blurred highlight."""
    lo, hi = MIRROR_ROUGH
    return np.clip((hi - np.asarray(roughness, np.float64)) / (hi - lo), 0.0, 1.0)
