"""The `auto` method: model no more than a scene needs, per object and per request, and say why.

For each mesh, `auto` looks at cheap facts (material class and IOR, topology, thickness, size
on screen, whether the camera is inside it) and picks the cheapest method whose error the
speed-vs-accuracy chart and the stability suite (bench/accuracy.py, bench/stability.py) show
to be within tolerance of the best raster method:

- opaque, mask and blend materials: the PBR + IBL raster pass only (the bake computed no
  interior vectors for them, and no refraction pass or texture is allocated);
- transmissive, `single` where it is within tolerance of `wyman`: IOR near 1, tiny on screen,
  camera inside (no front face to refract at); nowhere else on the chart's set. Thin objects
  keep `wyman`: the exit face undoes the entry refraction, which single misses (stability
  suite, slab: single FLIP 0.31, wyman 0.06);
- thin-walled transmissive (glTF: no volume, or thickness 0): `single`, exact for a sheet that
  light crosses unbent (renderer/methods/refraction.py THIN_WALLED), never a raster failure;
- transmissive otherwise: `wyman`, with the request's TIR treatment or else `reflect` when a
  wyman object has flat faces (exit TIR is common there) and the cheaper `paper` otherwise;
- `raytrace` for the whole frame only when the request gives a time budget
  (RenderOptions.budget_ms), the estimated ray-trace time fits it, and some object is in
  a case where the raster methods fail (genus > 0 at IOR >= RAYTRACE_MIN_IOR, an open mesh,
  diamond-like IOR, the camera inside) or glass whose look the raster only approximates
  (`raster_approximates`: Beer-Lambert attenuation, which the raster takes from the thickness
  factor instead of the path through the glass; dispersion; textured glass. `bench accuracy`,
  128 px: the absorbing vase ray traced 0.063 FLIP against wyman's 0.408, the textured sphere
  0.058 against 0.154).

`environment_face_size` sizes the environment bake for a request the same way: from the
output size and the smoothest material present. The decisions go into Frame.plan["auto"]
(the service's X-Render-Plan header; `asset-preview render --explain` prints them).
"""
from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field, replace
from typing import Any, Literal, cast

import numpy as np
from cachetools import LRUCache

from core.baked import BakedAsset, BakedMesh
from core.cubemap import default_face_size, default_levels
from core.options import RenderOptions, apply_override
from core.scene import Material
from renderer.view.camera import Camera
from renderer.view.framing import asset_camera

log = logging.getLogger(__name__)

