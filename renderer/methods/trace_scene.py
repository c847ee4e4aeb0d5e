"""What both integrators of method raytrace (renderer.methods.raytrace's Fresnel tree and
renderer.methods.path_trace) trace against: the world-space scene, its ray casts (Embree, through
culled back faces and alpha), the material at a hit, and the per-pixel hash their samples use."""
from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from renderer.methods import trace_lights, trace_material
from renderer.methods.trace_material import Surface

MAX_CULLED = 8         # back faces of single-sided materials a ray may pass through
EPSILON = 1e-4         # ray offset off a surface, relative to the scene's bounding radius
_THREADS = 2           # Embree releases the GIL: two halves of a batch run in parallel
_pool: ThreadPoolExecutor | None = None


@dataclass
class TraceScene:
    """The world-space triangle soup with per-triangle shading data."""
    embree: Any                  # embreex EmbreeScene
    normals: np.ndarray          # T x 3 x 3 float32 world vertex normals per corner
    geo_normals: np.ndarray      # T x 3 float32 unit geometric normals (winding order)
    material: np.ndarray         # T int32 index into the material tables
    base: np.ndarray             # K x 3 linear base colour
    metallic: np.ndarray         # K
    roughness: np.ndarray        # K
    transmission: np.ndarray     # K
    ior: np.ndarray              # K
    sigma: np.ndarray            # K x 3 absorption coefficient per scene unit (0: none)
    culled: np.ndarray           # K bool: single-sided and opaque (back faces let rays through)
    emission: np.ndarray         # K x 3 emissive factor x strength (linear radiance)
    thin: np.ndarray             # K bool: thin-walled (glTF: no volume): crossed unbent, no inside
    radius: float
    surface: Surface | None = None  # UVs, tangents, colours, textures (trace_material)
    eye: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    forward: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))  # the camera's axis
    spread: float = 0.0          # ray cone angle per unit length (a camera ray's pixel share)
    lights: trace_lights.Lights | None = None  # punctual lights (next-event estimation)
    emitters: trace_lights.Emitters | None = None  # emissive triangles as lights (the tree's NEE)
    embree_cached: bool = False  # the Embree scene came from raytrace's in-process cache
    # K bool: blended premultiplied as Storm blends a UsdPreviewSurface (core.scene.Material
    # opacity_premultiplied): the tracers stop on it and split it (opacity)
    premultiplied: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, bool))
    # K bool: single-sided USD, back faces lit as Storm lights them (core.storm)
    storm_back: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, bool))
    # K bool: Material.face_viewer (USD points): shaded as discs, so their spheres cast no
    # shadow (a sphere would shade its own disc; Storm's points cast none)
    sprite: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, bool))


def storm_back_faces(materials) -> np.ndarray:
    """K bool: single-sided USD materials whose back faces are drawn and lit as Storm lights
    them (core.storm); a refracting one keeps its exit, a glTF one is culled."""
    return np.asarray([m.show_back_faces and not m.double_sided and m.transmission <= 0
                       for m in materials], bool)


def storm_back(ts: TraceScene) -> np.ndarray:
    """ts.storm_back, or none set where a scene was built without it."""
    return ts.storm_back if len(ts.storm_back) == len(ts.ior) else np.zeros(len(ts.ior), np.bool_)


def intersect(ts: TraceScene, origins: np.ndarray, dirs: np.ndarray):
    """(triangle index or -1, u, v, t) for each ray, the batch split over threads."""
    global _pool
    o = np.ascontiguousarray(origins, np.float32)
    d = np.ascontiguousarray(dirs, np.float32)
    n = len(o)
    if n < 20000:
        r = ts.embree.run(o, d, output=1)
        return r["primID"], r["u"], r["v"], r["tfar"]
    if _pool is None:
        _pool = ThreadPoolExecutor(_THREADS, thread_name_prefix="embree")
    cuts = np.linspace(0, n, _THREADS + 1).astype(int)
    parts = list(_pool.map(lambda ab: ts.embree.run(o[ab[0]:ab[1]], d[ab[0]:ab[1]], output=1),
                           zip(cuts[:-1], cuts[1:])))
    return tuple(np.concatenate([p[k] for p in parts]) for k in ("primID", "u", "v", "tfar"))


