"""The ray tracer's surface data: the material each hit sees, textures included.

For every hit the tracer reads the same baked material the raster path does: factors times
textures (base colour, metal-rough, normal, occlusion, emissive, transmission), each with its
KHR_texture_transform, UV set and sampler, times vertex colours; the shading normal is the
interpolated vertex normal perturbed by the normal map in the baked tangent frame (as
shaders/material_info.glsl). Texels are read bilinearly from the baked mip chain (sRGB ones
decoded to linear first, as GL's sRGB textures filter in linear light), the level chosen from
the ray's footprint: a ray cone of `spread` radians per unit length (a camera ray's share of a
pixel), widened over the distance from the eye (Akenine-Moeller et al. 2019, without the
curvature term: a lower bound on secondary rays' footprints), against the triangle's texel
density. A hit's alpha (base colour alpha x texture alpha x vertex alpha) decides MASK
(cut-off) and BLEND (the ray passes with probability 1 - alpha: stochastic transparency,
unbiased and deterministic per ray).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from core.baked import BakedAsset, dequantise_directions
from core.lobes import BY_NAME, ao_multibounce
from core.scene import LINEAR, LINEAR_MIPMAP_LINEAR, NEAREST, Material, TextureRef, is_srgb

MIRRORED_REPEAT, CLAMP_TO_EDGE = 33648, 33071
NEAREST_MIPMAP_NEAREST, LINEAR_MIPMAP_NEAREST, NEAREST_MIPMAP_LINEAR = 9984, 9985, 9986
# The texture slots the tracer samples: every lobe's but volume thickness (the tracer
# measures the distance travelled inside) (core/lobes.py).
SLOTS = tuple(s.name for row in ("core", "transmission", "specular", "clearcoat", "sheen",
                                 "iridescence", "anisotropy", "diffuse_transmission")
              for s in BY_NAME[row].slots)


FETCH_MS = [0.0]  # wall time in texel fetches, summed over the process (the path tracer's split)


@dataclass
class TextureChain:
    """One texture's mip levels in one colour space, stored flat for the compiled sampler."""
    levels: list[np.ndarray]  # RGBA8, level 0 first
    srgb: bool
    wrap: tuple[int, int]     # (s, t) GL wrap modes
    mag: int
    min: int

    def __post_init__(self):
        self.texels = np.ascontiguousarray(np.concatenate([lv.reshape(-1, 4) for lv in self.levels]))
        sizes = [lv.shape[0] * lv.shape[1] for lv in self.levels]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.heights = np.asarray([lv.shape[0] for lv in self.levels], np.int64)
        self.widths = np.asarray([lv.shape[1] for lv in self.levels], np.int64)

    def sample(self, uv: np.ndarray, lod: np.ndarray) -> np.ndarray:
        """N x 4 float (linear RGB, alpha) at `uv` (N x 2, glTF: v = 0 is row 0) and mip
        level `lod` (N; log2 of the footprint in level-0 texels), as the sampler filters."""
        mip_mode = (0 if self.min in (NEAREST, LINEAR) else
                    1 if self.min in (NEAREST_MIPMAP_NEAREST, LINEAR_MIPMAP_NEAREST) else 2)
        min_nearest = self.min in (NEAREST, NEAREST_MIPMAP_NEAREST, NEAREST_MIPMAP_LINEAR)
        # numba's import costs ~0.6 s, which a process that never ray traces skips
        from renderer.methods import texel_kernel
        t0 = time.perf_counter()
        out = texel_kernel.sample_texture(
            self.texels, self.offsets, self.heights, self.widths,
            np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(lod, np.float64),
            self.srgb, int(self.wrap[0]), int(self.wrap[1]), self.mag == NEAREST, min_nearest,
            mip_mode)
        FETCH_MS[0] += (time.perf_counter() - t0) * 1e3
        return out


@dataclass
class Slot:
    """A material's texture slot: the chain, its UV set and transform."""
    chain: TextureChain
    uv_set: int
    uvm: np.ndarray  # 3 x 3 KHR_texture_transform


@dataclass
class SurfaceMaterial:
    """Material k as the tracer evaluates it."""
    material: Material
    slots: dict[str, Slot] = field(default_factory=dict)