# Thresholds, each from the chart / stability figures quoted in the README section of issue 7.
SINGLE_IOR_TOLERANCE = 0.02  # |IOR - 1| below this: the exit refraction bends rays by < 1 degree
# Single refraction is never within 10% of wyman on the chart's glass set (128 px,
# IOR 1.15..2.4, roughness 0 and 0.3): its object FLIP is 1.2-6.6x wyman's, rough glass included.
# Wyman's TIR treatment when the request names none. TIR at the exit is common behind flat
# faces (the internal ray keeps its angle) and rare behind curved ones (a sphere's exact exit
# never meets it). Chart, 128 px: on cubes tir=reflect's FLIP is 13-45% below tir=paper's
# (0.16 vs 0.30 at IOR 1.15); on smooth meshes within 0-5%, at 2-2.5x paper's time.
TIR_FLAT_SHARE = 0.5          # faceted share of the surface above which reflect pays
TINY_PX = 12.0               # projected diameter: below it the back-face pass buys nothing visible
RAYTRACE_MIN_IOR = 1.4       # genus > 0 at or above: wyman's torus FLIP 0.13-0.23 vs ray traced
#                              0.03 (chart); at 1.15-1.3 wyman is fine (0.04-0.09; stability
#                              torus at 1.2, the paper's Fig. 11 failure: 0.048)
DIAMOND_IOR = 2.0            # above it most exit rays are totally internally reflected
CONCAVE_CONVEXITY = 0.6      # bowl (0.4) degrades raster refraction; bunny, duck (> 0.8) do not
RAYTRACE_BOUNCES = 12        # RenderOptions' default (issue 26's front); the torus and diamond
#                              cases of the stability suite need 8
# Ray-trace time model (`asset-preview bench raycost`, bench/RESULTS.md "cost model"): fixed +
# per triangle (Embree build, material tables) + per frame pixel (centre rays, environment) +
# per traced pixel x rays a pixel x depth(bounces), by Fresnel split; the path integrator per
# traced pixel x path x depth. depth(b) = K (1 - exp(-b / K)): paths leave the glass, so late
# bounces carry fewer rays (the refit of issue 26's compiled material chose K -> infinity: depth
# = bounces). Refitted (issue 26's front, after the compiled environment reads) on the frames'
# CPU time, every thread's (`bench raycost --cpu`): on a shared machine a frame's wall time
# grows with the other work (its threads wait for a core: 1.3-2.4x its CPU time in that run;
# a wall run at load 6-7 measured 4.7x the quiet wall model), its CPU time much less; on a quiet machine
# the wall is at most the CPU time (the kernels' second core only shortens it). 5 glass scenes
# and the Duck at 64-256 px, tree and path (96 frames, 2 shared cores, 2026-12-03 19:43 UTC,
# load ~4): estimate / measured median 0.97 (per scene 0.77-1.06), |error| median 14%, rms
# 24%; rt_ms x RT_MODEL_FACTOR is at or above 92 of the 96 frames and every default-setting
# one (the worst: the Duck's first frame, 0.25, and the hollow vase with both children at
# 3 x 3, 0.34-0.47). With the whole frame traced (the service's estimate) it is under the
# measured time on 1 of 96 frames (median 1.9x over). The wall fit of 2026-12-02 (quiet)
# was 0.57x these CPU times. `sample` was not fitted: it traces fewer rays than roulette,
# which it borrows.
RT_FIXED_MS = 2.56
RT_MS_PER_TRIANGLE = 0.00298
RT_MS_PER_FRAME_PIXEL = 0.00251
RT_DEPTH_K = 1e9
RT_MS_PER_RAY_DEPTH = {"both": 0.000428, "roulette": 0.000173, "sample": 0.000173}
RT_MS_PER_PATH_DEPTH = 0.000721
RT_PATH_FIXED_MS = 82.6      # the path tracer's environment sampling tables, once a frame
RT_MODEL_FACTOR = 2.0        # a frame's CPU time is within this x rt_ms (the fit's spread)
# Emissive triangles (issue 26): both integrators sample a point on one at every surface a
# ray meets (the choice weighs up to LOCAL_EMITTERS of them by distance, one by one), read
# its emission and cast a shadow ray: the per-ray term x (1 + e), e = a share by integrator
# while any triangle emits + a share per emitter weighed. Fitted from on / off pairs of frames
# (`bench raycost`: a ratio, which a loaded machine scales alike; bench/RESULTS.md).
# 18 pairs on EmissiveStrengthTest (60 emitters), ClearCoatTest (36) and SpecGlossVsMetalRough
# (9020, of which 256 weighed) at 64 and 128 px, 2026-12-03 under a load of ~12: t_on / t_off
# median 1.61; the per-emitter share fitted to 0 (within the pairs' noise).
RT_EMITTER_SHARE = {"tree": 0.92, "path": 1.41}
RT_EMITTER_WEIGHED_SHARE = 0.0
# Raster time model (the service's cost estimate for scheduling and its ceiling): fixed + per
# frame pixel by method (MSAA 4x; wyman adds the back-face and refraction passes) + per
# triangle. Measured warm on the Duck, 2 shared cores: 1024 px opaque 0.38 s, wyman 1.09 s;
# 512 px 0.08 / 0.32 s; rounded up.
RASTER_FIXED_MS = 10.0
RASTER_MS_PER_PIXEL = {"opaque": 0.0004, "single": 0.0007, "wyman": 0.0011}
RASTER_MS_PER_TRIANGLE = 0.001
MAX_EXPLAINED_OBJECTS = 16    # more meshes than this are explained in groups (header size)
SMOOTH_ROUGHNESS = 0.05      # environment: a material smoother than this needs full-size faces