def intersect_front(ts: TraceScene, origins: np.ndarray, dirs: np.ndarray,
                     draw: np.ndarray | None = None, stop_premultiplied: bool = False,
                     shadow: bool = False):
    """intersect, passing through the back faces of single-sided opaque materials and
    where alpha says so (MASK: below the cut-off; BLEND: where `draw`, a uniform per ray,
    is at or above alpha; draw None: 0, so that any alpha above 0 is found, as the first
    pass that finds the object's pixels needs). `stop_premultiplied`: a premultiplied
    blend is always hit (at any opacity, even 0, its specular shows): the camera and bounce
    rays, which go on through it as a ray of their own (`opacity`); shadow rays pass it
    with probability 1 - opacity as any blend. `shadow`: a shadow ray, which passes sprites."""
    prim, u, v, t = intersect(ts, origins, dirs)
    surf = ts.surface
    tested = surf is not None and surf.alpha_tested.any()
    skip = ts.sprite if shadow and len(ts.sprite) == len(ts.culled) and ts.sprite.any() else None
    if not ts.culled.any() and not tested and skip is None:
        return prim, u, v, t
    prim, u, v, t = prim.copy(), u.copy(), v.copy(), t.astype(np.float64)
    eps = EPSILON * ts.radius
    fresh = np.ones(len(prim), bool)  # rays whose current hit is not yet accepted
    for layer in range(MAX_CULLED):
        hit = np.flatnonzero((prim >= 0) & fresh)
        k = ts.material[prim[hit]]
        back = np.einsum("ij,ij->i", dirs[hit], ts.geo_normals[prim[hit]]) > 0
        through = ts.culled[k] & back
        if skip is not None:
            through |= skip[k]
        if surf is not None and tested:
            tested_k = surf.alpha_tested[k]
            if stop_premultiplied and ts.premultiplied.any():
                tested_k = tested_k & ~ts.premultiplied[k]
            at = np.flatnonzero(tested_k & ~through)
            if len(at):
                ray = hit[at]
                width = ts.spread * (np.linalg.norm(origins[ray] - ts.eye, axis=-1) + t[ray])
                cos_d = np.abs(np.einsum("ij,ij->i", dirs[ray], ts.geo_normals[prim[ray]]))
                # each layer behind another draws anew (golden-ratio shift of the same draw)
                u_draw = (np.zeros(len(ray)) if draw is None
                          else (draw[ray] + 0.6180339887 * layer) % 1.0)
                through[at] = trace_material.passes_through(
                    surf, k[at], prim[ray], u[ray], v[ray], width, cos_d, u_draw)
        sel = hit[through]
        if not len(sel):
            break
        fresh[:] = False
        fresh[sel] = True
        start = t[sel] + eps
        p2, u2, v2, t2 = intersect(ts, origins[sel] + dirs[sel] * start[:, None], dirs[sel])
        prim[sel], u[sel], v[sel] = p2, u2, v2
        t[sel] = np.where(p2 >= 0, t2 + start, t2)
    return prim, u, v, t


