"""Ingest speed: our `load_scene` beside `trimesh.load` on the same files, in the same run.

Per asset: median ms of --repeat loads each (after one warm-up), and ours/trimesh. trimesh
opens embedded images lazily (it never decodes their pixels), and so do we (textures decode
on first use), so both columns measure parsing; the `+decode` column adds decoding every
texture to RGBA, what a bake pays later. trimesh cannot read USD: ours only there.

A second table measures compressed glTF (`--no-compressed` skips it): the shared samples'
glTF-Draco variants, and meshopt / KTX2 (UASTC) variants of Duck made in the run with the
encoders' wheels (bench/compressed.py). Per file: the bytes read, our load + decode (every
texture transcoded too) in ms and ms per MB read, the uncompressed sibling's load + decode,
and trimesh.load where it can read the file at all.

The generated USD stages (bench/usd_stages.py; `--no-stages` skips them): 10,000 instances of a
5,000-triangle mesh, by instanceable references and by a PointInstancer, and a stage of 64
MaterialX materials, beside a plain pxr traversal of the same stage, with each side's peak memory.
"""
from __future__ import annotations

import argparse
import gc
import statistics
import time
from pathlib import Path

from bench.assets import CORPUS

DEFAULT_ASSETS = CORPUS  # ../shared/assets when beside the checkout, else tests/assets
GROUPS = {"gltf": ("*.gltf", "*.glb"), "mesh": ("*.ply", "*.stl", "*.STL", "*.obj"),
          "usd": ("*.usd", "*.usda", "*.usdc", "*.usdz")}
USD_SUFFIXES = {".usd", ".usda", ".usdc", ".usdz"}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="*", type=Path,
                        help="asset files (default: every sample in ../shared/assets)")
    parser.add_argument("--assets", type=Path, default=DEFAULT_ASSETS,
                        help="sample asset folder (default: %(default)s)")
    parser.add_argument("--repeat", type=int, default=7, help="timed loads per asset")
    parser.add_argument("--no-compressed", dest="compressed", action="store_false",
                        help="skip the compressed glTF table (Draco, meshopt, KTX2)")
    parser.add_argument("--no-stages", action="store_true",
                        help="skip the generated USD stages (instanced, MaterialX)")


def sample_files(root: Path) -> list[Path]:
    """The sample assets: gltf/ and mesh/ files, usd/ top-level files and each package's
    entry file (the one named after its folder)."""
    files: list[Path] = []
    for group in ("gltf", "mesh"):
        for pattern in GROUPS[group]:
            files += sorted((root / group).glob(pattern))
    usd = root / "usd"
    for pattern in GROUPS["usd"]:
        files += sorted(usd.glob(pattern))
        files += sorted(p for p in usd.glob(f"*/{pattern}") if p.stem == p.parent.name)
    return sorted(set(files), key=lambda p: (p.parent.name != "gltf", str(p)))


def _median_ms(fns, repeat: int) -> list[float]:
    """Median ms of each function, called in turn within every round so that both sides see
    the same machine load (the CPU is shared), after one warm-up round; the order rotates
    each round so neither side always runs first. As in timeit, the garbage collector is
    paused during a round and run between rounds."""
    times: list[list[float]] = [[] for _ in fns]
    for round_ in range(repeat + 1):
        gc.collect()
        gc.disable()
        try:
            order = list(zip(fns, times))
            shift = round_ % len(order)
            for fn, out in order[shift:] + order[:shift]:
                start = time.perf_counter()
                fn()
                if round_:
                    out.append(time.perf_counter() - start)
        finally:
            gc.enable()
    return [1000 * statistics.median(t) for t in times]