@dataclass
class Surface:
    """Per-triangle data the tracer interpolates at hits (world space), and the materials."""
    uv: list[np.ndarray | None]          # per UV set: T x 3 x 2 (None: no mesh has the set)
    texel_density: list[np.ndarray | None]  # per UV set: T, sqrt(uv area / world area)
    tangents: np.ndarray | None          # T x 3 x 4 (w = 0: the mesh has none)
    colors: np.ndarray | None            # T x 3 x 4 linear (1 where a mesh has none)
    materials: list[SurfaceMaterial]
    alpha_tested: np.ndarray             # K bool: MASK or BLEND (rays may pass through)
    corners: np.ndarray | None = None    # T x 3 x 3 world corners (tangents from UVs)
    ao: np.ndarray | None = None         # T x 3 x 2 baked visibility, front and back (1: none)
    bent: np.ndarray | None = None       # T x 3 x 6 world bent normals, front xyz, back xyz (0: none)
    packed: tuple | None = None          # the tables of the compiled evaluate (pack), once built


def build_surface(asset: BakedAsset, materials: list[Material], parts: list[tuple[int, np.ndarray, np.ndarray]],
                  world: np.ndarray, texture_top: int | None) -> Surface:
    """`parts`: per placed mesh (mesh index, its T x 3 index array in world winding, the 3 x 3
    linear part of its transform), each mesh's placements in its transforms' order (the baked
    visibility may hold a row per placement); `world`: all T x 3 x 3 world corners in the same
    order."""
    n_sets = 2
    uv: list[list[np.ndarray]] = [[] for _ in range(n_sets)]
    have_uv = [False] * n_sets
    tangents, colors, aos, bents = [], [], [], []
    have_tan = have_col = have_ao = have_bent = False
    placement: dict[int, int] = {}  # parts list each mesh's placements in transforms' order
    for k, idx, lin in parts:
        mesh = asset.meshes[k]
        t = len(idx)
        row = placement[k] = placement.get(k, -1) + 1
        for s, arr in enumerate((mesh.uv0, mesh.uv1)):
            if arr is not None:
                have_uv[s] = True
                uv[s].append(np.asarray(arr, np.float64)[idx])
            else:
                uv[s].append(np.zeros((t, 3, 2)))
        if mesh.tangents is not None:
            have_tan = True
            tan = np.asarray(mesh.tangents, np.float64)[idx]
            xyz = tan[..., :3] @ lin.T
            w = np.where(tan[..., 3:4] < 0, -1.0, 1.0) * (1.0 if np.linalg.det(lin) >= 0 else -1.0)
            tangents.append(np.concatenate([xyz, w], axis=-1))
        else:
            tangents.append(np.zeros((t, 3, 4)))
        if mesh.colors is not None:
            have_col = True
            c = np.asarray(mesh.colors, np.float64)
            if c.shape[1] == 3:
                c = np.concatenate([c, np.ones((len(c), 1))], axis=1)
            colors.append(c[idx])
        else:
            colors.append(np.ones((t, 3, 4)))
        if (vis := mesh.visibility(row)) is not None:
            have_ao = True
            aos.append(vis.astype(np.float64).reshape(-1, 2)[idx])
        else:
            aos.append(np.ones((t, 3, 2)))
        if vis is not None and mesh.bent is not None and not mesh.ao_per_placement \
                and len(mesh.bent) == len(mesh.positions):
            have_bent = True  # turned as normals are (the raster's normal matrix), unnormalised
            b = dequantise_directions(mesh.bent).astype(np.float64)
            to_world = np.linalg.inv(lin)
            bents.append(np.concatenate([b[:, :3] @ to_world, b[:, 3:] @ to_world], axis=1)[idx])
        else:
            bents.append(np.zeros((t, 3, 6)))
    area = 0.5 * np.linalg.norm(np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0]), axis=-1)
    uvs: list[np.ndarray | None] = []
    density: list[np.ndarray | None] = []
    for s in range(n_sets):
        if not have_uv[s] or not uv[s]:
            uvs.append(None)
            density.append(None)
            continue
        a = np.concatenate(uv[s])
        e1, e2 = a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        uvs.append(a)
        density.append(np.sqrt(uv_area / np.maximum(area, 1e-30)))
    chains: dict[tuple[int, bool], TextureChain] = {}
    surf_mats = []
    for mat in materials:
        sm = SurfaceMaterial(mat)
        for slot in SLOTS:
            ref: TextureRef | None = getattr(mat, f"{slot}_texture")
            if ref is None or not 0 <= ref.texture < len(asset.textures) or uvs[min(ref.uv_set, 1)] is None:
                continue
            key = (ref.texture, is_srgb(slot))
            if key not in chains:
                tex = asset.textures[ref.texture]
                chains[key] = TextureChain(tex.mips(key[1], texture_top), key[1],
                                           (tex.sampler.wrap_s, tex.sampler.wrap_t),
                                           tex.sampler.mag_filter or LINEAR,
                                           tex.sampler.min_filter or LINEAR_MIPMAP_LINEAR)
            sm.slots[slot] = Slot(chains[key], min(ref.uv_set, 1), ref.uv_matrix().astype(np.float64))
        surf_mats.append(sm)
    alpha_tested = np.asarray([m.alpha_mode in ("MASK", "BLEND") for m in materials], bool)
    return Surface(uvs, density, np.concatenate(tangents) if have_tan and tangents else None,
                   np.concatenate(colors) if have_col and colors else None, surf_mats, alpha_tested,
                   np.asarray(world, np.float64), np.concatenate(aos) if have_ao and aos else None,
                   np.concatenate(bents) if have_bent and bents else None)