def opacity(ts: TraceScene, origins: np.ndarray, dirs: np.ndarray, prim: np.ndarray,
            u: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray | None:
    """Per ray the opacity (base alpha x texture x vertex alpha) of a premultiplied blend
    it hit, 1 elsewhere (misses too); None where the scene has no premultiplied blend."""
    surf = ts.surface
    if surf is None or not ts.premultiplied.any():
        return None
    out = np.ones(len(prim))
    hit = np.flatnonzero(prim >= 0)
    sel = hit[ts.premultiplied[ts.material[prim[hit]]]]
    if len(sel):
        width = ts.spread * (np.linalg.norm(origins[sel] - ts.eye, axis=-1) + t[sel])
        cos_d = np.abs(np.einsum("ij,ij->i", dirs[sel], ts.geo_normals[prim[sel]]))
        a = trace_material.base_rgba(surf, ts.material[prim[sel]], prim[sel], u[sel], v[sel],
                                     width, cos_d)[:, 3]
        out[sel] = np.clip(a, 0.0, 1.0)
    return out


def coverage(ts: TraceScene, origins: np.ndarray, dirs: np.ndarray, prim: np.ndarray, t: np.ndarray,
             cover: np.ndarray | None, draw: np.ndarray | None = None) -> np.ndarray:
    """Per camera ray what it covers (1 - the product of 1 - opacity over the premultiplied
    blends it crosses, up to anything else it meets): 1 or 0 without any; `prim`, `t`,
    `cover` its first hit (intersect_front with stop_premultiplied, opacity)."""
    cov = (prim >= 0).astype(np.float64)
    if cover is None:
        return cov
    todo = np.flatnonzero((prim >= 0) & (cover < 1))
    cov[todo] = cover[todo]
    left = 1.0 - cover[todo]
    eps = EPSILON * ts.radius
    o = origins[todo] + dirs[todo] * (np.asarray(t[todo], np.float64) + eps)[:, None]
    d = dirs[todo]
    for _ in range(MAX_CULLED):
        if not len(todo):
            break
        p2, u2, v2, t2 = intersect_front(ts, o, d, None if draw is None else draw[todo], True)
        a = opacity(ts, o, d, p2, u2, v2, t2)
        assert a is not None
        a = np.where(p2 >= 0, a, 0.0)
        cov[todo] += left * a
        left = left * (1.0 - a)
        go = (p2 >= 0) & (a < 1)
        todo, left, d = todo[go], left[go], d[go]
        o = o[go] + d * (np.asarray(t2[go], np.float64) + eps)[:, None]
    return cov


def pixel_shift(pix: np.ndarray, depth: int) -> np.ndarray:
    """A uniform number in [0, 1) per (pixel, bounce), the same every frame (splitmix64)."""
    with np.errstate(over="ignore"):
        h = pix.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(depth + 1) * np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(30)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(27)
        h *= np.uint64(0x94D049BB133111EB)
        h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def reverse_bits(x: np.ndarray) -> np.ndarray:
    """Bit reversal of uint32 values."""
    for shift, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF)):
        m, k = np.uint32(mask), np.uint32(shift)
        x = ((x >> k) & m) | ((x & m) << k)
    return (x >> np.uint32(16)) | (x << np.uint32(16))


