"""Bake assets and environments into the cache, and load them back without their sources.

An asset bake is: ingest -> one BakedMesh per (geometry, material) pair carrying every instance's
world matrix -> interior vectors for transmissive geometry only -> per-vertex ambient
occlusion of the opaque meshes (pipeline.occlusion) -> welded edges for edge
anti-aliasing (core.adjacency, assets within its triangle cap), the support points the camera
frames and the points whose convex hull bounds every surface (core.hull) -> a cache entry
holding the arrays (meshes.npz, hull.npy; per texture and colour space a zstd-compressed mip
chain capped for the largest thumbnail served, texture.<i>.<srgb|linear>.zst) and a manifest
with the full material values, so rendering never needs the source files again.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import os
import platform
import re
import sys
import time
from collections.abc import Iterable
from datetime import datetime, timezone
from functools import lru_cache, partial
from pathlib import Path
from typing import Any, cast

import numpy as np
import zstandard

from core import area_lights
from core.adjacency import MAX_TRIANGLES, welded_edges
from core.animation import Moment
from core.baked import BakedAsset, BakedEnvironment, BakedMesh, BakedTexture
from core.cubemap import DEFAULT_FACE_SIZE
from core.errors import AssetError, EmptyScene, MissingFile, UnsupportedFormat
from core.hull import hull_points, support_points
from core.mips import level_shapes, texture_size_for
from core.scene import (
    Light,
    Material,
    Sampler,
    Scene,
    SceneCamera,
    TextureRef,
    UdimLayout,
    extent,
    is_srgb,
    placed_bounds,
)
from pipeline import batching, udim
from pipeline.cache import BAKE_FORMAT_VERSION, Cache, Entry, NotInCache, SourceFiles
from pipeline.environment import prefilter as environment
from pipeline.environment import shipped, studio
from pipeline.environment.panorama import load_panorama
from pipeline.ingest import load_scene
from pipeline.limits import Limits
from pipeline.paths import sandbox_root
from pipeline.usd import subdivision

log = logging.getLogger(__name__)

# Bake options (all part of the cache key):
# - interior_epsilon: None = scale-aware (see interior.py);
# - subdivision_levels: None = by the cage's coarseness, 0: draw cages as they are (see
#   subdivision.py);
# - thumbnail_size: the largest thumbnail (longer side, px) the cache is baked for; textures
#   keep mips from texture_size_for(thumbnail_size) down (1024 px -> 2048^2 texels at most).
#   A larger render still works, with textures no sharper than that.
# - moment: None = at rest; else {"time": seconds | "poster", "animation": name | None}
#   (core.animation.Moment, as a dict for the key), the pose the asset is baked in.
# - variant_sets: USD variant selections, "[PRIM:]SET=NAME" in order (pipeline.usd.stage.load).
# - purposes: USD purposes drawn besides default (render, proxy, guide); other formats have
#   none, so theirs is always the default (one bake whatever a request asks).
# - draw_mode: USD model:drawMode stand-ins drawn ("authored") or the geometry ("full");
#   likewise always the default for other formats.
# - occlusion: bake per-vertex ambient occlusion for the image light (pipeline.occlusion);
#   None = as the format's reference draws it: glTF's are path tracers (issue 30), which see
#   it; USD's is usdview's Storm, which draws none.
ASSET_OPTIONS = {"interior_epsilon": None, "subdivision_levels": None, "thumbnail_size": 1024,
                 "moment": None, "variant_sets": (), "purposes": ("render",),
                 "draw_mode": "authored", "occlusion": None}
# A pose bakes no ambient occlusion: per frame it would cost a bake's rays, and a rig's frames
# (pipeline.gltf.rig, pipeline.usd.rig) re-pose one template, so posed reads and rig frames
# agree only if neither carries it.
POSED_OPTIONS = {"occlusion": False}
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def asset_options(options) -> dict:
    """The bake options a core.options.RenderOptions asks for (which prims a USD stage
    draws); the pose (`moment`) is the caller's, as an animation bakes none."""
    return {"variant_sets": tuple(options.variant_set), "purposes": tuple(options.purposes),
            "draw_mode": options.draw_mode}
PREFILTERS = ("ggx", "paper")
_MESH_ARRAYS = ("positions", "normals", "indices", "tangents", "uv0", "uv1", "colors", "interior",
                "ao", "bent", "edges", "edge_faces", "support", "edge_order")