def bent_at(surf: Surface | None, prim: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray | None:
    """N x 6 baked bent normals at the hits (front xyz, back xyz; world, unnormalised,
    interpolated as the raster's varyings are; 0 on misses and meshes without), or None where
    no mesh has them."""
    if surf is None or surf.bent is None:
        return None
    out = np.zeros((len(prim), 6))
    hit = np.flatnonzero(prim >= 0)
    out[hit] = _interp(surf.bent[prim[hit]], u[hit].astype(np.float64), v[hit].astype(np.float64))
    return out


def pack(surf: Surface) -> tuple:
    """The surface as renderer.methods.material_kernel.evaluate reads it (built once a scene):
    per-material factors and flags, per (material, slot) its chain, UV set and 2 x 3 transform,
    every chain's levels in one flat texel array, and the per-triangle arrays (empty where
    absent)."""
    if surf.packed is not None:
        return surf.packed
    from renderer.methods import material_kernel as mk  # numba: only a process that traces
    F_BASE, F_METAL, F_ROUGH, F_TRANS, F_EMIS = mk.F_BASE, mk.F_METAL, mk.F_ROUGH, mk.F_TRANS, mk.F_EMIS
    F_OCC, F_NSCALE, F_SPEC, F_SPEC_COL, N_F, K_SLOTS = mk.F_OCC, mk.F_NSCALE, mk.F_SPEC, mk.F_SPEC_COL, mk.N_F, mk.SLOTS
    n_k = len(surf.materials)
    mat_f = np.zeros((max(n_k, 1), N_F))
    mat_i = np.zeros((max(n_k, 1), 2), np.int64)
    slot_chain = np.full((max(n_k, 1), len(K_SLOTS)), -1, np.int64)
    slot_uv = np.zeros((max(n_k, 1), len(K_SLOTS)), np.int64)
    slot_m = np.zeros((max(n_k, 1), len(K_SLOTS), 6))
    chains: list[TextureChain] = []
    for k, sm in enumerate(surf.materials):
        m = sm.material
        mat_f[k, F_BASE:F_BASE + 3] = m.base_color[:3]
        mat_f[k, F_METAL], mat_f[k, F_ROUGH], mat_f[k, F_TRANS] = m.metallic, m.roughness, m.transmission
        mat_f[k, F_EMIS:F_EMIS + 3] = np.asarray(m.emissive, np.float64) * m.emissive_strength
        mat_f[k, F_OCC], mat_f[k, F_NSCALE], mat_f[k, F_SPEC] = m.occlusion_strength, m.normal_scale, m.specular
        mat_f[k, F_SPEC_COL:F_SPEC_COL + 3] = m.specular_color
        mat_i[k] = (bool(m.unlit), m.uses("specular"))
        for s, name in enumerate(K_SLOTS):
            slot = sm.slots.get(name)
            if slot is None:
                continue
            at = next((j for j, c in enumerate(chains) if c is slot.chain), None)
            if at is None:
                at = len(chains)
                chains.append(slot.chain)
            slot_chain[k, s], slot_uv[k, s] = at, slot.uv_set
            slot_m[k, s] = slot.uvm[:2].reshape(-1)
    if chains:
        texels = np.ascontiguousarray(np.concatenate([c.texels for c in chains]))
        starts = np.cumsum([0] + [len(c.texels) for c in chains])
        lv_off = np.concatenate([c.offsets + starts[j] for j, c in enumerate(chains)]).astype(np.int64)
        lv_h = np.concatenate([c.heights for c in chains]).astype(np.int64)
        lv_w = np.concatenate([c.widths for c in chains]).astype(np.int64)
        ch_nlv = np.asarray([len(c.offsets) for c in chains], np.int64)
        ch_lv0 = np.concatenate([[0], np.cumsum(ch_nlv)[:-1]]).astype(np.int64)
        ch_i = np.asarray([(c.srgb, c.wrap[0], c.wrap[1], c.mag == NEAREST,
                            c.min in (NEAREST, NEAREST_MIPMAP_NEAREST, NEAREST_MIPMAP_LINEAR),
                            0 if c.min in (NEAREST, LINEAR) else
                            1 if c.min in (NEAREST_MIPMAP_NEAREST, LINEAR_MIPMAP_NEAREST) else 2)
                           for c in chains], np.int64)
    else:
        texels = np.zeros((1, 4), np.uint8)
        lv_off, lv_h, lv_w = np.zeros(1, np.int64), np.ones(1, np.int64), np.ones(1, np.int64)
        ch_lv0, ch_nlv, ch_i = np.zeros(1, np.int64), np.ones(1, np.int64), np.zeros((1, 6), np.int64)

    def arr(a: np.ndarray | None, shape: tuple) -> np.ndarray:
        return np.zeros(shape) if a is None else np.ascontiguousarray(a, np.float64)
    uv0, uv1 = arr(surf.uv[0], (0, 3, 2)), arr(surf.uv[1], (0, 3, 2))
    dens0, dens1 = arr(surf.texel_density[0], (0,)), arr(surf.texel_density[1], (0,))
    surf.packed = (mat_f, mat_i, slot_chain, slot_uv, slot_m, texels, lv_off, lv_h, lv_w, ch_lv0,
                   ch_nlv, ch_i, uv0, uv1, dens0, dens1, surf.uv[0] is not None,
                   arr(surf.tangents, (0, 3, 4)), surf.tangents is not None,
                   arr(surf.corners, (0, 3, 3)), arr(surf.colors, (0, 3, 4)),
                   surf.colors is not None, arr(surf.ao, (0, 3, 2)), surf.ao is not None)
    return surf.packed


def _interp(corners: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return ((1 - u - v)[:, None] * corners[:, 0] + u[:, None] * corners[:, 1]
            + v[:, None] * corners[:, 2])


def _lookup(surf: Surface, slot: Slot, prim, u, v, width, cos_d, memo: dict | None = None) -> np.ndarray:
    """Texel of `slot` at the hits (prim, u, v) for a ray footprint `width` (world units).
    `memo` keeps each UV set's interpolated coordinates and footprint for the next slot."""
    key = slot.uv_set
    if memo is not None and key in memo:
        uv0, foot = memo[key]
    else:
        uv0 = _interp(surf.uv[key][prim], u, v)  # type: ignore[index]
        # the footprint in UV units: cone width over the surface's slant, times texel density
        foot = width * surf.texel_density[key][prim] / np.maximum(cos_d, 0.05)  # type: ignore[index]
        if memo is not None:
            memo[key] = uv0, foot
    uv = uv0 @ slot.uvm[:2, :2].T + slot.uvm[:2, 2]
    h, w = slot.chain.levels[0].shape[:2]
    scale = math.sqrt(abs(np.linalg.det(slot.uvm[:2, :2])) * w * h)
    lod = np.log2(np.maximum(foot * scale, 1e-30))
    return slot.chain.sample(uv, lod)


def base_rgba(surf: Surface, material: np.ndarray, prim, u, v, width, cos_d) -> np.ndarray:
    """N x 4 linear base colour and coverage alpha (factor x texture x vertex colour) at the
    hits (`material` per hit), as evaluate has it: alpha tests read A, a shadow ray through
    glass is tinted by RGB."""
    out = np.empty((len(prim), 4))
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    for k in np.unique(material):
        sm = surf.materials[k]
        sel = np.flatnonzero(material == k)
        b = np.broadcast_to(np.asarray(sm.material.base_color, np.float64), (len(sel), 4)).copy()
        slot = sm.slots.get("base_color")
        if slot is not None:
            b *= _lookup(surf, slot, prim[sel], u[sel], v[sel], width[sel], cos_d[sel])
        if surf.colors is not None:
            b *= _interp(surf.colors[prim[sel]], u[sel], v[sel])
        out[sel] = b
    return out


def passes_through(surf: Surface, material: np.ndarray, prim, u, v, width, cos_d,
                   draw: np.ndarray) -> np.ndarray:
    """Which hits on alpha-tested materials the ray goes through: MASK below the cut-off;
    BLEND where `draw` (uniform per ray) >= alpha."""
    a = base_rgba(surf, material, prim, u, v, width, cos_d)[:, 3]
    mode = np.asarray([surf.materials[k].material.alpha_mode for k in material])
    cutoff = np.asarray([surf.materials[k].material.alpha_cutoff for k in material], np.float64)
    return np.where(mode == "MASK", a < cutoff, draw >= a)


@dataclass
class Hits:
    """The material at each hit, as the shading kernel (the core model) and the path
    tracer's BSDF (every lobe, renderer.methods.path_bsdf) read it."""
    normal: np.ndarray     # N x 3 shading normal (front side, before facing the ray)
    base: np.ndarray       # N x 3 linear
    metallic: np.ndarray   # N
    roughness: np.ndarray  # N
    transmission: np.ndarray  # N
    emission: np.ndarray   # N x 3
    occlusion: np.ndarray  # N
    # the Khronos lobes (their glTF defaults where a material has none)
    specular: np.ndarray = field(default_factory=lambda: np.zeros(0))          # N factor
    specular_color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    clearcoat: np.ndarray = field(default_factory=lambda: np.zeros(0))
    clearcoat_roughness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    clearcoat_normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # front side
    sheen_color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sheen_roughness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iridescence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iridescence_ior: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iridescence_thickness: np.ndarray = field(default_factory=lambda: np.zeros(0))  # nm
    anisotropy: np.ndarray = field(default_factory=lambda: np.zeros(0))        # strength
    anisotropy_t: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # grain (0: none)
    diffuse_transmission: np.ndarray = field(default_factory=lambda: np.zeros(0))
    diffuse_transmission_color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @classmethod
    def empty(cls, n: int) -> "Hits":
        """N rows of a black, diffuse, default-extension material."""
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n),
                   np.zeros((n, 3)), np.ones(n), *_lobe_defaults(n, np.zeros((n, 3))))


