"""The slow, accurate method: Whitted-style ray tracing with Embree through the real triangles.

Every instance of every mesh is put into one Embree scene in world space. Rays are traced a
bounce at a time, all rays of a bounce in one Embree call (no per-pixel Python loop). At each
surface the ray splits deterministically into a reflected and a refracted child weighted by
the exact dielectric Fresnel reflectance (total internal reflection included: F = 1); a
child is traced on while its weight is above `MIN_WEIGHT`, so the image has no noise. With
`fresnel_split="sample"` the tree is pruned past the first surface a camera ray meets: one
child goes on, reflected with probability P proportional to what it carries (max over RGB)
and weighted 1 / P, refracted otherwise and weighted 1 / (1 - P): unbiased, about half the
rays at 8 bounces, noise averaged by the supersampling (choices stratified over a pixel's
rays and hashed from pixel and bounce: the same frame each time). `fresnel_split="roulette"`
keeps both children but lets one that carries under ROULETTE (10%) go on only with
probability weight / ROULETTE, reweighted: the strong paths stay noise-free and the tree of
faint internal reflections is pruned (0.6-0.7x the rays of "both" at 8 bounces).
Rays that escape read the environment cubemap (env.specular[0], or the mip for the roughness
they have gathered). Rays still alive after `options.bounces` surfaces read the environment
in their current direction: with bounces=1 this is the single-refraction method, with 2 the
exact two-interface result that Wyman's method approximates.

Materials (kd + kr + ks = 1, the paper's split): metallic m reflects m * EnvBRDF(F0 = base
colour), the split-sum albedo from the bake's LUT plus, with `multiscatter` (the default), the
multiply scattered share (Fdez-Aguera 2019, as shaders/ibl.glsl); the dielectric rest (1 - m)
reflects F (exact Fresnel at the IOR; on a rough surface seen from outside scaled by the
lobe's directional albedo relative to a smooth one's, compensated alike), transmits
(1 - F) * transmission * base colour times eta^2 (radiance scales with n^2 across an interface:
it cancels on a way in and out, and matters for a camera inside the glass) and scatters the
remainder diffusely. Rough glass (`rough_lobes="sample"`, the default) is traced through its
lobes: each ray draws a GGX visible microfacet normal (Heitz 2018, alpha = roughness^2 as
Mitsuba's roughdielectric with its default sample_visible) from a per-pixel Owen-scrambled
Sobol set, and reflects and refracts about it with Walter et al.'s weights, exact Fresnel on
the microfacet (TIR included) times the Smith G1 of the way out (tests/test_rough_dielectric.py
checks them against quadrature of the BSDF): it converges to Mitsuba's rough dielectric. With
`rough_lobes="prefilter"`, and always for metals and the diffuse share, lobes are not traced:
the diffuse share reads the baked SH irradiance about the normal (the raster's ambient); a rough
refraction keeps its refracted direction and a rough reflection escapes along its lobe's
dominant direction (Lagarde & de Rousiers 2014, as shaders/ibl.glsl), each reading at escape
the prefiltered mip for the lobe width gathered along the path (as the raster path's split-sum
does; refraction lobes are narrower by |1 - eta| / 2). The rough reflection child travels along a
direction drawn from its GGX lobe (`ROUGH_PROBE`; the pixel's stratified set): geometry in
part of a wide lobe is met by that part of the pixel's rays, and a ray that escapes still reads
the whole lobe's prefiltered light along the dominant direction (carried as its `look`): no
noise on open surfaces, biased as the split sum is. Inside a volume, Beer-Lambert
attenuation exp(-sigma t) with sigma = -ln(attenuation_color) / attenuation_distance.
Thin-walled materials (glTF: no KHR_materials_volume, or thickness 0) have no inside: every
hit counts as from outside (Fresnel at 1 / IOR, tinted by base colour, nothing absorbed, the
medium unchanged) and the transmitted ray leaves as through a slab of parallel faces: unbent
on a smooth sheet; refracted in about the sampled microfacet and out through the surface on a
rough one.
Single-sided opaque materials are invisible from behind (rays pass through their back faces,
as raster culling does); transmissive ones keep both sides (rays inside glass meet back
faces). Emissive surfaces add their emission wherever a path meets them, and light the
surfaces the rays meet by next-event estimation (`_emitter_hits`: a point on an emissive
triangle a ray, a shadow ray, the diffuse share in full and the glossy share weighed against the
mirror child by roughness; docs/raytrace.md, "Emitters as lights"; the path integrator samples
them with the same sampler, MIS-weighted: path_trace._emitter_nee).

The material at a hit is the baked one the raster reads (renderer.methods.trace_material):
factors times base colour, metal-rough, normal (baked tangents), occlusion, emissive and
transmission textures, each with its KHR_texture_transform, UV set and sampler, trilinear on
the baked mips at the ray cone's footprint, times vertex colours; alpha MASK cuts rays
through, BLEND lets them through with probability 1 - alpha (stratified per pixel); a
premultiplied BLEND (USD, as Storm) is split: opacity x diffuse + the whole reflection, and
a ray of 1 - opacity straight on (docs/raytrace.md "Premultiplied blends"). Occlusion
scales the diffuse share, which reads the environment without visibility (as the raster's
ambient term). The asset's punctual lights are added by next-event estimation at every
surface a path meets (renderer.methods.trace_lights). KHR_materials_specular tints and scales
the dielectric's Fresnel on the way in (optics.specular_tint, factor and colour textures
included). Not yet traced: the clearcoat, sheen, iridescence, anisotropy and
diffuse-transmission lobes (their factors and textures are ignored here; the raster has them).

Anti-aliasing: `supersample` x `supersample` stratified rays per pixel (box filter) on and
around the object, so silhouettes and the strongly minified refracted environment average
over the pixel as the reference's box filter does (a deterministic grid: no noise). Measured
on the IOR 1.5 sphere at 500 px against Mitsuba: relative error 0.038 with one ray per pixel,
0.024 with 2 x 2, 0.022 with 3 x 3 at twice the time; at 128 px 2 x 2 leaves 0.08-0.17 on the
ellipsoid and bunny and 4 x 4 halves it, so small frames get more (`default_supersample`). Pixels
whose centre ray and its 8 neighbours miss everything keep one ray: a sub-pixel object
between centre rays is missed (documented limit). `supersample` (RenderOptions) overrides the
grid; `aa_threshold` > 0 traces 2 x 2 first and the full grid only where those disagree.
With the default grid, pixels whose centre ray meets rough glass (sampled lobes) get
ROUGH_EXTRA more rays a side: their lobes are sampled with the pixel's rays.

Speed: the per-surface work of a bounce (normals, Fresnel, lobes, children) runs in one
compiled loop (renderer.methods.trace_kernel, numba; `_shade_numpy` is its numpy twin, the reference
it is tested against), as do the material at the hits (renderer.methods.material_kernel) and the
environment reads, each over the cores in a fixed number of chunks (the outputs packed in row
order: the same frame at any thread count); Embree casts each bounce's rays from two threads.
"""
from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
import threading
import time
from collections import OrderedDict
from typing import Any

import numpy as np

from core import storm
from core.baked import BakedAsset, BakedEnvironment
from core.cubemap import env_rotation_matrix, sample_cube
from core.mips import texture_size_for
from core.options import RenderOptions, apply_override, background_rgb
from renderer.frame import Frame, FrameTimings, alpha_is_mask, tonemap_srgb8
from renderer.methods import env_irradiance, path_bsdf, trace_lights, trace_material
from renderer.methods.optics import (
    dominant_direction,
    fresnel_dielectric,
    ggx_visible_normal,
    reflect,
    refract,
    sample_rough_dielectric,
    specular_tint,
)
from renderer.methods.trace_scene import (
    EPSILON,
    TraceScene,
    hit_material,
    intersect_front,
    opacity,
    pixel_shift,
    storm_back,
    storm_back_faces,
)
from renderer.methods.trace_scene import sobol_samples as _pixel_samples
from renderer.raster.final import GRADIENT
from renderer.view.camera import Camera
from renderer.view.framing import asset_camera

log = logging.getLogger(__name__)

MIN_WEIGHT = 1e-3      # children below this throughput (max over RGB) are not traced
ROULETTE = 0.1         # fresnel_split="roulette": weaker children go on with P = weight / this
CHUNK_PIXELS = 1 << 18  # supersampled pixels traced together: bounds memory at any size
KERNEL = True          # shade hits with the compiled trace_kernel (False: the numpy twin)
ROUGH_EXTRA = 1        # the default grid's extra rays a side on pixels whose centre meets rough glass
LIGHT_SAMPLES = 4      # shadow rays a camera ray's first surface sends to a light with extent (1 deeper)
EMITTER_SAMPLES = 1    # points on emissive triangles per ray at every surface (0: emitters light nothing)
# A rough reflection (not a sampled glass lobe) reads the prefiltered sky along its lobe's
# dominant direction when it escapes; with ROUGH_PROBE > 0 it travels along a direction drawn
# from the lobe (GGX visible normals of alpha sqrt(ROUGH_PROBE)), so that geometry in part of
# a wide lobe is met by that part of a pixel's rays. 0: it travels the dominant direction.
ROUGH_PROBE = 1.0


_NO_TABLE = np.zeros((0, 1, 1, 1))  # trace_kernel.shade's "no glass albedo compensation"
_NO_BENT = np.zeros((0, 6))  # trace_kernel.shade's "no bent normals"


def _kernel():
    """renderer.methods.trace_kernel, or None with KERNEL off. Imported on first use: numba's import
    and loading the cached machine code are heavy, and a process that never ray traces skips them."""
    if not KERNEL:
        return None
    from renderer.methods import trace_kernel
    return trace_kernel