def _occlusion(asked: bool | None, source) -> bool:
    """The `occlusion` option resolved: None is the format's default (see ASSET_OPTIONS)."""
    return Path(str(source)).suffix.lower() not in USD_SUFFIXES if asked is None else bool(asked)


def _cache(cache_dir) -> Cache:
    return cache_dir if isinstance(cache_dir, Cache) else Cache(cache_dir)


def _is_texture(name: str) -> bool:
    return name.startswith("texture.")


# -- assets ------------------------------------------------------------------------------------

def bake_asset(path, cache_dir=None, *, force: bool = False, limits: Limits | None = None,
               root=None, **options) -> BakedAsset:
    """Ingest and bake `path` into the cache, or load it from there when nothing changed.
    `root`: the folder its references must stay in (default its own; `paths.sandbox_root`)."""
    return bake_or_load_asset(path, cache_dir, force=force, limits=limits, root=root,
                              **options)[0]


def bake_or_load_asset(path, cache_dir=None, *, force: bool = False, limits: Limits | None = None,
                       root=None, **options) -> tuple[BakedAsset, bool]:
    """As `bake_asset`, also saying whether it came from the cache (True) or was baked."""
    unknown = set(options) - set(ASSET_OPTIONS)
    if unknown:
        raise TypeError(f"unknown bake option(s): {', '.join(sorted(unknown))}")
    opts = {**ASSET_OPTIONS, **options}
    opts["variant_sets"], opts["purposes"] = tuple(opts["variant_sets"]), tuple(opts["purposes"])
    if Path(path).suffix.lower() not in USD_SUFFIXES:
        opts["purposes"] = ASSET_OPTIONS["purposes"]
        opts["draw_mode"] = ASSET_OPTIONS["draw_mode"]
    opts["occlusion"] = _occlusion(opts["occlusion"], path)
    if isinstance(opts["moment"], Moment):
        opts["moment"] = dataclasses.asdict(opts["moment"])
    cache = _cache(cache_dir)
    path = Path(path)
    if not path.exists():
        raise MissingFile(path, "no such file")
    if not path.is_file():
        raise UnsupportedFormat(path, "not a regular file")
    try:
        if not force:
            key = cache.lookup_source("assets", path, opts)
            entry = key and cache.load("assets", key, lazy=_is_texture)
            if entry and _inputs_inside(entry.manifest, path, root):
                return unpack_asset(entry), True
        start = time.perf_counter()
        scene = load_scene(path, limits, root,
                           moment=None if opts["moment"] is None else Moment(**opts["moment"]),
                           variant_sets=opts["variant_sets"], purposes=opts["purposes"],
                           draw_mode=opts["draw_mode"])
        ingest_s = time.perf_counter() - start
        source = SourceFiles.hash(path, scene.files, scene.absent)
    except (FileNotFoundError, PermissionError, IsADirectoryError) as exc:  # changed under us
        raise MissingFile(exc.filename or path, f"cannot read: {exc.strerror}") from None
    key = source.key("assets", opts)
    entry = None if force else cache.load("assets", key, lazy=_is_texture)  # same bytes baked from elsewhere
    if entry:
        cache.record_source("assets", source, opts, key)
        return unpack_asset(entry), True

    baked = build_baked(scene, key, opts, batch=True)
    baked.manifest["timings"]["ingest_s"] = round(ingest_s, 6)
    baked.manifest["inputs"] = source.inputs()
    manifest, arrays = pack_asset(baked, opts)
    entry = cache.store("assets", key, manifest, arrays, replace=force)
    cache.record_source("assets", source, opts, key)
    baked.manifest = entry.manifest
    log.info("%s: baked as %s (ingest %.1f ms, interior %.1f ms)", path, key, 1000 * ingest_s,
             1000 * baked.manifest["timings"]["interior_s"])
    return baked, False


def _inputs_inside(manifest: dict, path: Path, root) -> bool:
    """Whether every input a cached bake read lies inside this call's root: a bake made with
    a wider --root is not handed to a narrower call (it bakes again, and is refused)."""
    top = sandbox_root(path, root)
    for item in manifest.get("inputs", [])[1:]:
        real = (path.parent / item["path"]).resolve()
        if real != top and top not in real.parents:
            return False
    return True