def _lobe_defaults(n: int, normal: np.ndarray) -> tuple[np.ndarray, ...]:
    return (np.ones(n), np.ones((n, 3)), np.zeros(n), np.zeros(n), normal.copy(), np.zeros((n, 3)),
            np.zeros(n), np.zeros(n), np.full(n, 1.3), np.zeros(n), np.zeros(n), np.zeros((n, 3)),
            np.zeros(n), np.ones((n, 3)))


def _perturb(t: np.ndarray, tan: np.ndarray, ng: np.ndarray, scale: float) -> np.ndarray:
    """The normal map's texels t (N x 4, 0..1) in the tangent frame `tan` (N x 4, w the
    handedness) about ng, xy scaled by `scale` (as shaders/material_info.glsl)."""
    tt = tan[:, :3] - ng * np.einsum("ij,ij->i", ng, tan[:, :3])[:, None]
    tt /= np.maximum(np.linalg.norm(tt, axis=-1, keepdims=True), 1e-20)
    bt = np.cross(ng, tt) * np.sign(tan[:, 3])[:, None]
    tn = t[:, :3] * 2.0 - 1.0
    tn[:, :2] *= scale
    pert = tn[:, :1] * tt + tn[:, 1:2] * bt + tn[:, 2:3] * ng
    pert /= np.maximum(np.linalg.norm(pert, axis=-1, keepdims=True), 1e-20)
    return np.where(np.isfinite(pert).all(axis=1, keepdims=True), pert, ng)


