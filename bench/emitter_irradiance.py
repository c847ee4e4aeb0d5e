"""Would a baked per-vertex emitter irradiance help the raster? (issue 30, part 2)

`python -m bench.emitter_irradiance --cycles OUT/fidelity/MODEL_cycles.exr` renders the raster
frame (`method auto`, bench fidelity's view and environment) and adds to it, at the surface
each pixel centre sees, the diffuse radiance base x (1 - metallic) x (1 - transmission) / pi x E
of the emitters' irradiance E, taken two ways:

- per vertex, as a bake like pipeline/occlusion.py's would store it: E at every triangle
  corner, both sides, by `--vertex-samples` shadowed emitter samples
  (raytrace.emitter_irradiance), interpolated with the hit's barycentrics, on the side the ray
  meets;
- per pixel, the same estimator at the pixel's own surface point (`--pixel-samples`): the best
  any bake of irradiance could give the raster.

Each is scored against the Cycles frame with bench fidelity's LDR FLIP; the bake's time is
printed beside it, and `--sheet` writes raster, raster + vertex bake, raster + per pixel,
Cycles side by side. It is a measurement: the raster does not add either.

`--tree-samples 0,1,2` also renders the ray tracer's default (tree) frame with each number of
emitter points a ray (raytrace.EMITTER_SAMPLES; 0: emitters light nothing, as before issue
30) and prints its FLIP and the median of `--repeat` frame times, all in the same run.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def world_corners(asset) -> np.ndarray:
    """T x 3 x 3 world triangles in raytrace.build_scene's order (mesh, instance, face)."""
    tris = []
    for mesh in asset.meshes:
        idx = mesh.indices.astype(np.int64)
        for m in mesh.transforms:
            m = np.asarray(m, np.float64)
            p = mesh.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
            tris.append(p[idx[:, ::-1] if np.linalg.det(m[:3, :3]) < 0 else idx])
    return np.concatenate(tris)