def instance_groups(scene: Scene) -> dict[tuple, list[int]]:
    """(mesh, material, variant mapping) -> the instances drawn as one BakedMesh, in the
    order build_baked makes them (a glTF variant mapping belongs to the primitive: kept with it)."""
    groups: dict[tuple, list[int]] = {}
    for k, inst in enumerate(scene.instances):
        groups.setdefault((inst.mesh, inst.material, tuple(sorted(inst.variants.items()))), []).append(k)
    return groups


def framed_bounds(meshes: list[BakedMesh], groups: Iterable[list[int]], scene: Scene) -> np.ndarray:
    """Bounds of posed BakedMeshes (made from `scene` in instance_groups' order, one list of
    instance indices per mesh), backdrops left out as Scene.bounds leaves them out."""
    return placed_bounds((mesh.positions, tr) for mesh, members in zip(meshes, groups)
                         for k, tr in zip(members, mesh.transforms) if not scene.instances[k].backdrop)


def build_baked(scene: Scene, key: str = "", options: dict | None = None,
                layouts: list[UdimLayout | None] | None = None, batch: bool = False) -> BakedAsset:
    """Group a Scene's instances into BakedMeshes, compute interior vectors where needed and
    the welded edges that edge anti-aliasing reads (renderer.raster.edges) for assets it serves, and
    the points on the hull that the framing and the final pass's regions read (core.hull).
    `layouts`: the textures' UDIM layouts, for a scene whose textures were left out (a pose
    keeps its base's) but whose meshes are remapped as the base's were (pipeline.udim).
    `batch`: small meshes placed once are drawn as one (pipeline.batching); the stored bake
    batches, a rig's template does not (it re-poses meshes in instance_groups' order)."""
    opts = {**ASSET_OPTIONS, **(options or {})}
    start = time.perf_counter()
    refined = subdivision.refine_scene(scene, min(Limits.from_env().max_triangles,
                                                  subdivision.BUDGET), opts["subdivision_levels"])
    subdivide_s = time.perf_counter() - start
    groups = {g: [np.asarray(scene.instances[k].matrix, np.float64) for k in members]
              for g, members in instance_groups(scene).items()}
    interiors: dict[object, np.ndarray] = {}
    stats = {"rays": 0, "misses": 0, "degenerate": 0, "build_s": 0.0, "trace_s": 0.0}
    meshes = []
    geometry: list[object] = []  # per BakedMesh, what its vertices are: the scene mesh's, or
    # those split for a UDIM material (pipeline.udim), which only that material's groups share
    remapped: dict[tuple[int, int], tuple | None] = {}
    if layouts is None:
        layouts = [t.udim for t in scene.textures]
    warnings = list(scene.warnings)
    for (mi, mat, variant_map), transforms in groups.items():
        mesh, material = scene.meshes[mi], scene.materials[mat]
        if (mi, mat) not in remapped:
            remapped[(mi, mat)] = udim.remap(mesh, material, layouts,
                                             lambda text: warnings.append(text)
                                             if text not in warnings else None)
        geo: object = mi
        if remapped[(mi, mat)] is not None:
            mesh, material = remapped[(mi, mat)]  # type: ignore[misc]  # not None here
            geo = (mi, mat)
        geometry.append(geo)
        variants = {scene.variants[v]: scene.materials[m] for v, m in variant_map}
        interior = None
        if any(m.material_class == "transmissive" for m in (material, *variants.values())):
            if geo not in interiors:
                from pipeline.interior.vectors import interior_vectors  # here: numba's import is
                # for bakes of glass, not for every process that loads a bake
                result = interior_vectors(mesh.positions, mesh.normals, mesh.indices,
                                          epsilon=opts["interior_epsilon"])
                interiors[geo] = result.vectors
                for k, v in (("rays", result.rays), ("misses", result.misses),
                             ("degenerate", result.degenerate), ("build_s", result.build_seconds),
                             ("trace_s", result.trace_seconds)):
                    stats[k] += v
                if result.misses:
                    log.info("%s: mesh %r: %d of %d interior rays missed (open mesh?); "
                             "bounding-box fallback used", scene.source, mesh.name, result.misses,
                             len(mesh.positions))
            interior = interiors[geo]
        meshes.append(BakedMesh(
            name=mesh.name, positions=mesh.positions, normals=mesh.normals, indices=mesh.indices,
            material=material, transforms=np.stack(transforms), tangents=mesh.tangents,
            uv0=mesh.uv0, uv1=mesh.uv1, colors=mesh.colors, interior=interior, variants=variants))
    occlusion = None
    if _occlusion(opts["occlusion"], scene.source):
        from pipeline.occlusion import ambient_occlusion, split_mesh  # Embree and numba: bakes only
        occlusion = ambient_occlusion(meshes, np.asarray(scene.bounds, np.float64), refine=True)
        for at, (ao, bent, split) in enumerate(zip(occlusion.ao, occlusion.bent or [None] * len(meshes),
                                                   occlusion.splits or [None] * len(meshes))):
            if split is not None:  # its own vertices now: no longer shared with a twin group
                meshes[at], geometry[at] = split_mesh(meshes[at], split), ("split", at)
            meshes[at].ao, meshes[at].bent = ao, bent
    start = time.perf_counter()
    with_edges = sum(len(m.indices) * len(m.transforms) for m in meshes) <= MAX_TRIANGLES
    batched = 0
    if batch:
        backdrop = [any(scene.instances[k].backdrop for k in members)
                    for members in instance_groups(scene).values()]
        meshes, parts = batching.batch(meshes, backdrop, with_edges)
        batched = sum(len(p) for p in parts if len(p) > 1)
        geometry = [geometry[p[0]] if len(p) == 1 else ("batch", i) for i, p in enumerate(parts)]
    batch_s = time.perf_counter() - start
    start = time.perf_counter()
    if with_edges:
        welded: dict[object, tuple[np.ndarray, np.ndarray]] = {}  # by geometry: one per mesh
        for mesh, geo in zip(meshes, geometry):
            if mesh.edges is not None:  # a batch: welded per part already
                continue
            if geo not in welded:
                welded[geo] = welded_edges(mesh.positions, mesh.indices)
            mesh.edges, mesh.edge_faces = welded[geo]
    adjacency_s = time.perf_counter() - start
    start = time.perf_counter()
    support: dict[object, np.ndarray] = {}  # by geometry, as the edges
    for mesh, geo in zip(meshes, geometry):
        if mesh.support is not None:  # a batch: its parts' own
            continue
        if geo not in support:
            support[geo] = support_points(mesh.positions)
        mesh.support = support[geo]
    support_s = time.perf_counter() - start
    start = time.perf_counter()
    hull = hull_points(meshes)
    hull_s = time.perf_counter() - start
    interior_s = stats["build_s"] + stats["trace_s"]
    stats["rays_per_s"] = round(stats["rays"] / interior_s) if interior_s > 0 else 0
    manifest = {
        "timings": {"interior_s": round(interior_s, 6), "subdivide_s": round(subdivide_s, 6),
                    "adjacency_s": round(adjacency_s, 6), "hull_s": round(hull_s, 6),
                    "support_s": round(support_s, 6), "batch_s": round(batch_s, 6),
                    "occlusion_s": round(occlusion.seconds, 6) if occlusion else 0.0},
        "stats": {"meshes": len(meshes), "instances": len(scene.instances), "refined": refined,
                  "batched": batched,  # meshes drawn as part of a batch (pipeline.batching)
                  "vertices": int(sum(len(m.positions) for m in meshes)),
                  "triangles": int(sum(len(m.indices) * len(m.transforms) for m in meshes)),
                  "textures": len(scene.textures), "interior": stats,
                  "occlusion": None if occlusion is None else
                  {"rays": occlusion.rays, "rays_per_vertex": occlusion.rays_per_vertex,
                   "stride": occlusion.stride, "vertices_added": occlusion.vertices_added}},
        # relative to the asset's folder, as the cache's inputs are (a moved tree keeps it)
        "animations": scene.animations, "time_range": scene.time_range, "moment": scene.moment,
        "environment": None if scene.environment is None else
        os.path.relpath(scene.environment, Path(scene.source).resolve().parent),
        "own_lighting": scene.own_lighting,  # pipeline.lighting
        "dome_radiance": None if scene.dome_radiance is None else list(scene.dome_radiance),
        "dome_scale": None if scene.dome_scale is None else list(scene.dome_scale),
    }
    cap = texture_size_for(opts["thumbnail_size"])
    spaces = _texture_spaces(scene)
    textures = [BakedTexture.from_texture(t, spaces[i], cap) for i, t in enumerate(scene.textures)]
    start = time.perf_counter()
    lights = area_lights.of_format(scene.format, meshes, textures)
    cast(dict, manifest["timings"])["area_lights_s"] = round(time.perf_counter() - start, 6)
    cast(dict, manifest["stats"])["area_lights"] = {"lights": len(lights), "dropped": lights.dropped}
    return BakedAsset(key=key, source=str(scene.source), format=scene.format, meshes=meshes,
                      textures=textures, bounds=np.asarray(scene.bounds, np.float64),
                      lights=list(scene.lights), warnings=warnings, manifest=manifest,
                      variants=list(scene.variants), cameras=list(scene.cameras),
                      extent=extent(scene) if any(i.backdrop for i in scene.instances) else None,
                      hull=np.zeros((0, 3)) if hull is None else hull, area_lights=lights)