def _tangents(surf: Surface, p: np.ndarray, u: np.ndarray, v: np.ndarray, ng: np.ndarray) -> np.ndarray:
    """N x 4 tangent frames at hits: the baked tangents, else the triangle's dP/du from UV
    set 0 (as the raster derives them from derivatives), else w = 0 (none)."""
    out = np.zeros((len(p), 4))
    if surf.tangents is not None:
        out = _interp(surf.tangents[p], u, v)
    need = np.flatnonzero(np.abs(out[:, 3]) <= 0.5)
    if len(need) and surf.uv[0] is not None and surf.corners is not None:
        c, uv = surf.corners[p[need]], surf.uv[0][p[need]]
        e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
        ok = np.abs(det) > 1e-12
        safe = np.where(ok, det, 1.0)[:, None]
        t = (d2[:, 1:2] * e1 - d1[:, 1:2] * e2) / safe
        bvec = (d1[:, 0:1] * e2 - d2[:, 0:1] * e1) / safe
        hand = np.where(np.einsum("ij,ij->i", np.cross(ng[need], t), bvec) < 0, -1.0, 1.0)
        good = ok & (np.linalg.norm(t, axis=-1) > 0)
        out[need[good], :3] = t[good]
        out[need[good], 3] = hand[good]
    return out