def build_scene(asset: BakedAsset, options: RenderOptions = RenderOptions()) -> TraceScene:
    """Transform every instance into world space and hand the triangles to Embree."""
    from embreex import rtcore_scene as rtcs  # Embree loads only in a process that traces
    from embreex.mesh_construction import TriangleMesh

    tris, nrms, mats, tables, parts, materials = [], [], [], [], [], []
    verts, faces, n_verts = [], [], 0  # the indexed form Embree is given
    for k, mesh in enumerate(asset.meshes):
        mat = apply_override(mesh.material, options.override)
        materials.append(mat)
        # unlit (KHR_materials_unlit): its colour is emitted (trace_material), and IOR 1
        # with no transmission leaves no reflection or diffuse share
        tables.append((mat.base_color[:3], mat.metallic, mat.roughness, mat.transmission,
                       1.0 if mat.unlit else mat.ior, mat.absorption(), not (mat.double_sided or mat.show_back_faces) and mat.transmission <= 0,
                       np.asarray(mat.emissive, np.float64) * mat.emissive_strength,
                       # a premultiplied blend is a sheet too: no inside (no TIR between its sides)
                       (mat.thin_walled and mat.transmission > 0)
                       or (mat.alpha_mode == "BLEND" and mat.opacity_premultiplied)))
        idx = mesh.indices.astype(np.int64)
        for m in mesh.transforms:
            m = np.asarray(m, np.float64)
            p = mesh.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
            normal_matrix = np.linalg.inv(m[:3, :3]).T
            n = mesh.normals.astype(np.float64) @ normal_matrix.T
            if np.linalg.det(m[:3, :3]) < 0:  # a mirroring transform flips the winding
                idx_w = idx[:, ::-1]
            else:
                idx_w = idx
            tris.append(p[idx_w])
            verts.append(p)
            faces.append(idx_w + n_verts)
            n_verts += len(p)
            parts.append((k, idx_w, m[:3, :3]))
            nrms.append(n[idx_w])
            mats.append(np.full(len(idx), k, np.int32))
    tri = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    nrm = np.concatenate(nrms) if nrms else np.zeros((0, 3, 3))
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-20)
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ng_len = np.linalg.norm(ng, axis=-1, keepdims=True)
    ng = np.where(ng_len > 0, ng / np.maximum(ng_len, 1e-30), nrm.mean(axis=1))
    # Degenerate or missing vertex normals fall back to the face normal.
    bad = ~np.isfinite(nrm).all(axis=-1) | (np.linalg.norm(nrm, axis=-1) < 0.5)
    nrm[bad] = np.broadcast_to(ng[:, None, :], nrm.shape)[bad]
    scene, cached = _embree_scene(np.concatenate(verts) if verts else np.zeros((0, 3)),
                                  np.concatenate(faces) if faces else np.zeros((0, 3), np.int64),
                                  rtcs, TriangleMesh)
    lo, hi = np.asarray(asset.bounds, np.float64)
    col = list(zip(*tables)) if tables else [[]] * 9
    surface = trace_material.build_surface(asset, materials, parts, tri,
                                           texture_size_for(max(options.width, options.height)))
    material = np.concatenate(mats) if mats else np.zeros(0, np.int32)
    emission = np.asarray(col[7], np.float64).reshape(-1, 3)
    emitters = trace_lights.emitters_of(tri, material, emission,
                                        np.asarray([not m.unlit for m in materials], bool),
                                        ~np.asarray(col[6], bool)) if len(material) else None
    return TraceScene(
        embree=scene, normals=nrm.astype(np.float32), geo_normals=ng.astype(np.float32),
        material=material,
        base=np.asarray(col[0], np.float64).reshape(-1, 3),
        metallic=np.asarray(col[1], np.float64), roughness=np.asarray(col[2], np.float64),
        transmission=np.asarray(col[3], np.float64), ior=np.asarray(col[4], np.float64),
        sigma=np.asarray(col[5], np.float64).reshape(-1, 3), culled=np.asarray(col[6], bool),
        emission=emission, thin=np.asarray(col[8], bool),
        radius=max(float(np.linalg.norm(hi - lo)) / 2, 1e-6), surface=surface, embree_cached=cached,
        premultiplied=np.asarray([m.alpha_mode == "BLEND" and m.opacity_premultiplied
                                  for m in materials], bool),
        storm_back=storm_back_faces(materials), emitters=emitters,
        sprite=np.asarray([m.face_viewer for m in materials], bool))


# Built Embree scenes by the digest of their world-space vertices and faces: the service renders
# many frames of one asset, and embreex copies vertices one by one (36k triangles: ~23 ms as
# 19k indexed vertices, ~40 ms as a triangle soup; the BVH build after it ~10 ms, quiet machine). Keyed on content, not on the asset key, so that no edit of a
# mesh (or a test asset reusing a key) can be served a stale scene. Embree traces a committed
# scene from any number of threads.
# Bounded by bytes, not by count: one 1M-triangle scene weighs as much as fifteen small ones,
# and a worker that kept its last four big ones held hundreds of MiB after its jobs.
EMBREE_CACHE_BYTES = 48 * 2**20  # least recently used out; a scene weighing more is used, not kept
# What a built scene holds (vertices, faces, BVH): RSS grew by 4.5 MiB for 36k triangles,
# 17 MiB for 250k, 75 MiB for 1M (embreex; bench/RESULTS.md, "AO: emitters do not occlude").
SCENE_FIXED_BYTES, SCENE_TRIANGLE_BYTES = 2**20, 80
_embree_cache: OrderedDict[bytes, tuple[Any, int]] = OrderedDict()
_embree_lock = threading.Lock()


def clear_scene_cache() -> None:
    """Forget the built Embree scenes (benchmarks time a frame's scene build as Mitsuba's load)."""
    with _embree_lock:
        _embree_cache.clear()


def _embree_scene(vertices: np.ndarray, faces: np.ndarray, rtcs, mesh_type) -> tuple[Any, bool]:
    """(EmbreeScene of the indexed mesh: V x 3 world vertices, T x 3 faces into them, whether it
    came from the cache). Primitive ids and barycentrics are those of the triangles in face
    order, as a triangle soup of the same faces gives."""
    vertices = np.ascontiguousarray(vertices, np.float32)
    faces = np.ascontiguousarray(faces, np.int32)
    digest = hashlib.blake2b(vertices.tobytes(), digest_size=16)
    digest.update(faces.tobytes())
    key = digest.digest() + repr((vertices.shape, faces.shape)).encode()
    with _embree_lock:
        kept = _embree_cache.get(key)
        if kept is not None:
            _embree_cache.move_to_end(key)
            return kept[0], True
    scene = rtcs.EmbreeScene()
    if len(faces):
        mesh_type(scene, vertices, faces)
        # commit (Embree builds its BVH on the first query) before the scene is shared
        scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), output=1)
    weight = scene_bytes(len(faces))
    if weight <= EMBREE_CACHE_BYTES:
        with _embree_lock:
            _embree_cache[key] = (scene, weight)
            while sum(w for _, w in _embree_cache.values()) > EMBREE_CACHE_BYTES:
                _embree_cache.popitem(last=False)
    return scene, False


def scene_bytes(triangles: int) -> int:
    """The weight of a built Embree scene of `triangles` in the scene cache."""
    return SCENE_FIXED_BYTES + SCENE_TRIANGLE_BYTES * triangles


def cached_scene_bytes() -> int:
    """What the kept Embree scenes weigh together."""
    with _embree_lock:
        return sum(w for _, w in _embree_cache.values())