def _texture_spaces(scene: Scene) -> list[tuple[bool, ...]]:
    """Per texture, the colour spaces materials read it in (True: sRGB); unused ones: none."""
    used: list[set] = [set() for _ in scene.textures]
    for material in scene.materials:
        for slot, ref in material.texture_refs().items():
            if 0 <= ref.texture < len(used):
                used[ref.texture].add(is_srgb(slot))
    return [tuple(sorted(u, reverse=True)) for u in used]


def _texture_file(i: int, srgb: bool) -> str:
    return f"texture.{i}.{'srgb' if srgb else 'linear'}.zst"


def load_baked(key: str, cache_dir=None) -> BakedAsset:
    """A baked asset by key alone (no source file needed). Raises NotInCache."""
    cache = _cache(cache_dir)
    entry = cache.load("assets", key, lazy=_is_texture)
    if entry is None:
        raise NotInCache(cache.entry_dir("assets", key),
                         "no baked asset with this key (never baked, evicted, or was corrupt)")
    return unpack_asset(entry)


def pack_asset(baked: BakedAsset, options: dict) -> tuple[dict, dict[str, dict[str, np.ndarray]]]:
    """A BakedAsset as (manifest, {file name: arrays}) for the cache."""
    materials: list[Material] = []
    material_index: dict[int, int] = {}  # id(material) -> index in `materials` (shared by meshes)
    mesh_arrays, mesh_meta = {}, []
    for i, m in enumerate(baked.meshes):
        for mat in (m.material, *m.variants.values()):
            if id(mat) not in material_index:
                material_index[id(mat)] = len(materials)
                materials.append(mat)
        present = []
        for name in _MESH_ARRAYS + ("transforms",):
            value = getattr(m, name)
            if value is not None:
                mesh_arrays[f"{i}.{name}"] = np.ascontiguousarray(value)
                present.append(name)
        mesh_meta.append({"name": m.name, "material": material_index[id(m.material)],
                          "arrays": present,
                          "variants": {k: material_index[id(v)] for k, v in m.variants.items()}})
    arrays: dict[str, Any] = {"meshes.npz": mesh_arrays}
    if baked.hull is not None:
        arrays["hull.npy"] = np.asarray(baked.hull, np.float64)
    if baked.area_lights is not None:
        arrays["area_lights.npz"] = baked.area_lights.arrays()
    for i, t in enumerate(baked.textures):
        arrays.update({_texture_file(i, srgb): t.mips(srgb)[::-1] for srgb in t.spaces})  # smallest first
    manifest = {
        **baked.manifest,
        "kind": "asset",
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "source": baked.source,
        "source_format": baked.format,
        "options": options,
        "versions": _versions(),
        "meshes": mesh_meta,
        "materials": [_material_to_json(m) for m in materials],
        "textures": [{"name": t.name, "source": t.source, "sampler": dataclasses.asdict(t.sampler),
                      "size": list(t.size), "spaces": ["srgb" if s else "linear" for s in t.spaces]}
                     for t in baked.textures],
        "lights": [_light_to_json(light) for light in baked.lights],
        "bounds": np.asarray(baked.bounds).tolist(),
        "warnings": baked.warnings,
        "variants": list(baked.variants),
        "extent": None if baked.extent is None else np.asarray(baked.extent).tolist(),
        "cameras": [{**{k: _finite(v) for k, v in dataclasses.asdict(c).items() if k != "matrix"},
                     "matrix": np.asarray(c.matrix).tolist()} for c in baked.cameras],
    }
    return manifest, arrays