def evaluate(surf: Surface, normals: np.ndarray, material: np.ndarray, prim: np.ndarray,
             u: np.ndarray, v: np.ndarray, d: np.ndarray, width: np.ndarray) -> Hits:
    """Hits (prim >= 0 everywhere) -> their material. `normals`: T x 3 x 3 vertex normals;
    `d`: ray directions; `width`: the ray cone's width at each hit."""
    u, v = u.astype(np.float64), v.astype(np.float64)
    n = len(prim)
    ns = _interp(normals[prim].astype(np.float64), u, v)
    ns /= np.maximum(np.linalg.norm(ns, axis=-1, keepdims=True), 1e-20)
    cos_d = np.abs(np.einsum("ij,ij->i", d, ns))
    base = np.empty((n, 3))
    metal, rough, trans, occ = np.empty(n), np.empty(n), np.empty(n), np.ones(n)
    emis = np.empty((n, 3))
    lobe = Hits(ns, base, metal, rough, trans, emis, occ, *_lobe_defaults(n, ns))
    for k in np.unique(material):
        sm = surf.materials[k]
        m = sm.material
        sel = np.flatnonzero(material == k)
        p, uu, vv = prim[sel], u[sel], v[sel]
        memo: dict = {}
        at = (p, uu, vv, width[sel], cos_d[sel], memo)

        def tex(name: str, sm=sm, at=at) -> np.ndarray | None:
            slot = sm.slots.get(name)
            return None if slot is None else _lookup(surf, slot, *at)
        b = np.broadcast_to(np.asarray(m.base_color[:3], np.float64), (len(sel), 3)).copy()
        t = tex("base_color")
        if t is not None:
            b *= t[:, :3]
        if surf.colors is not None:
            b *= _interp(surf.colors[p], uu, vv)[:, :3]
        base[sel] = b
        mr = tex("metallic_roughness")
        metal[sel] = np.clip(m.metallic * (1.0 if mr is None else mr[:, 2]), 0, 1)
        rough[sel] = np.clip(m.roughness * (1.0 if mr is None else mr[:, 1]), 0, 1)
        tr = tex("transmission")
        trans[sel] = m.transmission * (1.0 if tr is None else tr[:, 0])
        e = np.broadcast_to(np.asarray(m.emissive, np.float64) * m.emissive_strength, (len(sel), 3)).copy()
        t = tex("emissive")
        if t is not None:
            e *= t[:, :3]
        emis[sel] = e
        if m.unlit:  # the colour as it is, emitted; nothing reflected
            emis[sel], base[sel], metal[sel], trans[sel] = base[sel], 0.0, 0.0, 0.0
            continue
        t = tex("occlusion")
        if t is not None:
            occ[sel] = 1.0 + m.occlusion_strength * (t[:, 0] - 1.0)
        interp_n = ns[sel].copy()  # before the normal map: the clearcoat's and the grain's
        lazy_tan: list[np.ndarray] = []

        def tangent(p=p, uu=uu, vv=vv, ng=interp_n, lazy=lazy_tan) -> np.ndarray:
            if not lazy:
                lazy.append(_tangents(surf, p, uu, vv, ng))
            return lazy[0]
        t = tex("normal")
        if t is not None and (surf.tangents is not None or surf.uv[0] is not None):
            tan = tangent()
            ok = np.abs(tan[:, 3]) > 0.5
            if np.any(ok):
                ns[sel[ok]] = _perturb(t[ok], tan[ok], interp_n[ok], m.normal_scale)
        _lobes(m, lobe, sel, tex, tangent, interp_n, ns)
    if surf.ao is not None:  # the baked visibility of the side the ray meets (core.lobes)
        ao = _interp(surf.ao[prim], u, v)
        side = np.where(np.einsum("ij,ij->i", d, _interp(normals[prim].astype(np.float64), u, v)) < 0, 0, 1)
        albedo = (base * (1.0 - metal)[:, None]).mean(axis=1)
        lobe.occlusion[:] = np.minimum(occ, ao_multibounce(ao[np.arange(n), side], albedo))
    return lobe