class _Environment:
    """The baked environment as the tracer reads it: prefiltered radiance along world
    directions (turned by RenderOptions.env_rotation) and the split-sum LUT."""

    def __init__(self, env: BakedEnvironment, rotation_degrees: float = 0.0):
        self.baked = env
        self.to_env = (None if rotation_degrees % 360.0 == 0.0
                       else env_rotation_matrix(rotation_degrees))
        self._net: np.ndarray | None = None  # env_irradiance's net, found once a frame
        self._levels: Any = None  # trace_kernel.cube_levels of the specular mips

    def radiance(self, d: np.ndarray, roughness: np.ndarray) -> np.ndarray:
        if self.to_env is not None:
            d = d @ self.to_env.T
        if not KERNEL or not all(f.ndim == 4 and f.shape[3] == 3 and f.dtype == np.float32
                                 for f in self.baked.specular):
            return _env(self.baked, d, roughness)
        from renderer.methods import env_kernel  # numba loads only in a process that traces
        if self._levels is None:  # the mips as one list for the kernel, once a frame
            self._levels = env_kernel.cube_levels(self.baked.specular)
        return env_kernel.sample_env(self._levels, np.ascontiguousarray(d, np.float64),
                                     np.ascontiguousarray(roughness, np.float64), env_kernel.S_AXIS,
                                     env_kernel.S_SIGN, env_kernel.T_AXIS, env_kernel.T_SIGN)

    def irradiance(self, n: np.ndarray) -> np.ndarray:
        """Irradiance / pi about unit normals n: what a white Lambertian surface reflects,
        integrated from the cube's texels (env_irradiance: the bake's order-2 SH, which the
        raster's ambient term reads, is 1-3% off per channel on coloured skies). The roughest
        GGX mip is not this either: its lobe is narrower than the cosine and, under a blue sky,
        gave flat boards facing the horizon a blue cast (+14% blue on footprint_court)."""
        if self.to_env is not None:
            n = n @ self.to_env.T
        if self._net is None:  # net_for digests the cube to find its net: not every bounce
            self._net = env_irradiance.net_for(self.baked)
        return env_irradiance.read(self._net, n)

    def split_sum(self, cos_v: np.ndarray, roughness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(scale, bias) for F0, bilinear in the LUT (texel centres at (i + 0.5) / N)."""
        lut = np.asarray(self.baked.brdf_lut, np.float64)
        n_r, n_v = lut.shape[:2]
        x = np.clip(cos_v * n_v - 0.5, 0, n_v - 1)
        y = np.clip(roughness * n_r - 0.5, 0, n_r - 1)
        x0, y0 = np.minimum(x.astype(int), n_v - 2), np.minimum(y.astype(int), n_r - 2)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        top = lut[y0, x0] * (1 - fx) + lut[y0, x0 + 1] * fx
        bottom = lut[y0 + 1, x0] * (1 - fx) + lut[y0 + 1, x0 + 1] * fx
        ab = top * (1 - fy) + bottom * fy
        return ab[:, 0], ab[:, 1]

    def specular_albedo(self, f0: np.ndarray, cos_v: np.ndarray, roughness: np.ndarray,
                        multiscatter: bool) -> np.ndarray:
        """N x 3 directional albedo of the GGX lobe: FssEss (+ FmsEms), as shaders/ibl.glsl."""
        a, b = self.split_sum(cos_v, roughness)
        fss = f0 * a[:, None] + b[:, None]
        if not multiscatter:
            return fss
        ems = (1.0 - (a + b))[:, None]
        favg = f0 + (1.0 - f0) / 21.0
        return fss + ems * fss * favg / np.maximum(1.0 - ems * favg, 1e-6)


def _env(env: BakedEnvironment, d: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """Radiance from direction d, from the prefiltered mip for `roughness` (linear between
    mips; mip m holds roughness m / (levels - 1)); trace_kernel.sample_env is its compiled twin."""
    levels = len(env.specular)
    lod = np.clip(roughness, 0.0, 1.0) * (levels - 1)
    out = np.zeros((len(d), 3), np.float64)
    lo = np.floor(lod).astype(int)
    frac = lod - lo
    for level in np.unique(lo):
        sel = lo == level
        c = _cube(env.specular[level], d[sel])
        f = frac[sel]
        if level + 1 < levels and np.any(f > 0):
            c = c * (1 - f[:, None]) + _cube(env.specular[level + 1], d[sel]) * f[:, None]
        out[sel] = c
    return out


def _cube(faces: np.ndarray, d: np.ndarray) -> np.ndarray:
    """core.cubemap.sample_cube as float64, compiled where the kernel is on."""
    k = _kernel()
    if k is not None and faces.ndim == 4 and faces.shape[3] == 3 and faces.dtype == np.float32:
        return k.sample_cube(faces, np.ascontiguousarray(d, np.float64), k._S_AXIS, k._S_SIGN,
                             k._T_AXIS, k._T_SIGN)
    return sample_cube(faces, d).astype(np.float64)


def _lut_albedo(env: BakedEnvironment, cos_v: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """The GGX lobe's single-scattering albedo E_ss = scale + bias from the baked BRDF LUT
    (bilinear, as the raster path's texture lookup); 1 for smooth interfaces."""
    lut = np.asarray(env.brdf_lut, np.float64)
    n = lut.shape[0]
    x = np.clip(np.abs(cos_v) * n - 0.5, 0, n - 1)
    y = np.clip(roughness * n - 0.5, 0, n - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, n - 1), np.minimum(y0 + 1, n - 1)
    fx, fy = x - x0, y - y0
    e = lut[..., 0] + lut[..., 1]
    top = e[y0, x0] * (1 - fx) + e[y0, x1] * fx
    bottom = e[y1, x0] * (1 - fx) + e[y1, x1] * fx
    return np.where(roughness > 0, top * (1 - fy) + bottom * fy, 1.0)


def subpixel_rays(camera: Camera, pixels: np.ndarray, ss: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions on an ss x ss stratified grid inside each of `pixels` (flat indices), and the
    pixel of each ray: the rays renderer.view.camera would give a camera of ss times the size."""
    r, u, f = camera.basis()
    th = math.tan(math.radians(camera.fov) / 2)
    rows, cols = np.divmod(pixels, camera.width)
    off = (np.arange(ss) + 0.5) / ss
    y = rows[:, None, None] + off[None, :, None]        # pixel, sub-row, sub-col
    x = cols[:, None, None] + off[None, None, :]
    y, x = np.broadcast_arrays(y, x)
    sx = (x.reshape(-1) / camera.width * 2 - 1) * th * camera.aspect
    sy = (1 - y.reshape(-1) / camera.height * 2) * th
    d = f + sx[:, None] * r + sy[:, None] * u
    return d / np.linalg.norm(d, axis=-1, keepdims=True), np.repeat(pixels, ss * ss)


def grown_by_one(mask: np.ndarray) -> np.ndarray:
    """`mask` grown by one pixel in all eight directions."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    grown = out.copy()
    out[:, 1:] |= grown[:, :-1]
    out[:, :-1] |= grown[:, 1:]
    return out


class _Image:
    """Radiance and coverage summed per pixel."""

    def __init__(self, npix: int):
        self.npix = npix
        self.rgb = np.zeros((npix, 3))
        self.coverage = np.zeros(npix)

    def add(self, rgb: np.ndarray, pix: np.ndarray) -> None:
        for c in range(3):
            self.rgb[:, c] += np.bincount(pix, rgb[:, c], minlength=self.npix)


def default_supersample(width: int, height: int) -> int:
    """Rays per pixel side near the object: 2 from 384 px up, 3 from 128, 4 below. Smaller
    frames minify the refracted environment more per pixel, and cost little more. (4 up to
    255 px was the default until issue 26's front: at 128 px it costs 1.8x the 3 x 3 grid for
    0.054 mean FLIP against 0.064, bench/RESULTS.md; below 128 px a frame is cheap anyway and
    sampled rough lobes need the rays.)"""
    px = max(width, height, 1)
    return 4 if px < 128 else 3 if px < 384 else 2


def trace(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions,
          camera: Camera | None = None, supersample: int | None = None) -> tuple[np.ndarray, dict]:
    """Linear H x W x 4 float32 (premultiplied RGB, alpha = coverage) and statistics."""
    t0 = time.perf_counter()
    if camera is None:
        camera = asset_camera(asset, options)[0]  # framed as the raster methods frame it
    if supersample is None:
        supersample = options.supersample
    if supersample is None:
        supersample = default_supersample(camera.width, camera.height)
    ts = build_scene(asset, options)
    # A ray's cone: its share of a pixel's angle (the texture level follows its footprint).
    ts.eye = np.asarray(camera.position, np.float64)
    ts.forward = np.asarray(camera.basis()[2], np.float64)
    if ts.sprite.any():  # a disc's face is its surface: lit (and faced) about the camera's axis
        tri = ts.sprite[ts.material]
        ts.geo_normals = ts.geo_normals.copy()
        ts.geo_normals[tri] = -ts.forward
    ts.spread = 2 * math.tan(math.radians(camera.fov) / 2) / camera.height / supersample
    if options.lights and asset.lights:
        ts.lights = trace_lights.lights_of(asset.lights, options.light_shadows)
    sky = _Environment(env, options.env_rotation)
    t_build = time.perf_counter()
    npix = camera.width * camera.height
    passes = _dispersion_passes(ts, asset, options)
    images = [_Image(npix) for _ in passes]
    image = images[0]
    stats: dict[str, Any] = {"rays": npix, "bounces": [], "tir": 0, "embree_cached": ts.embree_cached,
                             "emitters": len(ts.emitters) if ts.emitters is not None else 0}
    show_env = options.background == "env"

    # Adaptive anti-aliasing: one centre ray finds the object; pixels on or next to it get
    # ss x ss rays (the refracted environment is minified there), the open background keeps
    # its centre ray (the cube map is already filtered at about a pixel's footprint).
    # Pixels go through in chunks so that memory stays bounded at any image size.
    first_prim = np.full(npix, -1, np.int64)
    for chunk in _chunks(np.arange(npix), 4 * CHUNK_PIXELS):
        d, _ = subpixel_rays(camera, chunk, 1)
        first_prim[chunk] = intersect_front(ts, np.broadcast_to(camera.position, d.shape), d,
                                            stop_premultiplied=True)[0]
    first = first_prim >= 0
    near = grown_by_one(first.reshape(camera.height, camera.width)).reshape(-1)
    if show_env:
        for chunk in _chunks(np.flatnonzero(~near), 4 * CHUNK_PIXELS):
            d, _ = subpixel_rays(camera, chunk, 1)
            for img in images:
                img.add(sky.radiance(d, np.full(len(d), options.background_blur)), chunk)
    if options.integrator == "path":  # progressive path tracing (renderer.methods.path_trace)
        from renderer.methods import path_trace
        pixels = np.flatnonzero(near)
        # budget_ms counts from the frame's start (the scene build included); a dispersive
        # frame's channels share what is left, so three channels do not take three budgets
        deadline = None if options.budget_ms is None else t0 + options.budget_ms / 1e3
        for c, (scene, img) in enumerate(zip(passes, images)):
            share = None if deadline is None else \
                time.perf_counter() + (deadline - time.perf_counter()) / (len(passes) - c)
            rgb_p, cov_p = path_trace.trace(scene, sky, options, camera, pixels, stats, share)
            img.rgb[pixels] += rgb_p
            img.coverage[pixels] += cov_p
        stats["elapsed_ms"] = (time.perf_counter() - t0) * 1e3  # the frame up to its last pass
        supersample = 1
    else:
        groups = [(near, supersample)]
        if options.supersample is None and options.rough_lobes == "sample" and ROUGH_EXTRA > 0:
            # rough glass samples its lobes with the pixel's rays: where the centre ray meets
            # it the default grid is finer (frosted sphere at 128 px: 0.116 FLIP at 3 x 3)
            k = ts.material[np.maximum(first_prim, 0)]
            rough = first & (ts.roughness[k] > 0) & (ts.transmission[k] > 0)
            if rough.any():
                groups = [(near & ~rough, supersample), (rough, supersample + ROUGH_EXTRA)]
        stats["rough_pixels"] = int(groups[-1][0].sum()) if len(groups) > 1 else 0
        for mask, ss in groups:
            for scene in passes:  # the ray cone of this grid's rays
                scene.spread = 2 * math.tan(math.radians(camera.fov) / 2) / camera.height / ss
            _trace_tree(ts, sky, options, camera, mask, ss, passes, images, stats)

    rgb = image.rgb if len(images) == 1 else np.stack([img.rgb[:, c] for c, img in enumerate(images)], -1)
    rgb = rgb.reshape(camera.height, camera.width, 3)
    coverage = image.coverage.reshape(rgb.shape[:2])
    stats["coverage"] = coverage.astype(np.float32)
    alpha = np.ones((camera.height, camera.width)) if show_env else coverage
    linear = np.concatenate([rgb, alpha[..., None]], axis=-1).astype(np.float32)
    linear = np.nan_to_num(linear, nan=0.0, posinf=0.0, neginf=0.0)  # never write NaN pixels
    t1 = time.perf_counter()
    stats.update(triangles=int(len(ts.material)), supersample=supersample,
                 build_ms=(t_build - t0) * 1e3, trace_ms=(t1 - t_build) * 1e3)
    log.info("raytrace %dx%d: %d rays in %.0f ms (%d bounces used)", camera.width,
             camera.height, stats["rays"], (t1 - t0) * 1e3, len(stats["bounces"]))
    return linear, stats


def _trace_tree(ts: TraceScene, sky: _Environment, options: RenderOptions, camera: Camera,
                near: np.ndarray, supersample: int, passes: list[TraceScene], images: list[_Image],
                stats: dict) -> None:
    """The Fresnel tree over the pixels `near`, ss x ss rays each (adaptive with aa_threshold)."""
    image = images[0]
    adaptive = options.aa_threshold > 0 and supersample > 2 and len(passes) == 1
    stats.setdefault("refined", 0)
    for chunk in _chunks(np.flatnonzero(near), CHUNK_PIXELS):
        if adaptive:  # 2 x 2 first; the full grid only where those disagree
            chunk = _coarse_pass(ts, sky, options, camera, chunk, image, stats)
            stats["refined"] += len(chunk)
        dirs, pix = subpixel_rays(camera, chunk, supersample)
        for scene, img in zip(passes, images):
            _trace_paths(scene, sky, options, camera.position, dirs, pix, 1.0 / supersample ** 2,
                         img, stats)



def _coarse_pass(ts: TraceScene, sky: _Environment, options: RenderOptions, camera: Camera,
                 pixels: np.ndarray, image: _Image, stats: dict) -> np.ndarray:
    """Trace 2 x 2 rays in each of `pixels`; add the pixels whose four samples agree (object
    coverage equal, tone-mapped luminance L / (1 + L) within options.aa_threshold) to
    `image` and return the others, to be traced again with the full grid."""
    dirs, pix = subpixel_rays(camera, pixels, 2)
    per_ray = _Image(len(dirs))
    _trace_paths(ts, sky, options, camera.position, dirs, pix, 0.25, per_ray, stats,
                 slot=np.arange(len(dirs)))
    lum = (per_ray.rgb @ np.array([0.2126, 0.7152, 0.0722]) * 4.0).reshape(-1, 4)
    tone = lum / (1.0 + lum)
    cover = per_ray.coverage.reshape(-1, 4)
    again = ((tone.max(1) - tone.min(1) > options.aa_threshold)
             | (cover.max(1) != cover.min(1)))
    keep = ~again
    image.rgb[pixels[keep]] += per_ray.rgb.reshape(-1, 4, 3)[keep].sum(1)
    image.coverage[pixels[keep]] += cover[keep].sum(1)
    return pixels[again]


def _dispersion_passes(ts: TraceScene, asset: BakedAsset, options: RenderOptions) -> list[TraceScene]:
    """One scene to trace, or with KHR_materials_dispersion three: one per RGB channel, each
    with that channel's IOR (Material.channel_iors); the frame takes channel c from pass c."""
    mats = [apply_override(m.material, options.override) for m in asset.meshes]
    if not any(m.dispersion > 0 for m in mats):
        return [ts]
    return [dataclasses.replace(ts, ior=np.asarray([m.channel_iors()[c] for m in mats], np.float64))
            for c in range(3)]


def _chunks(indices: np.ndarray, size: int):
    for start in range(0, len(indices), size):
        yield indices[start:start + size]


def _trace_paths(ts: TraceScene, env: _Environment, options: RenderOptions,
                 eye: np.ndarray, dirs: np.ndarray, pix: np.ndarray, sample_share: float,
                 image: _Image, stats: dict, slot: np.ndarray | None = None) -> None:
    """Trace camera rays `dirs` (pixel `pix`, each `sample_share` of its pixel) through every
    bounce, adding what reaches the environment into `image` at `slot` (default: `pix`)."""
    eps = EPSILON * ts.radius
    show_env = options.background == "env"
    add = image.add
    origins = np.broadcast_to(eye, dirs.shape)
    weight = np.ones((len(dirs), 3))  # throughput of a sample (decides what is traced on)
    share = np.full(len(dirs), sample_share)  # its part of the pixel
    blur = np.zeros(len(dirs))  # sum of squared GGX alphas of the lobes along the path
    medium = np.ones(len(dirs))  # IOR around the ray (outside every object: air)
    mirror = np.ones(len(dirs))  # of a light triangle's emission, the share a ray counts
    look = np.array(dirs, np.float64)  # where a ray reads the sky if it escapes (trace_kernel.shade)
    emitters = ts.emitters if EMITTER_SAMPLES > 0 else None
    # fresnel_split="sample": sub-ray j of a pixel's S draws (j + 0.5) / S + shift (mod 1), the
    # shift a hash of pixel and bounce: each draw uniform and independent of the previous
    # bounce's, and the pixel's S choices stratified (exactly F of them reflect, not about F).
    n_sub = max(1, round(1.0 / sample_share))
    sub = np.arange(len(dirs)) % n_sub  # rays come pixel by pixel, S a pixel
    if slot is None:
        slot = pix

    # only BLEND reads the per-ray draw (a hash per ray and bounce otherwise wasted)
    blended = ts.surface is not None and any(sm.material.alpha_mode == "BLEND"
                                             for sm in ts.surface.materials)
    if options.bounces <= 0:  # no surfaces: every camera ray reads the environment
        hit = intersect_front(ts, origins, dirs, _alpha_draw(pix, sub, n_sub, 0))[0] >= 0
        image.coverage += np.bincount(slot[hit], share[hit], minlength=image.npix)
        add(env.radiance(dirs, np.zeros(len(dirs))) * share[:, None], slot)
        return
    # A premultiplied blend (USD, as Storm) is split, not passed stochastically: the hit adds
    # opacity x its diffuse share (the occlusion input scales exactly that share) and its
    # whole reflection, and a ray of (1 - opacity) goes on straight behind. `clear`: the part
    # of a camera ray still on its line through such layers (0 off it): it adds coverage
    # where it lands and sees the background, not the lit environment, where it leaves.
    split = ts.premultiplied.any()
    clear = np.ones(len(dirs)) if split else np.zeros(0)
    for depth in range(int(options.bounces) + 1):
        if len(dirs) == 0:
            break
        if depth == options.bounces:  # out of bounces: read the environment where they point
            if split and np.any(on := clear > 0):  # still the camera's ray: the background
                if show_env:
                    bg = np.full(on.sum(), options.background_blur)
                    add(env.radiance(dirs[on], bg) * (weight[on] * share[on, None]), slot[on])
                look, weight, share, medium, blur, slot = (a[~on] for a in (look, weight, share, medium, blur, slot))
            # ... as if it left the medium it is in, without a Fresnel loss
            add((weight * (share * medium ** 2)[:, None]) * env.radiance(look, blur ** 0.25), slot)
            break
        prim, u, v, t = intersect_front(ts, origins, dirs,
                                        _alpha_draw(pix, sub, n_sub, depth) if blended else None,
                                        stop_premultiplied=True)
        stats["rays"] += len(dirs)
        if depth < len(stats["bounces"]):
            stats["bounces"][depth] += len(dirs)
        else:
            stats["bounces"].append(len(dirs))
        miss = prim < 0
        cover = opacity(ts, origins, dirs, prim, u, v, t)
        if split and depth > 0 and np.any(lost := miss & (clear > 0)):
            if show_env:  # behind the layers a camera ray went through: the background
                bg = np.full(lost.sum(), options.background_blur)
                add(env.radiance(dirs[lost], bg) * (weight[lost] * share[lost, None]), slot[lost])
            keep = np.flatnonzero(~lost)
            origins, dirs, weight, pix, sub, slot, blur, share, medium, mirror, look, clear, prim, u, v, t = (  # type: ignore[assignment]  # one selection of all
                a[keep] for a in (origins, dirs, weight, pix, sub, slot, blur, share, medium, mirror,
                                  look, clear, prim, u, v, t))
            miss = prim < 0
            if cover is not None:
                cover = cover[keep]
        if depth == 0 and not split:
            image.coverage += np.bincount(slot[~miss], share[~miss], minlength=image.npix)
        elif split:
            line = np.flatnonzero(~miss & (clear > 0))
            assert cover is not None
            image.coverage += np.bincount(slot[line], share[line] * clear[line] * cover[line],
                                          minlength=image.npix)
        if depth == 0 and show_env:
            bg = np.full(miss.sum(), options.background_blur)
            add(env.radiance(dirs[miss], bg) * share[miss, None], slot[miss])
        hits = hit_material(ts, origins, dirs, prim, u, v, t, lobes=False)
        if cover is not None:
            hits.occlusion = hits.occlusion * cover
        bent = _bent_at(ts, prim, u, v)
        # Storm's back-face rule (core.storm) is what the camera sees: on its rays (through
        # translucent layers too), not on a bounce (there a back face would reflect the sky
        # through itself)
        on_line = np.full(len(dirs), depth == 0) if not split else (clear > 0) | (depth == 0)
        ray_back = on_line & (prim >= 0) & storm_back(ts)[ts.material[np.maximum(prim, 0)]] \
            if len(ts.material) else np.zeros(len(dirs), bool)
        if ts.lights is not None and len(ts.lights):
            _light_hits(ts, ts.lights, env, options, origins, dirs, prim, t, hits,
                        weight * share[:, None], slot, add, cover, (pix, sub, n_sub, depth), ray_back)
        n_nee = 0
        if emitters is not None:
            n_nee = EMITTER_SAMPLES if depth == 0 else 1
            _mirror_emission(emitters, prim, hits, mirror)
            _emitter_hits(ts, emitters, env, options, origins, dirs, prim, t, hits,
                          weight * share[:, None], pix, sub, n_sub, depth, n_nee, slot, add, cover)
        kernel = _kernel()
        if kernel is not None:
            out = kernel.shade(
                np.ascontiguousarray(origins), dirs, prim, u, v, t, weight, pix, sub, slot, blur,
                share, medium, look, hits.normal, ts.geo_normals, ts.material, hits.base, hits.metallic,
                hits.roughness, hits.transmission, ts.ior, ts.sigma, ts.thin, hits.emission, hits.occlusion,
                np.ascontiguousarray(hits.specular, np.float64),
                np.ascontiguousarray(hits.specular_color, np.float64),
                np.asarray(env.baked.brdf_lut, np.float64), depth, n_sub, eps,
                options.rough_lobes == "sample", options.fresnel_split == "sample",
                options.multiscatter, MIN_WEIGHT, kernel._SOBOL_DIM1,
                ROULETTE if options.fresnel_split == "roulette" else 0.0, float(n_nee),
                *trace_lights.MIRROR_ROUGH, ROUGH_PROBE, ray_back, storm.back_face_table(),
                path_bsdf.glass_table() if options.multiscatter else _NO_TABLE,
                _NO_BENT if bent is None else bent)
            m_dir, m_w, m_blur, m_slot, direct, glow, diffuse, dnorm, matte, tir = out[11:21]
            if depth > 0 and len(m_slot):
                add(m_w * env.radiance(m_dir, m_blur ** 0.25), m_slot)
            e_dir, e_w, e_blur, e_slot = out[21:]  # Storm back faces' reflections: the environment
            if len(e_slot):
                add(e_w * env.radiance(e_dir, e_blur ** 0.25), e_slot)
            stats["tir"] += int(tir)
            if len(glow):
                add(direct, glow)
            if len(matte):
                add(diffuse * env.irradiance(dnorm), matte)
            out = out[:11]
        else:
            if depth > 0:
                add((weight[miss] * share[miss, None]) * env.radiance(look[miss], blur[miss] ** 0.25),
                    slot[miss])
            hit = ~miss
            d = dirs[hit].astype(np.float64)
            sel = np.flatnonzero(hit)
            out = _shade_numpy(ts, env, options, depth, n_sub, eps, d,
                               origins[hit] + d * t[hit, None], t[hit], prim[hit],
                               trace_material.Hits(*(getattr(hits, f.name)[sel] for f in  # the core
                                                     dataclasses.fields(trace_material.Hits)[:9])),
                               weight[hit], pix[hit], sub[hit], slot[hit], blur[hit], share[hit],
                               medium[hit], n_nee, add, stats, ray_back[hit],
                               None if bent is None else bent[hit])
        if split:
            assert cover is not None
            out, clear = _pass_on(out, origins, dirs, t, weight, pix, sub, slot, blur, share, medium,
                                  look, clear, _pass_share(ts, dirs, prim, cover, clear), eps)
        origins, dirs, weight, pix, sub, slot, blur, share, medium, mirror, look = out


def _pass_share(ts: TraceScene, dirs, prim, cover: np.ndarray, clear: np.ndarray) -> np.ndarray:
    """What goes on straight through a premultiplied blend, per ray (0 at anything else):
    1 - opacity on the camera's line, as Storm blends what it sees; elsewhere (a reflection
    meeting it) at most 1 - F besides the whole reflection F, so that a closed translucent
    mesh, whose inside reflects its rays back and forth, cannot give more than it gets (the
    rule's F + 1 - opacity passes 1 toward grazing, and grew by bounce)."""
    go = np.where(cover < 1, 1.0 - cover, 0.0)
    off = np.flatnonzero((cover < 1) & (clear <= 0))
    if len(off):
        k = ts.material[prim[off]]
        cos_i = np.abs(np.einsum("ij,ij->i", dirs[off], ts.geo_normals[prim[off]]))
        go[off] = np.minimum(go[off], 1.0 - fresnel_dielectric(cos_i, 1.0 / ts.ior[k]))
    return go


def _pass_on(children: tuple, origins, dirs, t, weight, pix, sub, slot, blur, share, medium,
             look, clear, go_w: np.ndarray, eps: float) -> tuple[tuple, np.ndarray]:
    """The shading's children and, after them, the rays that go on straight through the
    premultiplied blends they hit, carrying `go_w` (_pass_share; culled as the children are);
    with each one's `clear` (the children's: 0, off the camera's line)."""
    go = np.flatnonzero((go_w > 0) & (weight.max(axis=1) * go_w * medium ** 2 > MIN_WEIGHT))
    clear_out = np.concatenate([np.zeros(len(children[0])), clear[go] * go_w[go]])
    if not len(go):
        return children, clear_out
    d = dirs[go].astype(np.float64)
    # the mirror share is 1: a ray that goes on straight counts an emitter's light in full
    through = (origins[go] + d * (t[go] + eps)[:, None], d, weight[go] * go_w[go, None],
               pix[go], sub[go], slot[go], blur[go], share[go], medium[go], np.ones(len(go)), look[go])
    return tuple(np.concatenate([c, x.astype(c.dtype, copy=False)]) for c, x in zip(children, through)), clear_out


def _light_hits(ts: TraceScene, lights: trace_lights.Lights, env: _Environment,
                options: RenderOptions, origins, dirs, prim, t, hits: trace_material.Hits, carried: np.ndarray, slot: np.ndarray, add,
                cover: np.ndarray | None = None, strata: tuple | None = None,
                ray_back: np.ndarray | None = None) -> None:
    """Next-event estimation: what the punctual lights reflect along each ray from the
    surface it hit, times what the ray carries, into `add` (`cover`: the opacity of a
    premultiplied blend per ray, which scales the diffuse share). Hits from inside a transmissive
    object are skipped: light reaches them only refracted, which a straight shadow ray
    cannot follow. A light with extent (a USD rect, disk, sphere, cylinder or wide distant
    light) is sampled LIGHT_SAMPLES times a ray at the first surface, once deeper, from the
    pixel's scrambled Sobol set (`strata`: pixel, sub-ray, rays a pixel, bounce), so a
    pixel's rays stratify its extent together."""
    side = _lit_side(ts, origins, dirs, prim, t, hits)
    if side is None:
        return
    sel, k, d, ng, n, p = side
    samples = None
    if strata is not None and any(lights.extended(i) for i in range(len(lights))):
        pix, sub, n_sub, depth = strata
        wide = any(lights.extended(i) and not lights.narrow(i) for i in range(len(lights)))
        n_s = LIGHT_SAMPLES if depth == 0 and wide else 1  # a narrow cone takes the first only
        samples = [_pixel_samples(pix[sel], sub[sel] * n_s + j, 1700 + depth) for j in range(n_s)]

    def transmittance(o: np.ndarray, ldir: np.ndarray, dist: np.ndarray, normal: np.ndarray) -> np.ndarray:
        return shadow_transmittance(ts, o, ldir, dist, normal, 950)

    def spec_albedo(f0: np.ndarray, cos_v: np.ndarray, rough: np.ndarray):
        return (env.specular_albedo(f0, cos_v, rough, False),
                env.specular_albedo(f0, cos_v, rough, options.multiscatter))

    back = (np.zeros(len(sel), bool) if ray_back is None else ray_back[sel]) & \
        (np.einsum("ij,ij->i", d, ts.geo_normals[prim[sel]]) > 0)
    if np.any(back):  # Storm's back faces (core.storm): lit about the authored normals
        n, ng = n.copy(), ng.copy()
        n[back], ng[back] = hits.normal[sel[back]], -ng[back]
    rgb = trace_lights.direct(lights, transmittance, p, n, ng, -d, hits.base[sel],
                              hits.metallic[sel], hits.roughness[sel], hits.transmission[sel],
                              ts.ior[k], spec_albedo, None if cover is None else cover[sel], samples,
                              back)
    add(rgb * carried[sel], slot[sel])


def _lit_side(ts: TraceScene, origins, dirs, prim, t, hits: trace_material.Hits):
    """The hits that direct light reaches (not from inside a transmissive object: light gets
    there only refracted, which a straight shadow ray cannot follow) as (ray indices, their
    materials, directions, geometric and shading normals turned to the ray as the shading
    kernel turns them, points), or None."""
    sel = np.flatnonzero(prim >= 0)
    k = ts.material[prim[sel]]
    d = dirs[sel].astype(np.float64)
    ng = ts.geo_normals[prim[sel]].astype(np.float64)
    entering = np.einsum("ij,ij->i", d, ng) < 0
    keep = entering | (ts.transmission[k] <= 0) | ts.thin[k]
    sel, k, d, ng = sel[keep], k[keep], d[keep], ng[keep]
    if not len(sel):
        return None
    ng = ng * np.where(np.einsum("ij,ij->i", d, ng) < 0, 1.0, -1.0)[:, None]
    n = hits.normal[sel] * np.where(np.einsum("ij,ij->i", d, ng) < 0, 1.0, -1.0)[:, None]
    n = np.where((np.einsum("ij,ij->i", d, n) >= 0)[:, None], ng, n)
    return sel, k, d, ng, n, origins[sel] + d * t[sel, None]


def _emitter_hits(ts: TraceScene, em: trace_lights.Emitters, env: _Environment,
                  options: RenderOptions, origins, dirs, prim, t, hits: trace_material.Hits,
                  carried: np.ndarray, pix: np.ndarray, sub: np.ndarray, n_sub: int, depth: int,
                  n_s: int, slot: np.ndarray, add, cover: np.ndarray | None = None) -> None:
    """Next-event estimation toward the emissive triangles: n_s points a ray (the triangle
    chosen by trace_lights.emitter_choice, stratified over the pixel's rays; the point uniform
    on it, from the pixel's scrambled Sobol set), a shadow ray to each, and what the BRDF of
    trace_lights.direct reflects of the emission there (read at the point, textures included).
    The diffuse share takes all of it: the tree's diffuse reads only the sky. The glossy share
    is split with the mirror child, which meets the emitters too, by trace_lights.mirror_share
    of the roughness (the child carries its share, _mirror_emission applies it); rough glass
    with sampled lobes reflects a child drawn from its lobe, which alone is unbiased there: no
    glossy share here. `cover`: a premultiplied blend's opacity per ray, which scales the
    diffuse share (as in _light_hits)."""
    side = _lit_side(ts, origins, dirs, prim, t, hits)
    if side is None:
        return
    sel, k, d, ng, n, p = side
    v = -d
    base, metal = hits.base[sel], hits.metallic[sel]
    rough, trans = hits.roughness[sel], hits.transmission[sel]
    ior = ts.ior[k]
    n_v = np.clip(np.einsum("ij,ij->i", n, v), 1e-4, 1.0)
    f0 = (((ior - 1) / (ior + 1)) ** 2)[:, None] * (1 - metal[:, None]) + base * metal[:, None]
    e_ss = env.specular_albedo(f0, n_v, rough, False)
    e_spec = env.specular_albedo(f0, n_v, rough, options.multiscatter)
    ms_scale = e_spec / np.maximum(e_ss, 1e-4)
    diffuse = base * ((1 - metal) * (1 - trans))[:, None] / math.pi * (1 - e_spec)
    if cover is not None:
        diffuse = diffuse * cover[sel, None]
    alpha = np.maximum(rough * rough, 1e-3)
    glossy = ~((rough > 0) & (trans > 0)) if options.rough_lobes == "sample" else np.ones(len(sel), bool)
    w_l = np.where(glossy, 1.0 - trace_lights.mirror_share(rough), 0.0)  # the mirror child has the rest
    out = np.zeros((len(sel), 3))
    x = p + EPSILON * ts.radius * ng  # off the surface (a point on the card is on no emitter)
    for s in range(n_s):
        strata = sub[sel] * n_s + s
        u0 = ((strata + 0.5) / (n_sub * n_s) + pixel_shift(pix[sel], 1300 + depth)) % 1.0
        u1, u2 = _pixel_samples(pix[sel], strata, 1400 + depth)
        j, odds = trace_lights.emitter_choice(em, x, u0)
        r1 = np.sqrt(u1)
        bu, bv = r1 * (1 - u2), r1 * u2  # Embree's barycentrics of a uniform point
        q = em.p0[j] + bu[:, None] * em.e1[j] + bv[:, None] * em.e2[j]
        to = q - p
        dist = np.linalg.norm(to, axis=-1)
        ldir = to / np.maximum(dist, 1e-30)[:, None]
        cos_e = -np.einsum("ij,ij->i", ldir, em.normal[j])
        n_l = np.einsum("ij,ij->i", n, ldir)
        ok = (((cos_e > 0) | em.two_sided[j]) & (n_l > 0) & (np.einsum("ij,ij->i", ng, ldir) > 0)
              & (dist > 0) & (np.abs(cos_e) > 1e-9))
        idx = np.flatnonzero(ok)
        if not len(idx):
            continue
        tri = em.tri[j[idx]]
        # the combined density of the n_s samples, in solid angle
        p_l = n_s * odds[idx] / em.area[j[idx]] * dist[idx] ** 2 / np.abs(cos_e[idx])
        le = hit_material(ts, p[idx], ldir[idx], tri.astype(np.int32), bu[idx].astype(np.float32),
                          bv[idx].astype(np.float32), dist[idx], lobes=False).emission
        lit = np.flatnonzero(le.max(axis=1) > 0)
        if not len(lit):
            continue
        idx, p_l, le = idx[lit], p_l[lit], le[lit]
        # off the surface by eps along ng, the ray meets the emitter up to eps / cos_e early
        short = dist[idx] - EPSILON * ts.radius / np.maximum(np.abs(cos_e[idx]), 1e-3)
        vis = shadow_transmittance(ts, p[idx], ldir[idx], short, ng[idx], 1600 + 8 * depth)
        h = ldir[idx] + v[idx]
        h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
        n_h = np.clip(np.einsum("ij,ij->i", n[idx], h), 0.0, 1.0)
        v_h = np.clip(np.einsum("ij,ij->i", v[idx], h), 0.0, 1.0)
        spec = trace_lights.ggx_spec(f0[idx], alpha[idx], n_v[idx], n_l[idx], n_h, v_h) * ms_scale[idx]
        out[idx] += (diffuse[idx] + spec * w_l[idx, None]) * le * vis * (n_l[idx] / p_l)[:, None]
    add(out * carried[sel], slot[sel])


def _mirror_emission(em: trace_lights.Emitters, prim, hits: trace_material.Hits,
                     mirror: np.ndarray) -> None:
    """Scale the emission of the light triangles these rays hit by the share their parent
    left to its mirror child (trace_lights.mirror_share; 1 where the parent sampled no
    emitters), in place in hits.emission."""
    sel = np.flatnonzero((prim >= 0) & (mirror < 1.0))
    sel = sel[em.index[prim[sel]] >= 0]
    if len(sel):
        hits.emission[sel] *= mirror[sel, None]


def emitter_irradiance(ts: TraceScene, em: trace_lights.Emitters, p: np.ndarray, n: np.ndarray,
                       ng: np.ndarray, samples: int, seed: int = 0) -> np.ndarray:
    """N x 3 irradiance the emitters give points p (shading normal n, geometric ng on the lit
    side), shadowed, by `samples` emitter points each (iid, as _emitter_hits chooses them;
    no MIS: nothing else finds emitters here). For measurements such as a per-vertex bake's."""
    rng = np.random.default_rng(seed)
    out = np.zeros((len(p), 3))
    x = p + EPSILON * ts.radius * ng
    for _ in range(samples):
        u0, u1, u2 = rng.random((3, len(p)))
        j, odds = trace_lights.emitter_choice(em, x, u0)
        r1 = np.sqrt(u1)
        bu, bv = r1 * (1 - u2), r1 * u2
        q = em.p0[j] + bu[:, None] * em.e1[j] + bv[:, None] * em.e2[j]
        dist = np.linalg.norm(q - p, axis=-1)
        ldir = (q - p) / np.maximum(dist, 1e-30)[:, None]
        cos_e = -np.einsum("ij,ij->i", ldir, em.normal[j])
        n_l = np.einsum("ij,ij->i", n, ldir)
        idx = np.flatnonzero(((cos_e > 0) | em.two_sided[j]) & (n_l > 0) & (odds > 0)
                             & (np.einsum("ij,ij->i", ng, ldir) > 0) & (np.abs(cos_e) > 1e-9))
        if not len(idx):
            continue
        tri = em.tri[j[idx]]
        p_l = odds[idx] / em.area[j[idx]] * dist[idx] ** 2 / np.abs(cos_e[idx])
        le = hit_material(ts, p[idx], ldir[idx], tri.astype(np.int32), bu[idx].astype(np.float32),
                          bv[idx].astype(np.float32), dist[idx], lobes=False).emission
        short = dist[idx] - EPSILON * ts.radius / np.maximum(np.abs(cos_e[idx]), 1e-3)
        vis = shadow_transmittance(ts, p[idx], ldir[idx], short, ng[idx], 1600)
        out[idx] += le * vis * (n_l[idx] / p_l)[:, None]
    return out / samples


def shadow_transmittance(ts: TraceScene, o: np.ndarray, ldir: np.ndarray, dist: np.ndarray,
                   normal: np.ndarray, salt: int) -> np.ndarray:
    """N x 3 of what gets through the segments from o (offset off the surface along `normal`)
    along ldir for dist: alpha cut-outs and culled back faces pass, a blended surface stops the
    ray with the probability of its alpha (a draw hashed from `salt`), transmissive surfaces
    tint it, anything else blocks it."""
    eps = EPSILON * ts.radius
    vis = np.ones((len(o), 3))
    start, dist = o + eps * normal, dist.copy()
    todo = np.arange(len(o))
    for layer in range(trace_lights.MAX_LAYERS):
        # a blended surface stops a shadow ray with the probability of its alpha (as the
        # path tracer's shadow rays and the raster's tint atlas: 1 - alpha gets through);
        # a premultiplied one is met and lets 1 - alpha through untinted (no noise)
        draw = pixel_shift(todo + layer * len(o), salt + layer)
        hp, hu, hv, ht = intersect_front(ts, start[todo], ldir[todo], draw,
                                         stop_premultiplied=True, shadow=True)
        ht = np.asarray(ht, np.float64)
        blocked = (hp >= 0) & (ht < dist[todo] - 2 * eps)
        idx = todo[blocked]
        if not len(idx):
            break
        pb = hp[blocked]
        km = ts.material[pb]
        through = ts.transmission[km] * (1 - ts.metallic[km])
        if ts.surface is None:
            c = ts.base[km]
        else:  # the texel crossed, as the camera rays' tint has it
            width = ts.spread * (np.linalg.norm(start[idx] - ts.eye, axis=-1) + ht[blocked])
            cos_d = np.abs(np.einsum("ij,ij->i", ldir[idx], ts.geo_normals[pb]))
            rgba = trace_material.base_rgba(ts.surface, km, pb, hu[blocked], hv[blocked],
                                            width, cos_d)
            c = rgba[:, :3]
            if ts.premultiplied.any():
                pm = ts.premultiplied[km]
                through = np.where(pm, 1.0 - np.clip(rgba[:, 3], 0.0, 1.0), through)
                c = np.where(pm[:, None], 1.0, c)
        # a crossing of a volume takes sqrt(c) (a closed solid of one colour: c in all,
        # as its camera rays); a thin sheet is one surface: c
        c = np.where(ts.thin[km][:, None], c, np.sqrt(np.maximum(c, 0.0)))
        vis[idx] *= through[:, None] * c
        start[idx] += ldir[idx] * (ht[blocked] + eps)[:, None]
        dist[idx] -= ht[blocked] + eps
        todo = idx[through > 0]
        if not len(todo):
            break
    return vis


def _alpha_draw(pix: np.ndarray, sub: np.ndarray, n_sub: int, depth: int) -> np.ndarray:
    """The uniform per ray that alpha BLEND compares with: stratified over a pixel's rays."""
    return ((sub + 0.5) / n_sub + pixel_shift(pix, depth + 900)) % 1.0


def _bent_at(ts: TraceScene, prim: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray | None:
    """The baked bent normals at the hits (trace_material.bent_at), none on a sprite's disc (it
    is lit about the camera's axis, as the raster's FACE_VIEWER)."""
    bent = trace_material.bent_at(ts.surface, prim, u, v)
    if bent is not None and ts.sprite.any():
        bent[(prim >= 0) & ts.sprite[ts.material[np.maximum(prim, 0)]]] = 0.0
    return bent


def _bend(ns: np.ndarray, ng: np.ndarray, bent: np.ndarray, front: np.ndarray, back: np.ndarray) -> np.ndarray:
    """The diffuse share's normals: the shading normals bent as the raster's m.bent (numpy twin
    of trace_kernel._bend): normalize(n + normalize(b) - ng), b the side met; n where b is 0."""
    b = np.where(front[:, None], bent[:, :3], bent[:, 3:])
    ll = np.einsum("ij,ij->i", b, b)
    ok = (ll > 1e-12) & ~back
    out = ns.copy()
    x = ns[ok] + b[ok] / np.sqrt(ll[ok])[:, None] - ng[ok]
    out[ok] = x / np.sqrt(np.maximum(np.einsum("ij,ij->i", x, x), 1e-30))[:, None]
    return out


def _shade_numpy(ts: TraceScene, env: _Environment, options: RenderOptions, depth: int,
                 n_sub: int, eps: float, d, p, t, prim, hits: trace_material.Hits, w, px, sb,
                 sl, v_in, sh, n_in, nee: int, add, stats: dict, ray_back: np.ndarray | None = None,
                 bent: np.ndarray | None = None) -> tuple:
    """The numpy twin of renderer.methods.trace_kernel.shade (the reference the kernel is tested
    against): one bounce's hits -> their children (origin, dir, weight, pix, sub, slot,
    blur, share, medium, mirror share, look); emission and the diffuse share go straight into `add`."""
    ns = hits.normal.copy()
    ng = ts.geo_normals[prim].astype(np.float64)
    entering = np.einsum("ij,ij->i", d, ng) < 0
    side = np.where(entering, 1.0, -1.0)[:, None]
    ng, ns = ng * side, ns * side                 # both face the incoming ray
    flip = np.einsum("ij,ij->i", d, ns) >= 0      # shading normal behind the ray
    ns[flip] = ng[flip]
    k = ts.material[prim]
    # a single-sided USD surface's back face, lit as Storm lights it (core.storm): the
    # authored normal, facing away (N.E = 0); specular F0 A + B, diffuse 1 - F0, no refraction
    back = (np.zeros(len(k), bool) if ray_back is None else ray_back) & ~entering
    ns[back] = hits.normal[back]
    n_diffuse = ns if bent is None else _bend(ns, ng, bent, entering, back)
    thin = ts.thin[k]
    entering = entering | thin  # a thin sheet has no inside: every side is the outside
    base, metal = hits.base, hits.metallic
    rough_k, trans, ior = hits.roughness, hits.transmission, ts.ior[k]
    # Beer-Lambert over the segment just travelled inside the volume.
    inside = ~entering & (trans > 0) if ts.sigma.any() else np.zeros(0, bool)
    if np.any(inside):
        w = w.copy()
        w[inside] *= np.exp(-ts.sigma[k[inside]] * t[inside, None])
    glow = hits.emission.max(axis=1) > 0
    if np.any(glow):
        add(w[glow] * hits.emission[glow] * sh[glow, None], sl[glow])
    cos_i = -np.einsum("ij,ij->i", d, ns)
    eta = np.where(entering, 1.0 / ior, ior)
    fres = fresnel_dielectric(cos_i, eta)
    f_smooth = fres  # before the rough lobe's albedo: KHR_materials_specular's tint reads it
    ms = options.multiscatter
    cos_c = np.clip(cos_i, 1e-4, 1.0)
    rough_out = entering & (rough_k > 0) & ~((trans > 0) & (options.rough_lobes == "sample"))
    if np.any(rough_out):  # the rough lobe's albedo relative to a smooth one's
        sel = np.flatnonzero(rough_out)
        f0 = (((ior[sel] - 1) / (ior[sel] + 1)) ** 2)[:, None]
        e_rough = env.specular_albedo(f0, cos_c[sel], rough_k[sel], ms)[:, 0]
        e_smooth = env.specular_albedo(f0, cos_c[sel], np.zeros(len(sel)), ms)[:, 0]
        fres = fres.copy()
        fres[sel] = np.clip(fres[sel] * e_rough / np.maximum(e_smooth, 1e-6), 0.0, 1.0)
    # Rough glass (rough_lobes="sample"): one GGX visible normal per ray, drawn from the
    # pixel's stratified set; both children reflect and refract about it, weighted by
    # Walter et al.'s rough dielectric (F on the microfacet, G1 of the way out).
    lobe = (rough_k > 0) & (trans > 0) if options.rough_lobes == "sample" else rough_k < 0
    g_r = g_t = None
    lobe_e = np.ones(len(d))  # a sampled lobe's single-scattering albedo (1: none put back)
    if np.any(lobe):
        lsel = np.flatnonzero(lobe)
        u1, u2 = _pixel_samples(px[lsel], sb[lsel], depth)
        _, f_m, r_m, wr_m, t_m, wt_m, tir_m = sample_rough_dielectric(
            d[lsel], ns[lsel], rough_k[lsel] ** 2, eta[lsel], u1, u2)
        fres = fres.copy()
        fres[lsel] = f_m
        f_smooth = f_smooth.copy()
        f_smooth[lsel] = f_m
        g_r, g_t = np.ones(len(d)), np.ones(len(d))
        g_r[lsel] = wr_m / np.maximum(f_m, 1e-30)        # G1 (0: leaves below the surface)
        g_t[lsel] = wt_m / np.maximum(1.0 - f_m, 1e-30)
        if ms:  # what bounces between the facets puts back (path_bsdf.glass_albedo, below)
            lobe_e[lsel] = path_bsdf.glass_albedo(np.clip(cos_i[lsel], 0.0, 1.0), rough_k[lsel] ** 2, eta[lsel])
    # KHR_materials_specular: the reflected share per channel; what passes under it loses
    # its largest channel (glTF's fresnel_mix)
    fres_c = specular_tint(fres, f_smooth, ior, hits.specular, hits.specular_color, entering & ~back)
    f_diffuse = fres_c.max(axis=1)  # what the diffuse base loses
    if np.any(back):
        a_b, b_b = storm.back_face_albedo(rough_k[back])
        f0_b = ((ior[back] - 1) / (ior[back] + 1)) ** 2
        fres_c[back] = (f0_b * a_b + b_b)[:, None]
        f_diffuse[back] = f0_b
    fres = fres_c.max(axis=1)
    # Transmission tint (as Cycles' Principled BSDF): a volume's every crossing, in or out,
    # takes sqrt(base) of the texel it crosses, so a closed solid of one colour tints by base
    # and a textured one by sqrt(c_entry) sqrt(c_exit); a thin sheet is one surface: base.
    tint = np.where(thin[:, None], base, np.sqrt(np.maximum(base, 0.0)))
    # what bounced between a sampled rough lobe's facets, in both children (path_bsdf.glass_ms)
    lobe_ms = path_bsdf.glass_ms(lobe_e[:, None], tint)
    refl_w = ((1 - metal)[:, None] * fres_c * (1.0 if g_r is None else g_r[:, None])) * lobe_ms * w
    if np.any(metal > 0):  # the metallic share's lobe albedo (a LUT read: only for metals)
        sel = np.flatnonzero((metal > 0) & ~back)
        refl_w[sel] += (metal[sel, None] * env.specular_albedo(
            base[sel], cos_c[sel], rough_k[sel], ms)) * w[sel]
        sel = np.flatnonzero((metal > 0) & back)
        if len(sel):
            a_b, b_b = storm.back_face_albedo(rough_k[sel])
            refl_w[sel] += metal[sel, None] * (base[sel] * a_b[:, None] + b_b[:, None]) * w[sel]
    # Radiance crossing an interface scales by (n_camera_side / n_far_side)^2 = eta^2: it
    # cancels on a path in and out again and matters when the camera is inside the glass.
    # A rough interface's microfacets mask and shadow part of what crosses it, as they do
    # for reflection: the transmitted share keeps the GGX lobe's single-scattering albedo
    # E_ss (split-sum scale + bias at F0 = 1), as the raster refraction does.
    e_ss = _lut_albedo(env.baked, cos_i, rough_k) if np.any(rough_k > 0) else 1.0
    if g_t is not None:  # sampled lobes: G1 instead of the lobe's mean albedo
        e_ss = np.where(lobe, g_t, e_ss)
    trans_w = ((1 - metal) * (1 - fres) * trans * np.where(thin, 1.0, eta * eta) * e_ss)[:, None] * tint * lobe_ms * w
    diffuse_w = ((1 - metal) * (1 - f_diffuse) * (1 - trans) * hits.occlusion)[:, None] * base * w
    # Lobe widths add as variances. A rough refraction bends directions by
    # |1 - eta| per unit of microfacet tilt where a reflection bends them by 2, so its
    # lobe is that much narrower than the reflection lobe the mips were filtered for.
    alpha = np.where(lobe, 0.0, rough_k * rough_k)  # a sampled lobe adds no blur
    v_refl = v_in + alpha ** 2
    v_refr = v_in + (alpha * np.abs(1.0 - eta) / 2) ** 2
    if np.any(diffuse_w > 0):
        dsel = diffuse_w.max(axis=1) > 0
        add(diffuse_w[dsel] * sh[dsel, None] * env.irradiance(n_diffuse[dsel]), sl[dsel])
    rdir = reflect(d, ns)
    tdir, tir = refract(d, ns, eta)
    if g_r is not None:
        rdir[lsel], tdir[lsel], tir[lsel] = r_m, t_m, tir_m
    wide = np.flatnonzero(~lobe & (rough_k > 0))
    if len(wide):  # a wide lobe's light comes from nearer the normal
        rdir[wide] = dominant_direction(rdir[wide], ns[wide], rough_k[wide])
    rlook = rdir.copy()
    if ROUGH_PROBE > 0 and len(wide):  # travel along a direction of the lobe
        u1, u2 = _pixel_samples(px[wide], sb[wide], depth)
        m = ggx_visible_normal(-d[wide], ns[wide], rough_k[wide] ** 2 * math.sqrt(ROUGH_PROBE), u1, u2)
        q = reflect(d[wide], m)
        up = np.einsum("ij,ij->i", q, ns[wide]) > 0
        rdir[wide[up]] = q[up]
    if np.any(thin):  # out through the sheet's parallel back face: unbent where it is smooth
        tdir[thin], tir_out = refract(tdir[thin], ns[thin], ior[thin])
        tdir[thin & ~lobe] = d[thin & ~lobe]
        tir[thin] |= tir_out
    stats["tir"] += int(np.sum(tir & (trans > 0)))
    n_t = np.where(thin, n_in, np.where(entering, ior, 1.0))
    # Culling compares what a child would carry back out into the air.
    keep_r = refl_w.max(axis=1) * n_in ** 2 > MIN_WEIGHT
    reads = back & keep_r
    if np.any(reads):  # Storm's back face reflects its environment only, as the raster does
        add(refl_w[reads] * sh[reads, None] * env.radiance(rdir[reads], v_refl[reads] ** 0.25), sl[reads])
    keep_r &= ~back
    keep_t = (trans_w.max(axis=1) * n_t ** 2 > MIN_WEIGHT) & ~tir
    if options.fresnel_split == "sample" and depth > 0:  # one child, chosen by its share
        p_r = np.where(keep_r, refl_w.max(axis=1) * n_in ** 2, 0.0)
        p_t = np.where(keep_t, trans_w.max(axis=1) * n_t ** 2, 0.0)
        p_r = p_r / np.maximum(p_r + p_t, 1e-30)
        take_r = ((sb + 0.5) / n_sub + pixel_shift(px, depth)) % 1.0 < p_r
        keep_r, keep_t = keep_r & take_r, keep_t & ~take_r
        refl_w = refl_w / np.maximum(p_r, 1e-30)[:, None]
        trans_w = trans_w / np.maximum(1.0 - p_r, 1e-30)[:, None]
    elif options.fresnel_split == "roulette" and depth > 0:  # weak children: Russian roulette
        for keep, cw, n2, salt in ((keep_r, refl_w, n_in ** 2, 500), (keep_t, trans_w, n_t ** 2, 700)):
            carried = cw.max(axis=1) * n2
            weak = keep & (carried < ROULETTE)
            draw = ((sb + 0.5) / n_sub + pixel_shift(px, depth + salt)) % 1.0
            keep &= ~weak | (draw < carried / ROULETTE)
            cw[weak] *= (ROULETTE / np.maximum(carried[weak], 1e-30))[:, None]
    # The mirror child's share of a light's emission where this hit sampled the emitters
    # (_emitter_hits' condition)
    share_r = np.ones(len(d))
    if nee:
        sampled = ~lobe & (entering | (trans <= 0))
        share_r[sampled] = trace_lights.mirror_share(rough_k)[sampled]
    # Each child starts off the surface on the side it leaves toward (a reflection about
    # a shading or microfacet normal may dip below the geometric surface).
    out_r = np.where(np.einsum("ij,ij->i", rdir, ng) >= 0, eps, -eps)[:, None] * ng
    out_t = np.where(np.einsum("ij,ij->i", tdir, ng) > 0, eps, -eps)[:, None] * ng
    return (np.concatenate([p[keep_r] + out_r[keep_r], p[keep_t] + out_t[keep_t]]),
            np.concatenate([rdir[keep_r], tdir[keep_t]]),
            np.concatenate([refl_w[keep_r], trans_w[keep_t]]),
            np.concatenate([px[keep_r], px[keep_t]]), np.concatenate([sb[keep_r], sb[keep_t]]),
            np.concatenate([sl[keep_r], sl[keep_t]]),
            np.concatenate([v_refl[keep_r], v_refr[keep_t]]),
            np.concatenate([sh[keep_r], sh[keep_t]]), np.concatenate([n_in[keep_r], n_t[keep_t]]),
            np.concatenate([share_r[keep_r], np.ones(int(keep_t.sum()))]),
            np.concatenate([rlook[keep_r], tdir[keep_t]]))


def _samples_emitters(options: RenderOptions) -> bool:
    """Whether the integrator `options` asks for draws points on the emissive triangles."""
    if options.integrator == "path":
        from renderer.methods import path_trace
        return path_trace.EMITTER_NEE
    return EMITTER_SAMPLES > 0


def render_raytrace(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions,
                    camera: Camera | None = None, supersample: int | None = None):
    """Render with the ray tracer: a renderer.frame.Frame (linear + tone-mapped sRGB)."""

    t0 = time.perf_counter()
    linear, stats = trace(asset, env, options, camera, supersample)
    background = background_rgb(options.background)
    if options.background == "gradient":  # as shaders/final.frag: sRGB top to bottom, per row
        t = 1.0 - (np.arange(options.height) + 0.5) / options.height
        background = (t[:, None, None] * np.asarray(GRADIENT[0])
                      + (1 - t[:, None, None]) * np.asarray(GRADIENT[1])).astype(np.float32)
    rgba8 = tonemap_srgb8(linear, options.tonemap, options.exposure, background)
    if options.alpha == "coverage":  # alpha is what the object covers, whatever is behind it
        linear[..., 3] = stats["coverage"]
        rgba8[..., 3] = np.round(stats["coverage"] * 255).clip(0, 255).astype(np.uint8)
    t1 = time.perf_counter()
    plan = {"method": "raytrace", "bounces": int(options.bounces),
            "shadow": "none: the ray tracer draws no ground shadow",
            "supersample": stats["supersample"],
            "rays": stats["rays"], "rays_per_bounce": stats["bounces"],
            "tir_events": stats["tir"], "integrator": options.integrator,
            "embree_cached": stats["embree_cached"], "rough_pixels": stats.get("rough_pixels", 0),
            # emissive triangles sampled as lights (the tree's EMITTER_SAMPLES, the path's EMITTER_NEE)
            "emitters": stats["emitters"] if _samples_emitters(options) else 0}
    if options.integrator == "path":
        plan.update(passes=stats["passes"], samples_mean=round(stats["samples_mean"], 2),
                    stop=stats["stop"], nonfinite=stats.get("nonfinite", 0),
                    path_ms=round(stats["path_ms"], 1), pass_ms_max=round(stats["pass_ms_max"], 1),
                    elapsed_ms=round(stats["elapsed_ms"], 1),
                    split_ms={k: round(v, 1) for k, v in stats["split_ms"].items()})
    total = (t1 - t0) * 1e3
    timings = FrameTimings(total, {"build": stats["build_ms"], "trace": stats["trace_ms"],
                                   "tonemap": total - stats["build_ms"] - stats["trace_ms"]})
    return Frame(linear=linear, rgba8=rgba8, plan=plan, timings=timings,
                 alpha_is_mask=alpha_is_mask(options))