def unpack_asset(entry: Entry) -> BakedAsset:
    m = entry.manifest
    arrays = entry.arrays.get("meshes.npz", {})
    materials = [_material_from_json(d) for d in m["materials"]]
    meshes = []
    for i, meta in enumerate(m["meshes"]):
        fields = {name: arrays[f"{i}.{name}"] for name in meta["arrays"]}
        variants = {k: materials[v] for k, v in meta.get("variants", {}).items()}
        meshes.append(BakedMesh(name=meta["name"], material=materials[meta["material"]],
                                variants=variants, **fields))
    textures = [BakedTexture(t["name"], Sampler(**t["sampler"]), t["source"], tuple(t["size"]),
                             tuple(s == "srgb" for s in t["spaces"]), partial(_read_chain, entry, i, t["size"]))
                for i, t in enumerate(m["textures"])]
    return BakedAsset(key=entry.key, source=m["source"], format=m["source_format"], meshes=meshes,
                      textures=textures, bounds=np.asarray(m["bounds"], np.float64),
                      lights=[_light_from_json(d) for d in m["lights"]], warnings=list(m["warnings"]),
                      manifest=m, variants=list(m.get("variants", [])),
                      extent=None if m.get("extent") is None else np.asarray(m["extent"], np.float64),
                      cameras=[_camera_from_json(d) for d in m.get("cameras", [])],
                      hull=cast("np.ndarray | None", entry.arrays.get("hull.npy")),
                      area_lights=None if "area_lights.npz" not in entry.arrays
                      else area_lights.AreaLights.from_arrays(cast(dict, entry.arrays["area_lights.npz"])))