def _lobes(m: Material, h: Hits, sel: np.ndarray, tex, tangent, ng: np.ndarray, ns: np.ndarray) -> None:
    """The Khronos lobes of material m at rows `sel` of h: factors x textures, with the
    channels shaders/material_info.glsl reads."""
    def times(factor, name: str, channels) -> np.ndarray:
        f = np.broadcast_to(np.asarray(factor, np.float64), (len(sel),) + np.shape(factor)).copy()
        t = tex(name)
        return f if t is None else f * t[:, channels]
    if m.uses("specular"):
        h.specular[sel] = times(m.specular, "specular", 3)
        h.specular_color[sel] = times(m.specular_color, "specular_color", slice(0, 3))
    if m.uses("clearcoat"):
        h.clearcoat[sel] = np.clip(times(m.clearcoat, "clearcoat", 0), 0, 1)
        h.clearcoat_roughness[sel] = np.clip(times(m.clearcoat_roughness, "clearcoat_roughness", 1), 0, 1)
        h.clearcoat_normal[sel] = ng  # the base's normal map lies under the coat
        t = tex("clearcoat_normal")
        if t is not None:
            tan = tangent()
            ok = np.abs(tan[:, 3]) > 0.5
            if np.any(ok):
                h.clearcoat_normal[sel[ok]] = _perturb(t[ok], tan[ok], ng[ok], m.clearcoat_normal_scale)
    if m.uses("sheen"):
        h.sheen_color[sel] = times(m.sheen_color, "sheen_color", slice(0, 3))
        h.sheen_roughness[sel] = np.clip(times(m.sheen_roughness, "sheen_roughness", 3), 0, 1)
    if m.uses("iridescence"):
        h.iridescence[sel] = np.clip(times(m.iridescence, "iridescence", 0), 0, 1)
        h.iridescence_ior[sel] = m.iridescence_ior
        lo, hi = m.iridescence_thickness_range
        t = tex("iridescence_thickness")
        h.iridescence_thickness[sel] = hi if t is None else lo + (hi - lo) * t[:, 1]
    if m.uses("anisotropy"):
        d = np.tile([1.0, 0.0], (len(sel), 1))
        strength = np.full(len(sel), m.anisotropy_strength)
        t = tex("anisotropy")
        if t is not None:
            d = t[:, :2] * 2.0 - 1.0
            d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
            strength = strength * t[:, 2]
        c, s = math.cos(m.anisotropy_rotation), math.sin(m.anisotropy_rotation)
        d = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], -1)
        tan = tangent()
        ok = np.abs(tan[:, 3]) > 0.5
        tt = tan[:, :3] - ng * np.einsum("ij,ij->i", ng, tan[:, :3])[:, None]
        tt /= np.maximum(np.linalg.norm(tt, axis=-1, keepdims=True), 1e-20)
        bt = np.cross(ng, tt) * np.sign(tan[:, 3])[:, None]
        grain = tt * d[:, :1] + bt * d[:, 1:2]
        n = ns[sel]
        grain -= n * np.einsum("ij,ij->i", n, grain)[:, None]  # onto the shading normal's plane
        grain /= np.maximum(np.linalg.norm(grain, axis=-1, keepdims=True), 1e-20)
        h.anisotropy[sel] = np.clip(strength, 0, 1)
        h.anisotropy_t[sel] = np.where(ok[:, None], grain, 0.0)  # no frame: isotropic
    if m.uses("diffuse_transmission"):
        share = times(m.diffuse_transmission, "diffuse_transmission", 3)
        h.diffuse_transmission[sel] = np.clip(share, 0, 1)  # of the dielectric's diffuse
        h.diffuse_transmission_color[sel] = times(m.diffuse_transmission_color, "diffuse_transmission_color",
                                                  slice(0, 3))