def owen_scramble(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Nested uniform (Owen) scrambling of 32-bit fractions, hashed (Burley 2020)."""
    x = reverse_bits(x) + seed
    for c in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6):
        x ^= x * np.uint32(c)
    return reverse_bits(x)


SOBOL_DIM1 = [0x80000000]
for _ in range(31):
    SOBOL_DIM1.append(SOBOL_DIM1[-1] ^ (SOBOL_DIM1[-1] >> 1))


def sobol_samples(pix: np.ndarray, sub: np.ndarray, depth: int) -> tuple[np.ndarray, np.ndarray]:
    """Two uniforms per ray: sample `sub` of a shuffled, Owen-scrambled 2-D Sobol set seeded
    by (pixel, `depth`) (Burley 2020): each seed's pairs are a (0, 2)-sequence (any 2^k of
    them one per elementary cell), the index shuffle decorrelates one seed's stream from
    another's; the same frame each time (the tree's rough lobes, the path integrator's
    dimensions; trace_kernel._pixel_samples is its compiled twin)."""
    seed = (pixel_shift(pix, 1000 + depth) * 4294967296.0).astype(np.uint32)
    index = owen_scramble(sub.astype(np.uint32), seed)
    x = reverse_bits(index)
    y = np.zeros_like(index)
    for bit, v in enumerate(SOBOL_DIM1):
        y ^= np.where((index >> np.uint32(bit)) & np.uint32(1), np.uint32(v), np.uint32(0))
    x = owen_scramble(x, seed * np.uint32(0x9E3779B9) + np.uint32(1))
    y = owen_scramble(y, seed * np.uint32(0x85EBCA6B) + np.uint32(2))
    scale = 1.0 / 4294967296.0
    return (x.astype(np.float64) + 0.5) * scale, (y.astype(np.float64) + 0.5) * scale


KERNEL = True  # evaluate the core material compiled (renderer.methods.material_kernel; False: numpy)
# the lobes the compiled evaluate leaves to the numpy one (the path integrator's BSDF reads them)
EXTENSION_LOBES = ("clearcoat", "sheen", "iridescence", "anisotropy", "diffuse_transmission")


def hit_material(ts: TraceScene, origins: np.ndarray, dirs: np.ndarray, prim: np.ndarray,
                 u: np.ndarray, v: np.ndarray, t: np.ndarray, lobes: bool = True) -> trace_material.Hits:
    """The material at every ray's hit (rows of misses: Hits.empty's). `lobes` False: only the
    core model and KHR_materials_specular are filled (what the Fresnel tree reads; the other
    lobes keep their defaults), which the compiled evaluate does for any material; with `lobes`
    a material that uses an extension lobe sends the bounce to trace_material.evaluate."""
    n = len(prim)
    surf = ts.surface
    if surf is None:
        return trace_material.Hits.empty(n)
    if KERNEL and not (lobes and any(sm.material.uses(x) for sm in surf.materials
                                     for x in EXTENSION_LOBES)):
        from renderer.methods import material_kernel  # numba loads only in a process that traces
        hits = trace_material.Hits(np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n),
                                   np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n),
                                   np.empty((n, 3)))
        d = np.ascontiguousarray(dirs, np.float64)
        material_kernel.evaluate(  # type: ignore[call-arg]
            prim, u, v, t, np.ascontiguousarray(origins, np.float64), d, np.asarray(ts.eye, np.float64),
            float(ts.spread), ts.normals, ts.material, *trace_material.pack(surf), hits.normal,
            hits.base, hits.metallic, hits.roughness, hits.transmission, hits.emission,
            hits.occlusion, hits.specular, hits.specular_color)
        if lobes:  # the extension lobes at their defaults (no material here uses them)
            defaults = trace_material._lobe_defaults(n, hits.normal)
            (hits.clearcoat, hits.clearcoat_roughness, hits.clearcoat_normal, hits.sheen_color,
             hits.sheen_roughness, hits.iridescence, hits.iridescence_ior, hits.iridescence_thickness,
             hits.anisotropy, hits.anisotropy_t, hits.diffuse_transmission,
             hits.diffuse_transmission_color) = defaults[2:]
        return _facing_viewer(ts, hits, dirs, prim)
    full = trace_material.Hits.empty(n)
    sel = np.flatnonzero(prim >= 0)
    if not len(sel):
        return full
    width = ts.spread * (np.linalg.norm(origins[sel] - ts.eye, axis=-1) + t[sel])
    got = trace_material.evaluate(surf, ts.normals, ts.material[prim[sel]], prim[sel],
                                  u[sel], v[sel], dirs[sel], width)
    for f in dataclasses.fields(trace_material.Hits):
        getattr(full, f.name)[sel] = getattr(got, f.name)
    return _facing_viewer(ts, full, dirs, prim)


def _facing_viewer(ts: TraceScene, hits: trace_material.Hits, dirs: np.ndarray,
                   prim: np.ndarray) -> trace_material.Hits:
    """Hits on a Material.face_viewer surface (a USD point's disc) take the camera's axis,
    reversed, as their normal (Storm's eye-space +Z, as the raster does), or where a ray meets
    it from behind that axis (a bounce), the normal toward the ray's origin."""
    if not ts.sprite.any():
        return hits
    rows = np.flatnonzero(prim >= 0)
    rows = rows[ts.sprite[ts.material[prim[rows]]]]
    if len(rows):
        d = np.asarray(dirs[rows], np.float64)
        n = -d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-20)
        axis = -np.asarray(ts.forward, np.float64)
        n[np.einsum("ij,j->i", n, axis) > 0] = axis
        hits.normal[rows] = n
        if len(hits.clearcoat_normal) == len(hits.normal):
            hits.clearcoat_normal[rows] = n
    return hits