@dataclass(frozen=True)
class ObjectFacts:
    """What `auto` looks at for one mesh (all cheap; topology cached per mesh)."""
    mesh: str
    material_class: str
    ior: float
    roughness: float
    genus: int | None            # None: not a closed 2-manifold (open, or non-manifold edges)
    open_edges: int              # edges used by one triangle only
    convexity: float | None      # volume / convex hull volume (closed meshes; 1 = convex)
    normals_inward: float        # share of triangles whose stored normals oppose the winding
    faceted: float               # share of the surface shaded flat (vertex normals = face normal)
    thickness: float             # median interior distance / object diameter (1 = solid ball)
    screen_px: float             # projected diameter of the mesh's bounding sphere, pixels
    camera_inside: bool          # camera inside the mesh's world bounding box


@dataclass
class Decision:
    mesh: str
    method: str
    why: str
    facts: ObjectFacts | None = None


@dataclass
class Plan:
    """Per-object decisions and the per-request ones."""
    objects: list[Decision]
    frame_method: Literal["raytrace"] | None = None  # "raytrace" when the whole frame is ray traced
    tir: Literal["paper", "reflect"] | None = None  # wyman's TIR treatment for this request
    tir_why: str = ""
    bounces: int | None = None
    why: str = ""
    estimate_ms: dict = field(default_factory=dict)

    def method_for(self, index: int) -> tuple[str, str]:
        d = self.objects[index]
        return d.method, d.why

    def explain(self) -> dict:
        """JSON-ready summary (Frame.plan["auto"], the X-Render-Plan header)."""
        objects = [{"mesh": d.mesh, "method": d.method, "why": d.why} for d in self.objects]
        if len(objects) > MAX_EXPLAINED_OBJECTS:  # keep the HTTP header small: group alike
            groups: dict = {}
            for o in objects:
                g = groups.setdefault((o["method"], o["why"]), {**o, "count": 0})
                g["count"] += 1
            objects = list(groups.values())
        out: dict[str, Any] = {"request": self.why, "objects": objects}
        if self.tir:
            out["tir"] = self.tir
            out["tir_why"] = self.tir_why
        if self.frame_method:
            out["frame_method"] = self.frame_method
            out["bounces"] = self.bounces
        if self.estimate_ms:
            out["estimate_ms"] = {k: round(v, 1) for k, v in self.estimate_ms.items()}
        return out


# --- facts ----------------------------------------------------------------------------------

_topology_lock = threading.Lock()
_topology: LRUCache = LRUCache(64)  # id(positions) -> (positions, facts); the array checks the id