def main(argv: list[str] | None = None) -> int:
    from bench.fidelity import MODELS, VIEW, flip_ldr, read_exr
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer.methods import raytrace
    from renderer.methods.trace_scene import hit_material, intersect_front
    from renderer.raster.render import render
    from renderer.view.framing import asset_camera

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--samples", default=str(MODELS), help="folder of Khronos sample models")
    p.add_argument("--model", default="EmissiveStrengthTest")
    p.add_argument("--cycles", required=True, help="bench fidelity's MODEL_cycles.exr for this model")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--vertex-samples", type=int, default=1024)
    p.add_argument("--pixel-samples", type=int, default=256)
    p.add_argument("--cache", default="/tmp/emitter-irradiance-cache")
    p.add_argument("--sheet", default="")
    p.add_argument("--tree-samples", default="", help="comma-separated EMITTER_SAMPLES to time the tree at")
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)

    folder = Path(args.samples) / args.model
    path = next(iter(sorted(folder.glob("glTF-Binary/*.glb")) + sorted(folder.glob("glTF/*.gltf"))))
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    env = bake_environment("footprint_court", cache, face_size=256)
    asset = bake_asset(path, cache)
    o = RenderOptions(width=args.size, height=args.size, background="transparent", shadow=0.0,
                      tonemap="aces", yaw=VIEW["yaw"], pitch=VIEW["pitch"], fov=VIEW["fov"], method="auto")
    ref = read_exr(args.cycles)
    raster = render(asset, env, o).linear

    ts = raytrace.build_scene(asset, o)
    em = ts.emitters
    if em is None:
        print(f"{args.model}: nothing emits")
        return 0
    cam = asset_camera(asset, o)[0]
    d = cam.ray_directions().reshape(-1, 3).astype(np.float64)
    eye = np.broadcast_to(np.asarray(cam.position, np.float64), d.shape)
    ts.eye, ts.spread = np.asarray(cam.position, np.float64), 2 * np.tan(np.radians(cam.fov) / 2) / cam.height
    prim, u, v, t = intersect_front(ts, eye, d)
    sel = np.flatnonzero(prim >= 0)
    hits = hit_material(ts, eye, d, prim, u, v, t, lobes=False)
    pr, ds = prim[sel], d[sel]
    ng = ts.geo_normals[pr].astype(np.float64)
    front = np.einsum("ij,ij->i", ds, ng) < 0
    ng = ng * np.where(front, 1.0, -1.0)[:, None]
    n = hits.normal[sel] * np.where(front, 1.0, -1.0)[:, None]
    n = np.where((np.einsum("ij,ij->i", ds, n) >= 0)[:, None], ng, n)
    pts = eye[sel] + ds * np.asarray(t[sel], np.float64)[:, None]
    albedo = hits.base[sel] * ((1 - hits.metallic[sel]) * (1 - hits.transmission[sel]))[:, None] / np.pi

    t0 = time.perf_counter()
    corners = world_corners(asset).reshape(-1, 3)
    cn = ts.normals.reshape(-1, 3).astype(np.float64)
    cg = np.repeat(ts.geo_normals.astype(np.float64), 3, axis=0)
    # front and back of every corner, all samples in one batch (as a bake would cast them)
    k = args.vertex_samples
    baked = [raytrace.emitter_irradiance(ts, em, np.repeat(corners, k, 0), np.repeat(s * cn, k, 0),
                                         np.repeat(s * cg, k, 0), 1, seed=1)
             .reshape(-1, k, 3).mean(1).reshape(-1, 3, 3) for s in (1.0, -1.0)]
    bake_ms = (time.perf_counter() - t0) * 1e3
    bary = np.stack([1 - u[sel] - v[sel], u[sel], v[sel]], -1).astype(np.float64)
    e_vertex = np.where(front[:, None], np.einsum("ic,icj->ij", bary, baked[0][pr]),
                        np.einsum("ic,icj->ij", bary, baked[1][pr]))
    t0 = time.perf_counter()
    k = args.pixel_samples
    e_pixel = raytrace.emitter_irradiance(ts, em, np.repeat(pts, k, 0), np.repeat(n, k, 0),
                                          np.repeat(ng, k, 0), 1, seed=2).reshape(-1, k, 3).mean(1)
    pixel_ms = (time.perf_counter() - t0) * 1e3

    def plus(e: np.ndarray) -> np.ndarray:
        img = raster.copy()
        flat = img.reshape(-1, 4)
        flat[sel, :3] += (albedo * e).astype(np.float32)
        return img

    with_vertex, with_pixel = plus(e_vertex), plus(e_pixel)
    n_corners = len(corners)
    print(f"# {args.model} {args.size} px: {len(ts.material)} triangles, {len(em)} emitting; "
          f"LDR FLIP against {args.cycles}")
    print(f"raster                       {flip_ldr(raster, ref):.3f}")
    print(f"raster + per-vertex bake     {flip_ldr(with_vertex, ref):.3f}   ({n_corners} corners x 2 sides x "
          f"{args.vertex_samples} samples: {bake_ms:.0f} ms)")
    print(f"raster + per-pixel           {flip_ldr(with_pixel, ref):.3f}   ({len(sel)} pixels x "
          f"{args.pixel_samples} samples: {pixel_ms:.0f} ms)")
    rel = np.abs(e_vertex - e_pixel).sum(1) / np.maximum(e_pixel.sum(1), 1e-6)
    lit = e_pixel.sum(1) > 0.05 * e_pixel.sum(1).max()
    print(f"vertex vs pixel irradiance on the lit pixels: median |error| {np.median(rel[lit]) * 100:.0f}%, "
          f"90th percentile {np.percentile(rel[lit], 90) * 100:.0f}%")
    if args.tree_samples:
        traced = o.replace(method="raytrace")
        render(asset, env, traced)  # compiled kernels loaded, Embree scene cached
        kept = raytrace.EMITTER_SAMPLES
        for n_s in (int(x) for x in args.tree_samples.split(",")):
            raytrace.EMITTER_SAMPLES = n_s
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                img = render(asset, env, traced).linear
                times.append((time.perf_counter() - t0) * 1e3)
            print(f"raytrace (tree), {n_s} emitter points a ray   {flip_ldr(img, ref):.3f}   "
                  f"median {np.median(times):.0f} ms of {args.repeat}")
        raytrace.EMITTER_SAMPLES = kept
    if args.sheet:
        from PIL import Image

        from bench.fidelity import display
        tiles = [np.round(display(x) * 255).clip(0, 255).astype(np.uint8)
                 for x in (raster, with_vertex, with_pixel, ref)]
        Image.fromarray(np.concatenate(tiles, axis=1)).save(args.sheet)
        print(f"wrote {args.sheet} (raster | + per-vertex bake | + per-pixel | Cycles)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
