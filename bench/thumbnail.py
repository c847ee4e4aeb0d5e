"""`asset-preview bench thumbnail`: our thumbnail beside pyrender and f3d, same run, same camera.

Ours twice: `ours` is the default look (the generated studio light, gradient backdrop, ground
contact shadow) and `ours-old` the look
before it (footprint_court panorama as light and background, no shadow). `ours` also renders
a `--turntable`-frame turntable in the warm process (one upload, one bake; WebP encoding
included), reported per frame beside the single thumbnail, and `--repeat` interleaved pairs of
frames with the shadow on and off at one camera: the shadow's cost, wall and CPU.

Per asset and size, each tool runs in processes of its own (GL contexts do not mix):
- cold: wall time of a new process from start to a PNG on disk (interpreter, imports, GL
  context, shader compile, loading the asset: ours from the bake cache, peers from the file,
  render, PNG). One unmeasured run first per tool fills every disk cache (ours, f3d's HDRI
  bake, Mesa's shader cache), then the median of `--cold-repeat` runs (every tool's in turn),
  wall and CPU (the process's, all threads), and in-process: from the tool's set-up (loading
  the asset, its libraries' lazy imports) to the PNG, wall and CPU, without the interpreter's
  start and the first imports, where most of the noise lies; for ours also that frame's
  stages (renderer FrameTimings: upload, draw with the edges' set-up, ...).
- warm: in one process per tool, after a first thumbnail, the median time of the next
  `--repeat` thumbnails rendered into a uint8 RGB(A) array in memory, every tool's processes
  asked for one thumbnail at a time in turn (so all see the same machine load) ("+png": plus PNG encoding with the
  same encoder, renderer.frame.encode_png, for every tool), and the median CPU time of the process (all threads,
  llvmpipe's included) per render: the work a thumbnail costs, much less disturbed than wall
  time when other jobs share the two cores.
Peers: pyrender (EGL, one directional light from the camera plus ambient: punctual lights,
no image-based lighting, 4x MSAA) and f3d's Python module (EGL, HDRI = the same panorama with
`render.hdri.ambient` on and the skybox shown, FXAA, tone mapping). f3d reads no USD in its
PyPI wheel, so peers get the Teapot as a .glb exported from our bake (same triangles).
BigTextures8k (bench.big_textures: the Duck with three 8192^2 PNG textures in a 77 MB .glb) is
the StainedGlassLamp-class case; for it the run also reports the baked texture bytes and the
FLIP at 1024 px of our render against the same render with full-resolution textures.
TeapotFine is the Teapot baked one subdivision level finer (158k triangles, near the edge
anti-aliasing cap). `--tools ours,ours-unbaked` adds ours from the same entry with its baked
welded edges, hull and support points dropped, so the first frame computes them
(core.adjacency; core.hull: qhull with its scipy import, support points over every vertex) as
before the bake stored them: the cold path's before/after in one run.
Ours loads the bake by key, as the service's workers do. Per asset and size the run also
reports our anti-aliasing: FLIP of the default frame (edge anti-aliasing) against a 16x
supersampled render of our own (4 x 4 shaded samples per pixel), beside the frame with 4x MSAA
and the frame without anti-aliasing.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ASSETS = {
    "Duck": "gltf/Duck.glb",
    "CesiumMilkTruck": "gltf/CesiumMilkTruck.glb",
    "Teapot": "usd/Teapot/Teapot.usd",
    # Khronos material test models: clearcoat, sheen and rough transmission lobes
    "ClearCoatTest": "gltf-samples/ClearCoatTest/glTF/ClearCoatTest.gltf",
    "SheenCloth": "gltf-samples/SheenCloth/glTF/SheenCloth.gltf",
    "TransmissionRoughnessTest": "gltf-samples/TransmissionRoughnessTest/glTF/TransmissionRoughnessTest.gltf",
    "BigTextures8k": None,  # generated: bench.big_textures
    "TeapotFine": "usd/Teapot/Teapot.usd",  # baked one subdivision level finer: 158k triangles
}
BAKE_OPTIONS: dict[str, dict[str, Any]] = {"TeapotFine": {"subdivision_levels": 3}}
TOOLS = ("ours", "ours-old", "pyrender", "f3d")  # and on request ours-unbaked (below)
OLD_ENV = "footprint_court"  # the default light before the studio


def _view() -> dict[str, Any]:
    """The default view (core.options.RenderOptions), for every tool."""
    from core.options import RenderOptions
    d = RenderOptions()
    return {"yaw": d.yaw, "pitch": d.pitch, "fov": d.fov}


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--assets", default=",".join(ASSETS), help="comma-separated: " + ", ".join(ASSETS))
    p.add_argument("--sizes", default="256,512")
    p.add_argument("--tools", default=",".join(TOOLS))
    p.add_argument("--repeat", type=int, default=15, help="warm thumbnails timed per case")
    p.add_argument("--cold-repeat", type=int, default=3, help="cold processes timed per case")
    p.add_argument("--turntable", type=int, default=24, help="frames of the warm turntable (0: none)")
    p.add_argument("--env", default=None, help="environment (default: the bundled default)")
    p.add_argument("--cache", default=None, help="bake cache (default: a temporary folder)")
    p.add_argument("--json", help="also write the results here")
    p.add_argument("--multiscatter-cost", action="store_true",
                   help="only time our warm thumbnail with and without energy compensation, "
                        "interleaved in one process (no peers)")


def run(args: argparse.Namespace) -> int:
    from bench import big_textures
    from bench.assets import ASSETS as assets_root
    from pipeline.bake import bake_asset
    from pipeline.environment.panorama import DEFAULT_ENVIRONMENT, load_panorama, write_rgbe
    work = Path(tempfile.mkdtemp(prefix="bench-thumbnail-"))
    cache = Path(args.cache) if args.cache else work / "cache"
    env_name = args.env or DEFAULT_ENVIRONMENT
    pano = load_panorama(env_name)
    panorama = str(pano.files[0])
    if pano.files[0].suffix == ".py":  # generated in code (the studio): f3d reads an .hdr
        panorama = str(work / f"{pano.name}.hdr")
        write_rgbe(panorama, pano.pixels)
    sizes = [int(s) for s in args.sizes.split(",")]
    tools = [t for t in args.tools.split(",") if t]
    if args.multiscatter_cost:
        return _multiscatter_cost(args, cache, env_name, sizes)
    results = []
    for name in args.assets.split(","):
        rel = ASSETS[name]
        src = big_textures.build(assets_root) if rel is None else assets_root / rel
        baked = bake_asset(src, cache, **BAKE_OPTIONS.get(name, {}))  # ours renders from the cache, as the service does
        if name == big_textures.NAME:
            _texture_report(src, baked, cache, env_name)
        if any(t.startswith("ours") for t in tools):
            _edges_report(name, baked)
        peer_file = str(src) if src.suffix in (".glb", ".gltf") else _export_glb(baked, work / f"{name}.glb")
        for size in sizes:
            job = {"asset": str(src), "key": baked.key, "peer_file": peer_file, "size": size, "cache": str(cache),
                   "env": env_name, "panorama": panorama, "bounds": baked.bounds.tolist(),
                   "out": str(work / f"{name}-{size}-{{tool}}.png"), "turntable": args.turntable}
            row = {"asset": name, "size": size, "triangles": baked.triangle_count}
            row.update(_measure(tools, job, args.repeat, args.cold_repeat))
            if "ours" in tools:
                row["aa_flip"] = _aa_report(name, baked, cache, env_name, size)
            results.append(row)
            _print_row(row, tools)
    _print_summary(results, tools)
    print(f"\nimages: {work}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


def _texture_report(src: Path, baked, cache: Path, env_name: str, px: int = 1024) -> None:
    """Baked texture bytes, and FLIP at `px` against full-resolution textures (mips from the
    source size, built in memory: no 8k bake written)."""
    import flip_evaluator
    import numpy as np

    from core.options import RenderOptions
    from pipeline.bake import bake_environment, build_baked
    from pipeline.ingest import load_scene
    from renderer import render
    from renderer.methods.auto import environment_face_size
    entry = cache / "assets" / baked.key
    tex_bytes = sum(f.stat().st_size for f in entry.glob("texture.*"))
    src_bytes = src.stat().st_size
    full = build_baked(load_scene(src), "full-resolution", {"thumbnail_size": 1 << 16})
    errors = {}
    for bg in ("env", "transparent"):
        o = RenderOptions(width=px, height=px, background=bg, **_view())
        env = bake_environment(env_name, cache, face_size=environment_face_size(baked, o)[0])
        a, b = render(baked, env, o), render(full, env, o)
        err, mean, _ = flip_evaluator.evaluate(b.rgba8[..., :3] / np.float32(255),
                                               a.rgba8[..., :3] / np.float32(255), "LDR",
                                               applyMagma=False)
        errors[bg] = mean
        if bg == "transparent":  # the object's pixels only
            errors["object"] = float(err[b.rgba8[..., 3] > 0].mean())
    print(f"{src.name}: source {src_bytes / 1e6:.1f} MB, baked textures {tex_bytes / 1e6:.2f} MB "
          f"(target <= 32 MB); FLIP at {px} px vs full-resolution textures: frame "
          f"{errors['env']:.4f}, object pixels {errors['object']:.4f} (target <= 0.02)", flush=True)


def _edges_report(name: str, baked, repeat: int = 7) -> None:
    """The welded edges of edge anti-aliasing: what their set-up costs a first frame from the
    bake (its faces' planes) and built there (core.adjacency, before the bake stored them),
    CPU medians in this process; what reading and checksumming their bytes adds to a load,
    and their bake time and bytes."""
    import dataclasses
    import hashlib
    import io

    import numpy as np

    from renderer.raster import edges

    def cpu_ms(fn) -> float:
        runs = []
        for _ in range(repeat):
            c = time.process_time()
            fn()
            runs.append((time.process_time() - c) * 1e3)
        return statistics.median(runs)
    built = [dataclasses.replace(m, edges=None, edge_faces=None) for m in baked.meshes]
    arrays = {f"{i}.{k}": getattr(m, k) for i, m in enumerate(baked.meshes)
              for k in ("edges", "edge_faces") if getattr(m, k) is not None}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    data = buf.getvalue()

    def load() -> None:
        hashlib.sha256(data).hexdigest()
        with np.load(io.BytesIO(data)) as npz:
            [npz[k] for k in npz.files]
    print(f"{name:>15} edges per upload: {cpu_ms(lambda: [edges.of_mesh(m) for m in baked.meshes]):.1f} ms "
          f"from the bake vs {cpu_ms(lambda: [edges.of_mesh(m) for m in built]):.1f} ms built (CPU, medians "
          f"of {repeat}); their {len(data) / 1024:.0f} KB in the entry: +{cpu_ms(load):.1f} ms to a load, "
          f"{1e3 * baked.manifest['timings']['adjacency_s']:.1f} ms at bake", flush=True)


def _aa_report(name: str, baked, cache: Path, env_name: str, size: int) -> dict:
    """Anti-aliasing of our default frame: FLIP (LDR) against a 16x supersampled render of
    our own (renderer.raster.render.render_supersampled), beside the same frame with 4x MSAA and
    without anti-aliasing."""
    import dataclasses

    import flip_evaluator
    import numpy as np

    from core.options import RenderOptions
    from pipeline.bake import bake_environment
    from renderer import render
    from renderer.methods.auto import environment_face_size
    from renderer.raster.render import render_supersampled
    o = RenderOptions(width=size, height=size, **_view())
    env = bake_environment(env_name, cache, face_size=environment_face_size(baked, o)[0])
    ref = render_supersampled(baked, env, o, 4).rgba8[..., :3] / np.float32(255)
    out = {}
    for label, change in (("default", {}), ("msaa", {"antialias": "msaa", "msaa": 4}), ("no_aa", {"msaa": 0})):
        img = render(baked, env, dataclasses.replace(o, **change)).rgba8[..., :3] / np.float32(255)
        out[label] = float(flip_evaluator.evaluate(ref, img, "LDR", applyMagma=False)[1])
    print(f"{name:>15} {size:>4}px anti-aliasing, FLIP vs 16x supersampled: default ({o.antialias}) "
          f"{out['default']:.4f}, 4x MSAA {out['msaa']:.4f}, without anti-aliasing {out['no_aa']:.4f}",
          flush=True)
    return out


def _multiscatter_cost(args, cache: Path, env_name: str, sizes: list[int]) -> int:
    """Warm thumbnails with energy compensation (the default) and without, alternating frame by
    frame in this process so that both see the same machine load; medians and their ratio."""
    import dataclasses

    from bench.assets import ASSETS as assets_root
    from core.cubemap import default_face_size
    from core.options import RenderOptions
    from pipeline.bake import bake_asset, bake_environment
    from renderer import render
    print(f"{'asset':>15} {'px':>4} {'multiscatter ms':>16} {'without ms':>11} {'ratio':>6}"
          f" {'cpu ms':>8} {'without':>8} {'ratio':>6}")
    for name in args.assets.split(","):
        rel = ASSETS[name]
        if rel is None:  # generated assets are the texture report's, not this comparison's
            continue
        asset = bake_asset(assets_root / rel, cache)
        for size in sizes:
            env = bake_environment(env_name, cache, face_size=default_face_size(size))
            on = RenderOptions(width=size, height=size, **_view())
            off = dataclasses.replace(on, multiscatter=False)
            wall: dict[bool, list[float]] = {True: [], False: []}
            cpu: dict[bool, list[float]] = {True: [], False: []}
            render(asset, env, on), render(asset, env, off)  # compile both programs
            for _ in range(args.repeat):
                for o in (on, off):
                    c, t = _cpu(), time.perf_counter()
                    _ = render(asset, env, o).rgba8
                    wall[o.multiscatter].append((time.perf_counter() - t) * 1e3)
                    cpu[o.multiscatter].append((_cpu() - c) * 1e3)
            a, b = statistics.median(wall[True]), statistics.median(wall[False])
            ca, cb = statistics.median(cpu[True]), statistics.median(cpu[False])
            print(f"{name:>15} {size:>4} {a:>16.2f} {b:>11.2f} {a / b:>6.3f}"
                  f" {ca:>8.2f} {cb:>8.2f} {ca / cb:>6.3f}", flush=True)
    return 0


def _export_glb(baked, path: Path) -> str:
    """Our baked geometry (with vertex colours) as a .glb for peers that cannot read the source."""
    import numpy as np
    import trimesh
    scene = trimesh.Scene()
    for m in baked.meshes:
        for k, mtx in enumerate(m.transforms):
            colors = m.colors if m.colors is not None else np.tile(m.material.base_color, (len(m.positions), 1))
            mesh = trimesh.Trimesh(m.positions, m.indices, vertex_normals=m.normals, process=False,
                                   vertex_colors=(np.clip(colors, 0, 1) * 255).astype(np.uint8))
            scene.add_geometry(mesh, node_name=f"{m.name}-{k}", transform=mtx)
    scene.export(path)
    return str(path)


def _measure(tools: list[str], job: dict, repeat: int, cold_repeat: int) -> dict[str, dict]:
    """Cold runs per tool, then the warm thumbnails of every tool interleaved: one worker
    process per tool, kept, asked for one thumbnail at a time in turn (the order rotating),
    so that every tool's medians see the same machine load."""
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    cwd = Path(__file__).resolve().parents[1]

    def cmd(tool: str) -> list[str]:
        return [sys.executable, "-m", "bench.thumbnail", tool, json.dumps(job)]

    def worker(tool: str, *extra) -> str:
        p = subprocess.run(cmd(tool) + list(extra), env=env, cwd=cwd, capture_output=True, text=True)
        if p.returncode:
            raise RuntimeError(f"{tool} worker failed:\n{p.stderr[-2000:]}")
        return p.stdout

    for tool in tools:
        worker(tool, "cold")  # fill the disk caches
    colds: dict[str, list[dict]] = {tool: [] for tool in tools}
    for i in range(cold_repeat):  # tools in turn, the order rotating, as for warm thumbnails
        for tool in tools[i % len(tools):] + tools[:i % len(tools)]:
            t, c = time.perf_counter(), _cpu(resource.RUSAGE_CHILDREN)
            reply = next(line for line in worker(tool, "cold").splitlines() if line.startswith(_REPLY))
            colds[tool].append({"cold_s": time.perf_counter() - t,
                                "cold_cpu_s": _cpu(resource.RUSAGE_CHILDREN) - c,
                                **json.loads(reply[len(_REPLY):])})
    out: dict[str, dict] = {tool: {k: statistics.median(run[k] for run in runs) if runs else None
                                   for k in ("cold_s", "cold_cpu_s", "first_ms", "first_cpu_ms")}
                            for tool, runs in colds.items()}  # --cold-repeat 0: none
    for tool, runs in colds.items():  # ours: the stages of the cold process's one frame
        out[tool].update({k: statistics.median(run[k] for run in runs)
                          for k in (runs[0] if runs else {}) if k.startswith("frame_")})
    procs = {t: subprocess.Popen(cmd(t) + ["serve"], env=env, cwd=cwd, stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, text=True) for t in tools}

    def ask(tool: str, line: str) -> dict:
        p = procs[tool]
        assert p.stdin is not None and p.stdout is not None
        p.stdin.write(line + "\n")
        p.stdin.flush()
        while True:  # a peer's library may print its own lines to stdout
            reply = p.stdout.readline()
            if not reply:
                raise RuntimeError(f"{tool} worker stopped (see its stderr above)")
            if reply.startswith(_REPLY):
                return json.loads(reply[len(_REPLY):])
    try:
        for name in tools:
            ask(name, "ready")  # set up and the first thumbnail drawn
        shots: dict[str, list[dict]] = {name: [] for name in tools}
        for i in range(repeat):
            for name in tools[i % len(tools):] + tools[:i % len(tools)]:
                shots[name].append(ask(name, "shot"))
        for name in tools:
            med = {k: statistics.median(shot[k] for shot in shots[name]) for k in ("render", "render_png", "cpu_ms")}
            out[name].update(warm_ms=med["render"], warm_png_ms=med["render_png"], warm_cpu_ms=med["cpu_ms"])
            if name == "ours":
                out[name].update(ask(name, f"extra {repeat}"))
    finally:
        for p in procs.values():
            if p.stdin is not None:
                p.stdin.close()
            p.wait(timeout=120)
    return out


def _print_row(row: dict, tools: list[str]) -> None:
    parts = [f"{row['asset']:>15} {row['size']:>4}px"]
    for t in tools:
        r = row[t]
        extra = ""
        if "shadow_ms" in r:
            extra += (f", shadow +{r['shadow_ms']:.1f} ms wall = {r['shadow_ms'] / r['noshadow_ms']:.0%}, "
                      f"+{r['shadow_cpu_ms']:.1f} ms cpu = {r['shadow_cpu_ms'] / r['noshadow_cpu_ms']:.0%}"
                      " of the frame without it")
        if "turntable_frame_ms" in r:
            n, frame, enc = r["turntable_frames"], r["turntable_frame_ms"], r["turntable_encode_ms"]
            extra += (f", turntable of {n}: {frame:.1f} ms/frame render + {enc:.1f} webp "
                      f"(a warm thumbnail: {r['warm_ms']:.1f} + png), {n * (frame + enc) / 1e3:.2f} s in all")
            if r["cold_s"] is not None:
                extra += f" vs {n * r['cold_s']:.1f} s for {n} `render` commands"
        cold = "-" if r["cold_s"] is None else (f"{r['cold_s']:.2f} s (cpu {r['cold_cpu_s']:.2f}; "
                                                f"in-process {r['first_ms']:.0f} ms, cpu {r['first_cpu_ms']:.0f}")
        if "frame_total_ms" in r:
            stages = ", ".join(f"{k[6:-3]} {v:.1f}" for k, v in r.items()
                               if k.startswith("frame_") and k != "frame_total_ms")
            cold += f"; its frame {r['frame_total_ms']:.0f} ms: {stages}"
        cold += ")" if r["cold_s"] is not None else ""
        parts.append(f"{t}: cold {cold}, warm {r['warm_ms']:.1f} ms "
                     f"(+png {r['warm_png_ms']:.1f}, cpu {r['warm_cpu_ms']:.1f}){extra}")
    print(" | ".join(parts), flush=True)


def _print_summary(results: list[dict], tools: list[str]) -> None:
    peers = [t for t in tools if t != "ours"]  # ours-old included: the default look's cost
    if "ours" not in tools or not peers:
        return
    print("\nratios, ours / peer (below 1: we are faster)")
    head = f"{'asset':>15} {'px':>4} " + " ".join(f"{'warm/' + p:>14} {'cpu/' + p:>14} {'cold/' + p:>14}" for p in peers)
    print(head)
    for r in results:
        cells = []
        for p in peers:
            cells.append(f"{r['ours']['warm_ms'] / r[p]['warm_ms']:>14.2f}")
            cells.append(f"{r['ours']['warm_cpu_ms'] / r[p]['warm_cpu_ms']:>14.2f}")
            cold = (r["ours"]["cold_s"], r[p]["cold_s"])
            cells.append(f"{cold[0] / cold[1]:>14.2f}" if None not in cold else f"{'-':>14}")
        print(f"{r['asset']:>15} {r['size']:>4} " + " ".join(cells))


# --- workers: one tool, one process -----------------------------------------------------------

def _camera(job: dict):
    import numpy as np

    from renderer.view.camera import frame_bounds
    return frame_bounds(np.array(job["bounds"]), job["size"], job["size"], **_view())


def _png(rgb) -> bytes:
    from renderer.frame import encode_png
    if rgb.shape[2] == 4 and rgb[..., 3].min() == 255:
        rgb = rgb[..., :3]  # opaque: RGB, as Frame.encode writes it
    return encode_png(rgb)


def _ours(job: dict, old: bool = False, unbaked: bool = False):
    from core.options import RenderOptions
    from pipeline.bake import bake_environment, load_baked
    from renderer.methods.auto import environment_face_size
    asset = load_baked(job["key"], job["cache"])
    if unbaked:  # edges, hull and support points computed by the first frame, as before the
        asset.hull = None  # bake stored them
        for mesh in asset.meshes:
            mesh.edges = mesh.edge_faces = mesh.support = None
    look: dict[str, Any] = {"background": "env", "shadow": 0.0} if old else {}
    options = RenderOptions(width=job["size"], height=job["size"], **_view(), **look)
    env = bake_environment(OLD_ENV if old else job["env"], job["cache"],
                                    face_size=environment_face_size(asset, options)[0])

    return _OursShot(asset, env, options)


class _OursShot:
    """One thumbnail per call, plus the turntable and shadow measurements of the same set-up."""
    def __init__(self, asset, env, options):
        self.asset, self.env, self.options = asset, env, options

    def __call__(self):
        from renderer import render
        frame = render(self.asset, self.env, self.options)
        self.timings = frame.timings.as_dict()  # the cold worker reports its one frame's stages
        return frame.rgba8

    def turntable(self, n: int) -> tuple[float, float]:
        return _turntable(self.asset, self.env, self.options, n)

    def shadow_cost(self, n: int) -> dict:
        return _shadow_cost(self.asset, self.env, self.options, n)


def _shadow_cost(asset, env, options, n: int) -> dict:
    """What the ground shadow adds to a frame: n interleaved pairs with the shadow on and off
    at one camera (the shadow otherwise also widens the framing), medians of wall and CPU."""
    import dataclasses

    from renderer import render
    distance = render(asset, env, options).plan["view"]["distance"]
    on = dataclasses.replace(options, distance=distance)
    off = dataclasses.replace(on, shadow=0.0)
    wall: dict[str, list[float]] = {"on": [], "off": []}
    cpu: dict[str, list[float]] = {"on": [], "off": []}
    for _ in range(n):
        for k, o in (("on", on), ("off", off)):
            c, t = _cpu(), time.perf_counter()
            render(asset, env, o)
            wall[k].append((time.perf_counter() - t) * 1e3)
            cpu[k].append((_cpu() - c) * 1e3)
    med = {f"{m}_{k}": statistics.median(v[k]) for m, v in (("wall", wall), ("cpu", cpu)) for k in v}
    return {"shadow_ms": med["wall_on"] - med["wall_off"], "shadow_cpu_ms": med["cpu_on"] - med["cpu_off"],
            "noshadow_ms": med["wall_off"], "noshadow_cpu_ms": med["cpu_off"]}


def _turntable(asset, env, options, n: int) -> tuple[float, float]:
    """Wall ms per frame of an n-frame turntable: rendering, and WebP encoding (medians of 3)."""
    import dataclasses

    from renderer.sequence import encode_animation, render_turntable
    opts = dataclasses.replace(options, turntable=n)
    draw, encode = [], []
    for _ in range(3):
        t = time.perf_counter()
        frames = render_turntable(asset, env, opts, keep_linear=False)  # as the service does
        t1 = time.perf_counter()
        encode_animation(frames, "webp")
        draw.append((t1 - t) * 1e3 / n)
        encode.append((time.perf_counter() - t1) * 1e3 / n)
    return statistics.median(draw), statistics.median(encode)


def _pyrender(job: dict):
    import numpy as np
    import pyrender
    import trimesh
    scene = pyrender.Scene.from_trimesh_scene(trimesh.load(job["peer_file"]), ambient_light=[0.3] * 3)
    cam = _camera(job)
    pose = np.linalg.inv(cam.view_matrix())
    scene.add(pyrender.PerspectiveCamera(yfov=np.radians(cam.fov), aspectRatio=cam.aspect,
                                         znear=cam.near, zfar=cam.far), pose=pose)
    scene.add(pyrender.DirectionalLight(intensity=3.0), pose=pose)
    r = pyrender.OffscreenRenderer(job["size"], job["size"])
    return lambda: r.render(scene)[0]


def _f3d(job: dict):
    import f3d
    import numpy as np
    f3d.Engine.autoload_plugins()
    eng = f3d.Engine.create_egl()
    eng.options.update({"render.hdri.file": job["panorama"], "render.hdri.ambient": True,
                        "render.background.skybox": "enabled",
                        "render.effect.antialiasing.mode": "fxaa", "render.effect.tone_mapping": True})
    eng.window.size = (job["size"], job["size"])
    eng.scene.add(job["peer_file"])
    cam = _camera(job)
    c = eng.window.camera
    c.position, c.focal_point, c.view_up = (tuple(map(float, v)) for v in (cam.position, cam.target, cam.up))  # type: ignore[assignment]  # f3d: 3-tuples
    c.view_angle = cam.fov

    def shot():
        img = eng.window.render_to_image()
        return np.frombuffer(img.content, np.uint8).reshape(img.height, img.width, img.channel_count)[::-1]
    return shot


def _worker(tool: str, job: dict, mode: str) -> None:
    """`cold`: one thumbnail to a PNG. `serve`: set up, then answer lines from stdin, one
    JSON line each: `ready` (after a first thumbnail), `shot` (one timed thumbnail: render,
    render + PNG, CPU), `extra N` (ours: the shadow's cost and the turntable)."""
    make = {"ours": _ours, "ours-old": lambda j: _ours(j, old=True),
            "ours-unbaked": lambda j: _ours(j, unbaked=True), "pyrender": _pyrender, "f3d": _f3d}
    c, t = _cpu(), time.perf_counter()
    shot = make[tool](job)
    if mode == "cold":
        Path(job["out"].format(tool=tool)).write_bytes(_png(shot()))
        print(_REPLY + json.dumps({"first_ms": (time.perf_counter() - t) * 1e3,
                                   "first_cpu_ms": (_cpu() - c) * 1e3,
                                   **{f"frame_{k}": v for k, v in getattr(shot, "timings", {}).items()}}),
              flush=True)
        return
    for line in sys.stdin:
        cmd, *arg = line.split()
        out: dict = {}
        if cmd == "ready":
            shot()
        elif cmd == "shot":
            c = _cpu()
            t = time.perf_counter()
            img = shot()
            t1 = time.perf_counter()
            out["cpu_ms"] = (_cpu() - c) * 1e3
            _png(img)
            out["render"], out["render_png"] = (t1 - t) * 1e3, (time.perf_counter() - t) * 1e3
        elif cmd == "extra" and tool == "ours":
            out.update(shot.shadow_cost(int(arg[0])))
            if job.get("turntable"):
                out["turntable_frame_ms"], out["turntable_encode_ms"] = shot.turntable(job["turntable"])
                out["turntable_frames"] = job["turntable"]
        print(_REPLY + json.dumps(out), flush=True)


_REPLY = "@reply "  # marks the serve worker's answers among whatever else reaches stdout


def _cpu(who: int = resource.RUSAGE_SELF) -> float:
    """CPU seconds of this process, all threads (llvmpipe's included): the work a thumbnail
    costs, less disturbed than wall time by other jobs on a shared machine (RUSAGE_CHILDREN:
    of the worker processes that have ended)."""
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


if __name__ == "__main__":
    _worker(sys.argv[1], json.loads(sys.argv[2]), sys.argv[3])