def _camera_from_json(d: dict) -> SceneCamera:
    d = dict(d, matrix=np.asarray(d["matrix"], np.float64))
    if d.get("zfar") is None:
        d["zfar"] = math.inf
    return SceneCamera(**d)


def _read_chain(entry: Entry, i: int, size, srgb: bool, top: int | None = None) -> list[np.ndarray]:
    """A baked texture's levels from the first no larger than `top` down: the file is read and
    checksummed whole (compressed bytes), but it holds the levels smallest first, so only the
    prefix a render needs is decompressed (a 512 px render of a 2048 px chain: a quarter).
    Level views share one buffer. CorruptEntry if it fails (the entry is dropped)."""
    name = _texture_file(i, srgb)
    data = entry.read(name)
    shapes = level_shapes(*size)[::-1]  # smallest first, as stored
    if zstandard.frame_content_size(data) != 4 * sum(h * w for h, w in shapes):
        entry.invalid(name, f"holds {zstandard.frame_content_size(data)} bytes, expected RGBA8 mips of {size}")
    wanted = [s for s in shapes if top is None or max(s) <= top] or shapes[:1]
    nbytes = 4 * sum(h * w for h, w in wanted)
    raw = bytearray(nbytes)  # decompressed into place: half the CPU of growing it chunk by chunk
    view, got = memoryview(raw), 0
    with zstandard.ZstdDecompressor().stream_reader(data) as reader:
        while got < nbytes and (n := reader.readinto(view[got:])):
            got += n
    if got != nbytes:
        entry.invalid(name, "truncated compressed stream")
    levels, offset = [], 0
    for h, w in wanted:
        levels.append(np.frombuffer(raw, np.uint8, h * w * 4, offset).reshape(h, w, 4))
        offset += h * w * 4
    return levels[::-1]  # level 0 (the largest wanted) first


def _finite(x):
    """JSON has no infinity: inf is stored as null."""
    return None if isinstance(x, float) and math.isinf(x) else x


def _material_to_json(material: Material) -> dict:
    return {k: _finite(v) for k, v in dataclasses.asdict(material).items()}


def _material_from_json(d: dict) -> Material:
    values = {}
    for f in dataclasses.fields(Material):
        if f.name not in d:
            continue
        v = d[f.name]
        if f.name.endswith("_texture") and v is not None:
            v = TextureRef(**cast(dict[str, Any], {k: tuple(x) if isinstance(x, list) else x for k, x in v.items()}))
        elif isinstance(v, list):
            v = tuple(v)
        elif v is None and f.name == "attenuation_distance":
            v = math.inf
        values[f.name] = v
    return Material(**values)