def topology(positions: np.ndarray, indices: np.ndarray) -> tuple[int | None, int]:
    """(genus or None, open edge count) of a triangle mesh, vertices welded by position.

    A closed 2-manifold with C components and Euler characteristic V - E + F has genus
    (2C - chi) / 2 summed over components; with open or non-manifold edges genus is None."""
    from scipy.sparse import coo_matrix  # scipy is heavy to import: only topology needs it
    from scipy.sparse.csgraph import connected_components

    _, weld = np.unique(np.round(np.asarray(positions, np.float64), 6), axis=0, return_inverse=True)
    tri = weld.reshape(-1)[np.asarray(indices, np.int64).reshape(-1)].reshape(-1, 3)
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    if len(tri) == 0:
        result: tuple[int | None, int] = (None, 0)
    else:
        e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        edges, count = np.unique(e, axis=0, return_counts=True)
        open_edges = int(np.sum(count == 1))
        used = np.unique(tri)
        if open_edges or np.any(count > 2):
            result = (None, open_edges)
        else:
            n = int(weld.max()) + 1
            graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
            labels = connected_components(graph, directed=False)[1][used]
            components = len(np.unique(labels))
            chi = len(used) - len(edges) + len(tri)
            result = (max(0, (2 * components - chi) // 2), 0)
    return result


@dataclass(frozen=True)
class MeshShape:
    """What auto needs of a mesh's geometry, independent of the request (computed once)."""
    genus: int | None
    open_edges: int
    convexity: float | None
    normals_inward: float
    faceted: float
    lo: np.ndarray                # object-space bounds
    hi: np.ndarray
    reach: float                  # farthest vertex from the bounds centre
    thickness: float              # median interior distance (else smallest extent) / diameter


def shape(mesh: BakedMesh) -> MeshShape:
    """The mesh's MeshShape, cached per positions array (a small LRU)."""
    key = id(mesh.positions)
    with _topology_lock:
        hit = _topology.get(key)
        if hit is not None and hit[0] is mesh.positions:
            return hit[1]
    pos = np.asarray(mesh.positions, np.float64)
    tri = np.asarray(mesh.indices, np.int64).reshape(-1, 3)
    p0, p1, p2 = pos[tri[:, 0]], pos[tri[:, 1]], pos[tri[:, 2]]
    winding = np.cross(p1 - p0, p2 - p0)
    area = np.linalg.norm(winding, axis=1)
    solid = area > 1e-3 * float(np.median(area)) if len(area) else area > 0  # slivers close nothing
    genus, open_edges = topology(pos, tri[solid])
    corner = np.asarray(mesh.normals, np.float64)[tri]  # T x 3 corners x 3
    stored = corner.sum(axis=1)
    inward = float(area[np.einsum("ij,ij->i", winding, stored) < 0].sum() / max(area.sum(), 1e-30))
    unit = winding / np.maximum(area, 1e-30)[:, None]
    corner = corner / np.maximum(np.linalg.norm(corner, axis=-1, keepdims=True), 1e-30)
    flat = np.all(np.abs(np.einsum("tki,ti->tk", corner, unit)) > 0.9998, axis=1)  # within ~1 deg
    faceted = float(area[flat].sum() / max(area.sum(), 1e-30))
    convexity = None
    if genus is not None:
        from scipy.spatial import ConvexHull  # heavy, as in topology()
        volume = abs(float(np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum()) / 6)
        try:
            convexity = round(min(1.0, volume / ConvexHull(pos).volume), 3)
        except Exception:  # flat or degenerate point sets have no hull volume
            convexity = None
    lo, hi = pos.min(0), pos.max(0)
    reach = float(np.sqrt(np.max(np.sum((pos - (lo + hi) / 2) ** 2, axis=1))))
    diameter = float(np.linalg.norm(hi - lo)) or 1.0
    if mesh.interior is not None and len(mesh.interior):
        thickness = float(np.median(cast(np.ndarray, mesh.interior_length))) / diameter
    else:
        thickness = float((hi - lo).min()) / diameter
    result = MeshShape(genus, open_edges, convexity, round(inward, 3), round(faceted, 3), lo, hi,
                       reach,
                       round(thickness, 4))
    with _topology_lock:
        _topology[key] = (mesh.positions, result)
    return result


def object_facts(mesh: BakedMesh, material: Material, camera: Camera) -> ObjectFacts:
    """The request-dependent facts (size on screen, camera inside) over the cached shape."""
    sh = shape(mesh)
    corners = np.array([[x, y, z] for x in (sh.lo[0], sh.hi[0]) for y in (sh.lo[1], sh.hi[1])
                        for z in (sh.lo[2], sh.hi[2])])
    mats = np.asarray(mesh.transforms, np.float64)
    pts = (corners @ mats[:, :3, :3].transpose(0, 2, 1) + mats[:, None, :3, 3]).reshape(-1, 3)
    wlo, whi = pts.min(0), pts.max(0)
    centre = (wlo + whi) / 2
    # Radius: the farthest vertex from the box centre, scaled by the largest instance scale.
    radius = sh.reach * max(float(np.linalg.norm(m[:3, :3], 2)) for m in mats[:64])
    dist = float(np.linalg.norm(np.asarray(camera.position) - centre))
    half = math.tan(math.radians(camera.fov) / 2)
    screen = camera.height * radius / max(dist * half, 1e-12) if dist > radius else math.inf
    inside = bool(np.all(camera.position >= wlo) and np.all(camera.position <= whi))
    return ObjectFacts(mesh.name, material.material_class, float(material.ior),
                       float(material.roughness), sh.genus, sh.open_edges, sh.convexity,
                       sh.normals_inward, sh.faceted, sh.thickness, round(float(screen), 1),
                       inside)


# --- decisions ------------------------------------------------------------------------------

def raster_fails(f: ObjectFacts) -> str | None:
    """Why the raster methods fail on this object (stability suite), or None."""
    if f.camera_inside:
        return "camera inside the object: no front face to refract at"
    if f.genus is None and f.open_edges:
        return f"open mesh ({f.open_edges} open edges): interior rays miss"
    if f.normals_inward > 0.5:
        return f"stored normals point inward on {f.normals_inward:.0%} of the surface"
    if f.convexity is not None and f.convexity < CONCAVE_CONVEXITY:
        return f"concave (volume {f.convexity:.2f} of its hull): refracted rays re-enter"
    if f.genus and f.ior >= RAYTRACE_MIN_IOR:
        return f"genus {f.genus} at IOR {f.ior:g}: rays cross the hole, >2 refractions"
    if f.ior >= DIAMOND_IOR:
        return f"IOR {f.ior:g}: strong total internal reflection, many internal bounces"
    return None


def raster_approximates(mat: Material) -> str | None:
    """Why the ray tracer shows this transmissive material better than raster can, though
    the raster does not fail on it, or None. The real assets of issue 26: absorbing glass
    (vases, bottles), dispersive glass, textured glass (stained glass, labels, normal-mapped)."""
    if math.isfinite(mat.attenuation_distance) and any(c < 1.0 for c in mat.attenuation_color):
        return (f"attenuation (colour {', '.join(f'{c:g}' for c in mat.attenuation_color)} at "
                f"{mat.attenuation_distance:g}): the raster reads the thickness factor, not the "
                "path through the glass")
    if mat.uses("dispersion"):
        return f"dispersion {mat.dispersion:g}: one IOR per colour channel"
    slots = [n for n, t in (("base colour", mat.base_color_texture),
                            ("transmission", mat.transmission_texture),
                            ("normal", mat.normal_texture)) if t is not None]
    if slots:
        return (f"textured glass ({', '.join(slots)} texture): the raster refracts what is "
                "seen through it at two interfaces only")
    return None


def choose_raster(f: ObjectFacts, available: list[str]) -> tuple[str, str]:
    """The raster method for a transmissive object and why."""
    if "single" in available:
        if abs(f.ior - 1.0) < SINGLE_IOR_TOLERANCE:
            return "single", f"IOR {f.ior:g}: rays barely bend, single is within tolerance of wyman"
        if f.screen_px < TINY_PX:
            return "single", f"{f.screen_px:.0f} px on screen: single is within tolerance of wyman"
        if f.camera_inside:
            return "single", "camera inside: neither raster method sees a front face; single is cheaper"
    if "wyman" in available:
        return "wyman", f"IOR {f.ior:g}, {f.screen_px:.0f} px: wyman's exit refraction is needed"
    if "single" in available:
        return "single", "wyman not installed: single is the best raster refraction available"
    return "opaque", "no refraction method installed: transmission ignored"


def rt_depth(bounces: int) -> float:
    """The model's effective depth of `bounces` (at most bounces, saturating at RT_DEPTH_K)."""
    b = max(int(bounces), 1)
    return K * (1.0 - math.exp(-b / K)) if (K := RT_DEPTH_K) < 1e8 else float(b)


def rt_ms(triangles: int, width: int, height: int, traced_px: float, bounces: int,
          supersample: int | None, fresnel_split: str = "roulette", integrator: str = "tree",
          samples: int = 64, emitters: int = 0) -> float:
    """The ray-trace time model: `traced_px` pixels on and next to the object (the whole frame
    for an upper estimate), `supersample` None for the tracer's size-dependent default,
    `emitters` the emissive triangles (Material.is_light) the integrators sample."""
    from renderer.methods.raytrace import default_supersample  # (a cycle at import time)
    from renderer.methods.trace_lights import LOCAL_EMITTERS

    path = integrator == "path"
    rays = max(samples, 1) if path else (supersample or default_supersample(width, height)) ** 2
    per_ray = RT_MS_PER_PATH_DEPTH if path else RT_MS_PER_RAY_DEPTH[fresnel_split]
    if emitters > 0:
        per_ray *= (1.0 + RT_EMITTER_SHARE["path" if path else "tree"]
                    + RT_EMITTER_WEIGHED_SHARE * min(emitters, LOCAL_EMITTERS))
    return (RT_FIXED_MS + (RT_PATH_FIXED_MS if path else 0.0)
            + RT_MS_PER_TRIANGLE * triangles + RT_MS_PER_FRAME_PIXEL * width * height
            + per_ray * rays * traced_px * rt_depth(bounces))


def estimate_raytrace_ms(asset: BakedAsset, options: RenderOptions, coverage_px: float,
                         bounces: int) -> float:
    supersample = options.supersample
    if supersample is None and options.integrator != "path" and options.rough_lobes == "sample":
        from renderer.methods.raytrace import ROUGH_EXTRA, default_supersample
        mats = [apply_override(m.material, options.override) for m in asset.meshes]
        if any(m.roughness > 0 and m.transmission > 0 for m in mats):
            # rough glass gets the finer grid where it is seen (counted here on every pixel)
            supersample = default_supersample(options.width, options.height) + ROUGH_EXTRA
    return rt_ms(asset.triangle_count, options.width, options.height, coverage_px, bounces,
                 supersample, options.fresnel_split, options.integrator, options.samples,
                 emissive_triangles(asset, options))


def emissive_triangles(asset: BakedAsset, options: RenderOptions) -> int:
    """The emitters the ray tracer will sample: triangles as rendered whose material, after
    the request's override, is a light (Material.is_light)."""
    return sum(len(m.indices) * len(m.transforms) for m in asset.meshes
               if apply_override(m.material, options.override).is_light)


def estimate_request_ms(triangles: int, width: int, height: int, method: str, transmissive: bool,
                        budget_ms: float | None, bounces: int = RAYTRACE_BOUNCES,
                        supersample: int | None = None, integrator: str = "tree",
                        samples: int = 64, fresnel_split: str = "roulette", emitters: int = 0) -> float:
    """Upper estimate of one render's time from what is known before loading the asset
    (its triangle count, whether anything transmits, its emissive triangles): the ray-trace
    model above with the whole frame covered, or the raster model. `auto` with a budget ray traces only when its
    estimate fits the budget, so its cost is at most the larger of raster and budget."""
    pixels = width * height
    raytrace = rt_ms(triangles, width, height, pixels, bounces, supersample, fresnel_split,
                     integrator, samples, emitters)
    if integrator == "path" and budget_ms:  # passes stop before budget_ms is spent
        raytrace = min(raytrace, budget_ms)
    if method == "raytrace":
        return raytrace
    raster_method = method if method in RASTER_MS_PER_PIXEL else ("wyman" if transmissive else "opaque")
    raster = (RASTER_FIXED_MS + RASTER_MS_PER_PIXEL[raster_method] * pixels
              + RASTER_MS_PER_TRIANGLE * triangles)
    if method == "auto" and budget_ms:
        return max(raster, min(budget_ms, raytrace))
    return raster


def plan_request(asset: BakedAsset, options: RenderOptions, available: list[str]) -> Plan:
    """Decide every mesh's method for `options` (method "auto") and whether to ray trace."""
    camera = None  # the camera the frame will have: only transmissive objects need it
    decisions, failing, coverage = [], [], 0.0
    for mesh in asset.meshes:
        mat = apply_override(mesh.material, options.override)
        cls = mat.material_class
        if cls != "transmissive":
            decisions.append(Decision(mesh.name, "opaque", f"{cls}: PBR + IBL raster only, "
                                      "no interior bake or refraction pass"))
            continue
        if camera is None:
            camera = asset_camera(asset, options)[0]
        f = object_facts(mesh, mat, camera)
        if mat.thin_walled and "single" in available:
            # a sheet with no inside: light crosses it unbent, so there is no exit to find
            # and no shape-dependent failure; both raster methods draw it the same
            decisions.append(Decision(mesh.name, "single", "thin-walled (glTF: no volume or "
                                      "thickness 0): light passes unbent, single is exact", f))
            continue
        method, why = choose_raster(f, available)
        decisions.append(Decision(mesh.name, method, why, f))
        reason = raster_fails(f) or raster_approximates(mat)
        if reason:
            failing.append((mesh.name, reason))
            r_px = min(f.screen_px, max(options.width, options.height)) / 2
            coverage += math.pi * r_px * r_px
    plan = Plan(decisions)
    wyman = [d.facts for d in decisions if d.method == "wyman" and d.facts is not None]
    if wyman:
        flat = [f.mesh for f in wyman if f.faceted >= TIR_FLAT_SHARE]
        plan.tir = options.tir or ("reflect" if flat else "paper")
        plan.tir_why = ("requested" if options.tir else
                        f"flat faces ({', '.join(flat)}): exit TIR is common" if flat else
                        "curved surfaces only: exit TIR is rare, paper's fallback suffices")
    budget = options.budget_ms
    if not failing:
        plan.why = "raster: every object within the raster methods' tolerance"
        return plan
    names = "; ".join(f"{n}: {r}" for n, r in failing)
    if "raytrace" not in available:
        plan.why = f"raster (ray tracer not installed) although {names}"
        return plan
    est = estimate_raytrace_ms(asset, options, min(coverage, options.width * options.height),
                               RAYTRACE_BOUNCES)
    plan.estimate_ms = {"raytrace": est}
    if budget is None:
        plan.why = f"raster: no time budget given for raytrace although {names}"
    elif est > budget:
        plan.why = f"raster: raytrace estimated {est:.0f} ms > budget {budget:g} ms ({names})"
    else:
        plan.frame_method, plan.bounces = "raytrace", RAYTRACE_BOUNCES
        plan.why = f"raytrace, {RAYTRACE_BOUNCES} bounces, est. {est:.0f} ms <= budget {budget:g} ms: {names}"
        for d in plan.objects:
            d.method, d.why = "raytrace", f"whole frame ray traced ({d.why})"
    log.debug("auto: %s", plan.why)
    return plan


def run_frame_method(plan: Plan, fn, asset: BakedAsset, env, options: RenderOptions):
    """Render the whole frame with the frame method `plan` chose; its decisions in the plan."""
    assert plan.frame_method is not None and plan.bounces is not None  # set together by plan_request
    frame = fn(asset, env, replace(options, method=plan.frame_method, bounces=plan.bounces))
    frame.plan["auto"] = plan.explain()
    return frame


def environment_face_size(asset: BakedAsset, options: RenderOptions) -> tuple[int, str]:
    """Cube face size for the environment bake of this request, and why. The one policy: the
    CLI, the service's workers and the bench all size environments with it, so the same
    request gets the same cubemap everywhere (and its inputs are all in the request).

    The output size bounds it (pipeline.environment.prefilter.default_face_size). When the background
    does not show the environment, the smoothest material bounds it too: a GGX lobe of
    alpha = roughness^2 radians half-width needs about pi / alpha texels per face (two texels
    across it); the mip count then follows the face size (pipeline.environment.prefilter.default_levels:
    mip m holds roughness m / (levels - 1), so the chain always reaches roughness 1)."""
    px = max(options.width, options.height)
    face = default_face_size(px)
    why = f"{face} px faces for a {px} px frame"
    if options.background != "env" and asset.meshes:
        rough = min(apply_override(m.material, options.override).roughness for m in asset.meshes)
        if rough >= SMOOTH_ROUGHNESS:
            need = 1 << max(0, math.ceil(math.log2(math.pi / (rough * rough))))
            if need < face:
                face = max(32, need)
                why = (f"{face} px faces: smoothest material has roughness {rough:g} and the "
                       f"background hides the environment")
    return face, f"{why}; {default_levels(face)} mips"
