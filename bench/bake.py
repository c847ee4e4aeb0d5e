"""Bake speed: interior rays, cold bake vs cache hit, environment prefiltering; peers beside us.

Four tables, medians of --repeat runs (after one warm-up) measured in this run:
- interior: our whole pass (Embree BVH build + rays + graze/miss handling) on every mesh of each
  sample asset and of the glass test meshes, treated as transmissive; the BVH build alone, rays/s
  over the whole pass (wall time of the call: setup, build, rays, fallbacks) and over tracing
  alone, and rays per CPU-second of the process (all threads: less disturbed than wall time when
  other jobs share the cores). Rays are those cast, graze continuations included (the peers cast
  only the first ray per vertex). Peers on the same rays, BVH build included:
  trimesh's Embree ray intersector (`intersects_location`, first hit) and embreex's own scene
  (TriangleMesh + EmbreeScene.run: the pass before pipeline.interior.embree). Meshes: every sample asset,
  the glass test meshes, the shared bunny.ply and a 100k-triangle torus. Target >= 2 M rays/s.
- interior-parts: what bounds that pass on the bunny and the 100k torus: process CPU of the BVH
  build, of tracing the rays on one thread, and of the whole pass; the whole pass's rays per
  CPU-second, twice that being the most two idle cores could give.
- asset: ingest (load_scene), a cold bake (`force=True`: ingest + interior + cache write), and a
  cache hit (`bake_asset` on the unchanged file: hash sources, read and verify the entry);
  peer: re-ingesting, what a hit saves. Target: hit <= 20 ms. Also what the welded edges
  for edge anti-aliasing (core.adjacency), the final pass's hull points and the framing's
  support points (core.hull) add:
  their bake time (the last cold bake's) and bytes, beside the whole entry's bytes; and the
  ambient occlusion pass (pipeline.occlusion): its time, rays and rays per vertex.
- environment: per bundled 1024 x 512 panorama, a cold bake to 256-px faces (decode + cube +
  GGX mip chain + SH + BRDF LUT + cache write), the prefilter alone, and a hit; peer: the paper's
  Gaussian mip chain (`--prefilter paper`). Target: cold bake <= 0.5 s. The first bake in a
  process also pays the GL context, shader compiles and the LUT, so it is shown apart.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from typing import cast

import numpy as np

from bench.ingest import DEFAULT_ASSETS, sample_files
from bench.metrics import median_ms

TARGET_RAYS = 2e6
TARGET_HIT_MS = 20.0
TARGET_ENV_MS = 500.0


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--assets", type=Path, default=DEFAULT_ASSETS,
                        help="sample asset folder (default: %(default)s)")
    parser.add_argument("--env", action="append", default=None, metavar="NAME|FILE",
                        help="environments to bake (default: every bundled one)")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per figure")
    parser.add_argument("--face-size", type=int, default=256)
    parser.add_argument("--tables", default="interior,interior-parts,asset,environment",
                        help="which tables to run (comma-separated; default: all)")


def _median_s(fn, repeat: int) -> float:
    """Median seconds of `repeat` calls after one warm-up (bench.metrics.median_ms)."""
    return median_ms(fn, repeat)[0] / 1e3


def _interior_meshes(assets: Path):
    """(label, [(positions, normals, indices)]) for each sample asset and glass test mesh."""
    import trimesh

    from bench.shapes import mesh_arrays
    from core.errors import AssetError
    from pipeline.ingest import load_scene

    out = []
    for path in sample_files(assets):
        try:
            scene = load_scene(path)
        except AssetError:
            continue
        out.append((path.name, [(m.positions, m.normals, m.indices) for m in scene.meshes]))
    for kind in ("sphere", "bunny", "torus"):
        out.append((f"glass {kind}", [mesh_arrays(kind)]))
    out.extend((label, [mesh]) for label, mesh in _target_meshes(assets))
    big = trimesh.creation.icosphere(subdivisions=7)
    out.append(("icosphere 7 (big)", [(big.vertices.astype(np.float32),
                                       big.vertex_normals.astype(np.float32),
                                       big.faces.astype(np.uint32))]))
    return out


def _target_meshes(assets: Path):
    """The two meshes of the target: the shared bunny.ply and a 100k-triangle torus."""
    import trimesh

    bunny = cast(trimesh.Trimesh, trimesh.load(assets / "mesh" / "bunny.ply", process=False))
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=250, minor_sections=200)
    return [(label, (np.asarray(m.vertices, np.float32), np.asarray(m.vertex_normals, np.float32),
                     np.asarray(m.faces, np.uint32)))
            for label, m in (("bunny.ply", bunny), ("torus 100k", torus))]


def _trimesh_pass(meshes) -> None:
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    for p, n, idx in meshes:
        mesh = trimesh.Trimesh(p, idx, process=False)
        eps = 1e-4 * float(np.linalg.norm(np.ptp(p, axis=0)))
        RayMeshIntersector(mesh).intersects_location(p - n * eps, -n, multiple_hits=False)


def _embreex_pass(meshes) -> None:
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    for p, n, idx in meshes:
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, np.asarray(p, np.float32)[np.asarray(idx, np.int64)])
        eps = 1e-4 * float(np.linalg.norm(np.ptp(p, axis=0)))
        scene.run(np.asarray(p - n * eps, np.float32), np.asarray(-n, np.float32), output=1)


def _cpu_s() -> float:
    import resource
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def interior_table(assets: Path, repeat: int) -> list[float]:
    from pipeline.interior.vectors import interior_vectors

    print(f"\ninterior (target >= {TARGET_RAYS / 1e6:.0f} M rays/s; medians of {repeat})")
    print(f"{'mesh':26} {'rays':>8} {'ours ms':>8} {'build ms':>8} {'M rays/s':>9} {'trace-only':>10} "
          f"{'per cpu-s':>9} {'trimesh ms':>10} {'embreex ms':>10} {'ours/trimesh':>12} {'ours/embreex':>12}")
    rates = []
    for label, meshes in _interior_meshes(assets):
        rays = sum(len(p) for p, _, _ in meshes)
        if rays == 0:
            continue
        results: list = []

        def ours():
            results.clear()
            results.extend(interior_vectors(p, n, i) for p, n, i in meshes)

        cpu, build, trace = [], [], []

        def ours_timed():
            c = _cpu_s()
            ours()
            cpu.append(_cpu_s() - c)
            build.append(sum(r.build_seconds for r in results))
            trace.append(sum(r.trace_seconds for r in results))

        ours_s = _median_s(ours_timed, repeat)
        del cpu[0], build[0], trace[0]  # the untimed warm-up run
        cast = sum(r.rays for r in results)  # rays actually cast, graze continuations included
        peer_s = _median_s(lambda: _trimesh_pass(meshes), repeat)
        old_s = _median_s(lambda: _embreex_pass(meshes), repeat)
        rates.append(cast / ours_s)
        print(f"{label[:26]:26} {cast:8d} {1000 * ours_s:8.1f} {1000 * statistics.median(build):8.1f} "
              f"{cast / ours_s / 1e6:9.2f} {cast / statistics.median(trace) / 1e6:10.2f} "
              f"{cast / statistics.median(cpu) / 1e6:9.2f} "
              f"{1000 * peer_s:10.1f} {1000 * old_s:10.1f} {ours_s / peer_s:12.2f} {ours_s / old_s:12.2f}",
              flush=True)
    return rates


def interior_parts_table(assets: Path, repeat: int) -> None:
    """What bounds the interior pass: process CPU (all threads) of pairing the triangles into
    quads, of the BVH build over them, of tracing the first rays on one thread, and of the whole
    pass, for the bunny and the 100k torus."""
    from pipeline.interior.embree import TriangleScene
    from pipeline.interior.pairing import pair_quads
    from pipeline.interior.vectors import interior_vectors

    def cpu_ms(fn) -> float:
        fn()
        times = []
        for _ in range(max(1, repeat)):
            c = _cpu_s()
            fn()
            times.append(1000 * (_cpu_s() - c))
        return statistics.median(times)

    print(f"\ninterior pass by part (process CPU ms, all threads; medians of {repeat})")
    print(f"{'mesh':14} {'triangles':>9} {'quads':>7} {'rays':>7} {'pairing':>7} {'build':>7} {'us/tri':>6} "
          f"{'trace 1T':>8} {'us/ray':>6} {'whole':>7} {'M rays/cpu-s':>12} {'2-core ceiling':>14}")
    for label, (p, n, f) in _target_meshes(assets):
        result = interior_vectors(p, n, f)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = (-n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
        rays = np.flatnonzero(np.isfinite(d).all(axis=1))  # the pass's rays: usable normals
        offsets = np.full(len(p), 1e-4 * float(np.linalg.norm(np.ptp(p, axis=0))), np.float32)
        quads = pair_quads(f)
        scene = TriangleScene(p, quads)
        pairing = cpu_ms(lambda: pair_quads(f))
        build = cpu_ms(lambda: TriangleScene(p, quads))
        trace = cpu_ms(lambda: scene.closest(p, d, offsets, rays, threads=1))
        whole = cpu_ms(lambda: interior_vectors(p, n, f))
        rate = result.rays / whole / 1e3
        print(f"{label:14} {len(f):9d} {len(quads):7d} {result.rays:7d} {pairing:7.1f} {build:7.1f} "
              f"{1000 * build / len(f):6.3f} {trace:8.1f} {1000 * trace / result.rays:6.3f} {whole:7.1f} "
              f"{rate:12.2f} {2 * rate:14.2f}", flush=True)


def asset_table(assets: Path, repeat: int, cache: Path) -> list[float]:
    from core.errors import AssetError
    from pipeline.bake import bake_or_load_asset
    from pipeline.ingest import load_scene

    print(f"\nasset bake (target: hit <= {TARGET_HIT_MS:.0f} ms; medians of {repeat})")
    print(f"{'asset':34} {'ingest ms':>9} {'cold ms':>8} {'hit ms':>7} {'hit/ingest':>10} "
          f"{'edges ms':>8} {'edges KB':>8} {'hull ms':>7} {'hull KB':>7} {'supp ms':>7} {'supp KB':>7} "
          f"{'entry KB':>8} {'ao ms':>7} {'ao rays':>8} {'ao/vtx':>6}")
    hits = []
    for path in sample_files(assets):
        try:
            ingest = _median_s(lambda: load_scene(path), repeat)
            cold = _median_s(lambda: bake_or_load_asset(path, cache, force=True), repeat)
            assert bake_or_load_asset(path, cache)[1], "a second bake must be a cache hit"
            hit = _median_s(lambda: bake_or_load_asset(path, cache), repeat)
            baked = bake_or_load_asset(path, cache)[0]
        except AssetError as exc:
            print(f"{path.name[:34]:34} failed: {exc.reason}")
            continue
        hits.append(hit)
        # what the welded edges and the hull points add to the bake and the entry
        edge_bytes = sum(a.nbytes for m in baked.meshes for a in (m.edges, m.edge_faces) if a is not None)
        support_bytes = sum(m.support.nbytes for m in baked.meshes if m.support is not None)
        files = baked.manifest["files"]
        entry_bytes = sum(f["bytes"] for f in files.values())
        print(f"{path.name[:34]:34} {1000 * ingest:9.1f} {1000 * cold:8.1f} {1000 * hit:7.2f} "
              f"{hit / ingest:10.3f} {1000 * baked.manifest['timings']['adjacency_s']:8.1f} "
              f"{edge_bytes / 1024:8.0f} {1000 * baked.manifest['timings']['hull_s']:7.1f} "
              f"{files.get('hull.npy', {}).get('bytes', 0) / 1024:7.1f} "
              f"{1000 * baked.manifest['timings']['support_s']:7.1f} {support_bytes / 1024:7.1f} "
              f"{entry_bytes / 1024:8.0f} {1000 * baked.manifest['timings'].get('occlusion_s', 0):7.1f} "
              f"{(ao.get('rays', 0) if (ao := baked.manifest['stats'].get('occlusion')) else 0):8d} "
              f"{ao.get('rays_per_vertex', 0) if ao else 0:6d}")
    return hits


def environment_table(envs: list[str], repeat: int, face_size: int, cache: Path) -> list[float]:
    from pipeline.bake import bake_or_load_environment
    from pipeline.environment.panorama import load_panorama
    from pipeline.environment.prefilter import prefilter

    print(f"\nenvironment bake, {face_size}-px faces (target: cold bake <= {TARGET_ENV_MS:.0f} ms; "
          f"medians of {repeat})")
    start = time.perf_counter()
    bake_or_load_environment(envs[0], cache, face_size=face_size, force=True)
    print(f"first bake in this process (GL context, shader compiles, BRDF LUT): "
          f"{1000 * (time.perf_counter() - start):.0f} ms")
    print(f"{'environment':18} {'size':>9} {'cold ms':>8} {'ggx ms':>7} {'paper ms':>8} "
          f"{'ggx/paper':>9} {'hit ms':>7}")
    colds = []
    for env in envs:
        pixels = load_panorama(env).pixels
        cold = _median_s(lambda: bake_or_load_environment(env, cache, face_size=face_size, force=True), repeat)
        ggx = _median_s(lambda: prefilter(pixels, face_size, "ggx"), repeat)
        paper = _median_s(lambda: prefilter(pixels, face_size, "paper"), repeat)
        hit = _median_s(lambda: bake_or_load_environment(env, cache, face_size=face_size), repeat)
        colds.append(cold)
        size = f"{pixels.shape[1]}x{pixels.shape[0]}"
        print(f"{Path(env).stem[:18]:18} {size:>9} {1000 * cold:8.0f} {1000 * ggx:7.0f} "
              f"{1000 * paper:8.0f} {ggx / paper:9.2f} {1000 * hit:7.1f}")
    return colds


def run(args: argparse.Namespace) -> int:
    from pipeline.environment.panorama import list_bundled

    envs = args.env or list_bundled()
    tables = set(args.tables.split(","))
    rates = hits = colds = None
    with tempfile.TemporaryDirectory(prefix="bench-bake-") as tmp:
        if "interior" in tables:
            rates = interior_table(args.assets, args.repeat)
        if "interior-parts" in tables:
            interior_parts_table(args.assets, args.repeat)
        if "asset" in tables:
            hits = asset_table(args.assets, args.repeat, Path(tmp))
        if "environment" in tables:
            colds = environment_table(envs, args.repeat, args.face_size, Path(tmp))
    print("\nsummary (medians over the rows above)")
    if rates:
        print(f"  interior whole pass: {statistics.median(rates) / 1e6:.2f} M rays/s "
              f"(target {TARGET_RAYS / 1e6:.0f}); best {max(rates) / 1e6:.2f}")
    if hits:
        print(f"  cache hit: {1000 * statistics.median(hits):.2f} ms (target {TARGET_HIT_MS:.0f}); "
              f"worst {1000 * max(hits):.2f}")
    if colds:
        print(f"  environment cold bake: {1000 * statistics.median(colds):.0f} ms "
              f"(target {TARGET_ENV_MS:.0f}; f3d's first HDRI bake: 6600 ms, quoted from issue 3, "
              f"not measured here)")
    return 0