def _light_to_json(light: Light) -> dict:
    d = {k: _finite(v) for k, v in dataclasses.asdict(light).items()}
    d["matrix"] = np.asarray(light.matrix).tolist()
    return d


def _light_from_json(d: dict) -> Light:
    d = dict(d, matrix=np.asarray(d["matrix"], np.float64), color=tuple(d["color"]),
             shadow_color=tuple(d["shadow_color"]), size=tuple(d.get("size", (0.0, 0.0))))
    if d.get("range") is None:
        d["range"] = math.inf
    return Light(**d)


_RECORDED = ("asset-preview", "numpy", "embreex", "usd-core", "trimesh", "moderngl")


@lru_cache(maxsize=1)
def _versions() -> dict:
    return {"bake_format": BAKE_FORMAT_VERSION, "python": platform.python_version(), **installed_versions(_RECORDED)}


def _dist_key(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def installed_versions(dists: Iterable[str]) -> dict[str, str]:
    """The installed version of each distribution found, as `importlib.metadata.version` gives
    it: the first `*.dist-info` / `*.egg-info` folder on sys.path of that name, its `Version:`
    header. Read directly, because importing importlib.metadata (email, zipfile, csv ...) cost
    a cold render more than the bake record it feeds (bench/RESULTS.md); a sys.path entry that
    is a file (a zip) is left to importlib.metadata."""
    wanted = {_dist_key(d): d for d in dists}
    out: dict[str, str] = {}
    for entry in sys.path:
        folder = entry or "."
        if os.path.isfile(folder):
            from importlib import metadata
            for dist in wanted.values():
                if dist not in out:
                    try:
                        out[dist] = metadata.version(dist)
                    except metadata.PackageNotFoundError:
                        pass
            continue
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            stem, _, kind = name.rpartition(".")
            found = wanted.get(_dist_key(stem.partition("-")[0])) if kind in ("dist-info", "egg-info") else None
            if found is None or found in out:
                continue
            version = _version_header(os.path.join(folder, name, "METADATA" if kind == "dist-info" else "PKG-INFO"))
            if version is not None:
                out[found] = version
    return {d: out[d] for d in dists if d in out}


def _version_header(path: str) -> str | None:
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                if not line.strip():
                    break  # the headers end at the first blank line
                if line.startswith("Version:"):
                    return line[len("Version:"):].strip()
    except OSError:
        pass
    return None


# -- environments ------------------------------------------------------------------------------

def bake_environment(source, cache_dir=None, face_size: int = DEFAULT_FACE_SIZE, prefilter: str = "ggx",
                     force: bool = False, limits: Limits | None = None) -> BakedEnvironment:
    """Prefilter a panorama (file or bundled name) into the cache, or load it from there."""
    return bake_or_load_environment(source, cache_dir, face_size=face_size, prefilter=prefilter,
                                    force=force, limits=limits)[0]


def bake_or_load_environment(source, cache_dir=None, face_size: int = DEFAULT_FACE_SIZE, prefilter: str = "ggx",
                             force: bool = False, limits: Limits | None = None
                             ) -> tuple[BakedEnvironment, bool]:
    if prefilter not in PREFILTERS:
        raise ValueError(f"prefilter must be one of {PREFILTERS}, not {prefilter!r}")
    environment.check_face_size(face_size)  # before the key: default_levels needs a valid one
    cache = _cache(cache_dir)
    source_files, opts, key = shipped.environment_key(source, face_size, prefilter)
    if not force:
        entry = cache.load("environments", key)
        if entry:
            return unpack_environment(entry), True

    start = time.perf_counter()
    env = shipped.load_shipped(key)  # the default studio's bake ships with the package
    from_package = env is not None
    if env is not None:
        name, shape = studio.NAME, [studio.WIDTH // 2, studio.WIDTH, 3]
        load_s, prefilter_s = time.perf_counter() - start, 0.0
    else:
        panorama = load_panorama(source, limits)
        name, shape = panorama.name, list(panorama.pixels.shape)
        load_s = time.perf_counter() - start
        start = time.perf_counter()
        env = environment.prefilter(panorama.pixels, face_size=face_size, method=prefilter)
        prefilter_s = time.perf_counter() - start
    arrays: dict[str, Any] = {f"specular.{i}.npy": mip for i, mip in enumerate(env.specular)}
    arrays["small.npz"] = {"irradiance_sh": np.asarray(env.irradiance_sh),
                           "brdf_lut": np.asarray(env.brdf_lut), "irradiance": np.asarray(env.irradiance)}
    manifest = {
        "kind": "environment", "name": name,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "inputs": source_files.inputs(), "options": opts, "versions": _versions(),
        "panorama_shape": shape, "mips": len(env.specular),
        "shipped": shipped.STUDIO_BAKES.name if from_package else None,
        "timings": {"load_s": round(load_s, 6), "prefilter_s": round(prefilter_s, 6),
                    **{k: round(float(v), 6) for k, v in dict(env.timings).items()}},
    }
    entry = cache.store("environments", key, manifest, arrays, replace=force)
    log.info("%s: environment baked as %s in %.1f ms", source, key, 1000 * (load_s + prefilter_s))
    return unpack_environment(entry), False


def load_environment(key: str, cache_dir=None) -> BakedEnvironment:
    """A baked environment by key alone. Raises NotInCache."""
    cache = _cache(cache_dir)
    entry = cache.load("environments", key)
    if entry is None:
        raise NotInCache(cache.entry_dir("environments", key),
                         "no baked environment with this key (never baked, evicted, or was corrupt)")
    return unpack_environment(entry)


def unpack_environment(entry: Entry) -> BakedEnvironment:
    a, m = entry.arrays, entry.manifest
    specular = [cast(np.ndarray, a[f"specular.{i}.npy"]) for i in range(m["mips"])]
    return BakedEnvironment(key=entry.key, name=m["name"], specular=specular,
                            irradiance_sh=a["small.npz"]["irradiance_sh"], brdf_lut=a["small.npz"]["brdf_lut"],
                            irradiance=a["small.npz"]["irradiance"],
                            prefilter=m["options"]["prefilter"], manifest=m)


def bake_one(kind: str, source: str, *, cache=None, max_bytes=None, force=False,
             face_size=DEFAULT_FACE_SIZE, prefilter="ggx", roots=None, library=()) -> dict:
    """The unit of work of `asset-bake` (in processes or Ray tasks): bake one asset or
    environment; never raises (the result says what went wrong). `roots` maps an asset to
    the folder its references may read (cli.bake's `_collect`); `library`: the files found
    by walking a folder, where a USD layer with nothing to draw (a kit's material layer) is
    skipped with a note, not failed."""
    start = time.perf_counter()
    result: dict[str, Any] = {"kind": kind, "path": source}
    try:
        store = Cache(cache, max_bytes=max_bytes)
        baked: BakedAsset | BakedEnvironment
        if kind == "asset":
            baked, hit = bake_or_load_asset(source, store, force=force,
                                            root=(roots or {}).get(source))
            result.update(triangles=int(baked.triangle_count), meshes=len(baked.meshes))
            interior = baked.manifest.get("stats", {}).get("interior", {})
            if interior.get("rays"):
                result.update(interior_rays=interior["rays"], interior_misses=interior["misses"])
        else:
            baked, hit = bake_or_load_environment(source, store, face_size=face_size,
                                                       prefilter=prefilter, force=force)
            result.update(face_size=baked.face_size, mips=len(baked.specular))
        result.update(status="cached" if hit else "baked", key=baked.key)
    except EmptyScene as exc:
        if source in library and Path(source).suffix.lower() in (".usd", ".usda", ".usdc"):
            result.update(status="skipped", note=f"not an asset: {exc.reason}")
        else:
            result.update(status="failed", error=str(exc))
    except AssetError as exc:
        result.update(status="failed", error=str(exc))
    except (ValueError, OSError) as exc:  # bad option values, unwritable cache
        result.update(status="failed", error=f"{source}: {exc}")
    except Exception as exc:  # a bug: report it for this input and carry on with the others
        log.exception("%s: unexpected error while baking", source)
        result.update(status="failed", error=f"{source}: internal error ({type(exc).__name__}: {exc})")
    result["seconds"] = round(time.perf_counter() - start, 4)
    return result