def run(args: argparse.Namespace) -> int:
    import trimesh

    from core.errors import AssetError
    from pipeline.ingest import load_scene

    paths = args.paths or sample_files(args.assets)
    print(f"{'asset':34} {'tris':>7} {'ours ms':>9} {'+decode':>9} {'trimesh ms':>10} {'ratio':>6}")
    worst = 0.0
    for path in paths:
        try:
            scene = load_scene(path)
        except AssetError as exc:
            print(f"{path.name:34} error: {exc.reason}")
            continue

        def load_and_decode():
            for tex in load_scene(path).textures:
                tex.image  # noqa: B018 - decoding is the point
        if path.suffix.lower() in USD_SUFFIXES:  # trimesh reads no USD: ours only
            ours = _median_ms([lambda: load_scene(path)], args.repeat)[0]
            decoded = _median_ms([load_and_decode], args.repeat)[0] if scene.textures else ours
            print(f"{path.name:34} {scene.triangle_count:7d} {ours:9.2f} {decoded:9.2f} "
                  f"{'(no peer)':>10} {'':>6}")
            continue
        ours, peer = _median_ms([lambda: load_scene(path), lambda: trimesh.load(path)],
                                args.repeat)
        decoded = _median_ms([load_and_decode], args.repeat)[0] if scene.textures else ours
        ratio = ours / peer
        if path.suffix.lower() in (".gltf", ".glb"):
            worst = max(worst, ratio)
        print(f"{path.name:34} {scene.triangle_count:7d} {ours:9.2f} {decoded:9.2f} "
              f"{peer:10.2f} {ratio:6.2f}")
    print(f"worst glTF ratio ours/trimesh: {worst:.2f} (target <= 1.0); median of "
          f"{args.repeat} loads each, after one warm-up")
    if args.compressed:
        compressed_table(args.assets, args.repeat)
    if not args.no_stages:
        _stages(min(args.repeat, 3))
    return 0


def compressed_files(assets: Path, tmp: Path) -> list[tuple[Path, str, Path]]:
    """(compressed file, codec, uncompressed sibling) for the compressed glTF table."""
    from bench.compressed import ktx2_variant, meshopt_variant

    samples = assets / "gltf-samples"
    rows = [(p, "draco", p.parent.parent / "glTF" / p.name)
            for p in sorted(samples.glob("*/glTF-Draco/*.gltf"))]
    duck = samples / "Duck" / "glTF" / "Duck.gltf"
    if duck.exists():
        rows.append((meshopt_variant(duck, tmp / "meshopt"), "meshopt", duck))
        rows.append((ktx2_variant(duck, tmp / "ktx2"), "ktx2", duck))
    return rows


def compressed_table(assets: Path, repeat: int) -> None:
    import tempfile

    import trimesh

    from pipeline.ingest import load_scene

    def load_decoded(path: Path):
        def fn():
            for tex in load_scene(path).textures:
                tex.image  # noqa: B018 - decoding is the point
        return fn

    def trimesh_fn(path: Path):
        try:
            trimesh.load(path)
        except Exception as exc:  # noqa: BLE001 - a peer that cannot read the file
            return f"({type(exc).__name__})"
        return lambda: trimesh.load(path)

    print(f"\n{'compressed glTF':34} {'codec':>7} {'MB read':>8} {'ours ms':>8} {'ms/MB':>7} "
          f"{'plain ms':>8} {'trimesh ms':>12}")
    with tempfile.TemporaryDirectory() as tmp:
        for path, codec, plain in compressed_files(assets, Path(tmp)):
            mb = sum(Path(f).stat().st_size for f in load_scene(path).files) / 2**20
            peer = trimesh_fn(path)
            fns = [load_decoded(path), load_decoded(plain)] + ([peer] if callable(peer) else [])
            times = _median_ms(fns, repeat)
            peer_text = f"{times[2]:12.2f}" if callable(peer) else f"{peer:>12}"
            name = f"{path.parent.parent.name}/{path.name}" if codec == "draco" else path.name
            print(f"{name[:34]:34} {codec:>7} {mb:8.3f} {times[0]:8.2f} {times[0] / mb:7.1f} "
                  f"{times[1]:8.2f} {peer_text}")
    print("ours and plain include decoding every texture (KTX2: transcoding to RGBA8); "
          f"median of {repeat} each, after one warm-up")


def _stages(repeat: int) -> None:
    import tempfile

    from bench import usd_stages

    with tempfile.TemporaryDirectory(prefix="bench-usd-") as tmp:
        stages = usd_stages.write_stages(Path(tmp))
        print(f"\n{'USD stage':16} {'drawn tris':>11} {'ours ms':>9} {'pxr ms':>8} {'ratio':>6} "
              f"{'ours MB':>8} {'pxr MB':>7}")
        for name, path in stages.items():
            tris = usd_stages.ours(str(path))
            assert tris == usd_stages.pxr_traversal(str(path)), name
            a, b = _median_ms([lambda: usd_stages.ours(str(path)),
                               lambda: usd_stages.pxr_traversal(str(path))], repeat)
            ma, mb = usd_stages.peak_mb("ours", path), usd_stages.peak_mb("pxr", path)
            print(f"{name:16} {tris:11d} {a:9.1f} {b:8.1f} {a / b:6.2f} {ma:8.1f} {mb:7.1f}")
        print(f"median of {repeat} runs after one warm-up; MB: peak resident set a fresh "
              "process adds above its size after imports")
