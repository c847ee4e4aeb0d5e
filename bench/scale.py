"""Scale-out: cold bakes of a few hundred assets with 1 and 2 local workers and with Ray on the
same cores; Ray's per-task overhead; a projection to a large catalogue on N machines.

Corpus: the sample assets plus --copies copies of each with perturbed bytes (a comment in the
header or a glTF `extras`), so every copy has its own cache key and is baked in full. Each
configuration runs the real `asset-bake` command in a fresh process against a fresh cache,
--repeat times in rotating order (the CPU is shared with other work), and the median run is
shown; assets/s counts the bake phase as asset-bake reports it (after Ray has connected; the
wall column includes process and cluster start). Ray's overhead per task is measured three ways: one
no-op task's round trip, the driver's cost per no-op task in a burst, and the bake's extra
wall time per asset against the local 2-worker pool.

Projection (a stated model, not a run): T(N) = A * (c + o) / (N * W * e), bounded below by
A * d (one driver dispatching every task) and by A * b / B (the cache's bytes through the
shared filesystem's write bandwidth B). Measured here: c = mean seconds per asset inside a
worker (1-worker run: ingest + bake + cache write, worker start-up excluded), o = Ray's
overhead per task, d = the driver's cost per task, b = cache bytes per asset. Assumed (flags):
W = cores per machine, e = parallel efficiency on dedicated cores (the 2-worker efficiency
measured here is printed but not used: this machine's 2 cores are shared with other work),
B = filesystem bandwidth. A = 100k assets with this corpus's mix of sizes.

--cluster: the library job (`asset-bake --thumbnails --size 64 --executor ray`, every asset baked
and rendered in one Ray task) over 300+ assets (the corpus above) on a fresh loopback cluster
(bench/cluster.py) with 1 and with 2 worker nodes of 1 CPU each (--repeat rounds, rotating), then
with 2 of which one is SIGKILLed once a quarter is done: exit status, assets per minute, every
asset exactly once in the result lines and the manifest, every cache entry whole, no temporary
file in DIR. Then the local job in one process (cold, and again with the bakes cached) against
f3d rendering the same files in one process (its Python module, EGL), 64 px PNGs each.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.ingest import DEFAULT_ASSETS, sample_files

CATALOGUE = 100_000
CLUSTER_MIN_ASSETS = 300


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--assets", type=Path, default=DEFAULT_ASSETS,
                        help="sample asset folder (default: %(default)s)")
    parser.add_argument("--copies", type=int, default=None,
                        help="perturbed copies of each sample (default 18: ~200 assets; with --cluster, "
                             f"enough for {CLUSTER_MIN_ASSETS})")
    parser.add_argument("--repeat", type=int, default=3,
                        help="cold bakes per executor, in rotating order (the CPU is shared); medians")
    parser.add_argument("--cores", type=int, default=16, help="cores per machine in the projection")
    parser.add_argument("--efficiency", type=float, default=0.8,
                        help="parallel efficiency per machine in the projection (default 0.8)")
    parser.add_argument("--fs-mb-s", type=float, default=500.0,
                        help="shared filesystem write bandwidth in the projection, MB/s")
    parser.add_argument("--cluster", action="store_true",
                        help="instead: the library job (--thumbnails) on a local loopback Ray cluster "
                             "with 1 and 2 worker nodes, and with 2 that lose one mid-run; then the "
                             "local job against f3d in one process")
    parser.add_argument("--keep", type=Path, default=None, help="build corpus and caches here and keep them")


# -- corpus -------------------------------------------------------------------------------------

def _perturb(data: bytes, suffix: str, i: int) -> bytes | None:
    """The same asset with different bytes, or None for a format we do not alter."""
    tag = f"asset-preview bench copy {i}"
    if suffix in (".usda", ".usd") and data.startswith(b"#usda"):
        return data + f"\n# {tag}\n".encode()
    if suffix == ".gltf":
        doc = json.loads(data)
        doc.setdefault("asset", {}).setdefault("extras", {})["bench"] = tag
        return json.dumps(doc).encode()
    if suffix == ".glb":  # rewrite the JSON chunk (padded with spaces to 4 bytes) and lengths
        length = int.from_bytes(data[12:16], "little")
        doc = json.loads(data[20:20 + length])
        doc.setdefault("asset", {}).setdefault("extras", {})["bench"] = tag
        chunk = json.dumps(doc).encode()
        chunk += b" " * (-len(chunk) % 4)
        rest = data[20 + length:]
        body = len(chunk).to_bytes(4, "little") + data[16:20] + chunk + rest
        return data[:8] + (12 + len(body)).to_bytes(4, "little") + body
    if suffix == ".ply":  # a comment after the `ply` and `format` lines
        magic, fmt, rest = data.split(b"\n", 2)
        return b"\n".join((magic, fmt, f"comment {tag}".encode(), rest))
    if suffix == ".stl":
        if len(data) == 84 + 50 * int.from_bytes(data[80:84], "little"):  # binary: 80-byte header
            return f"{tag}".encode().ljust(80) + data[80:]
        first, _, rest = data.partition(b"\n")
        return first.rstrip() + f"_c{i}\n".encode() + rest
    if suffix == ".obj":
        return f"# {tag}\n".encode() + data
    return None


def build_corpus(assets: Path, root: Path, copies: int) -> list[Path]:
    """The samples (copied with their folders, so relative references resolve) and perturbed
    copies beside each: the file list to bake."""
    files = []
    for group in ("gltf", "mesh", "usd"):
        shutil.copytree(assets / group, root / group)
    for sample in sample_files(assets):
        base = root / sample.relative_to(assets)
        files.append(base)
        data = base.read_bytes()
        for i in range(copies):
            changed = _perturb(data, base.suffix.lower(), i)
            if changed is None:
                break
            copy = base.with_name(f"{base.stem}.c{i:03d}{base.suffix}")
            copy.write_bytes(changed)
            files.append(copy)
    return files


# -- runs ---------------------------------------------------------------------------------------

def bake_run(files: list[Path], cache: Path, *extra: str) -> dict:
    """One cold `asset-bake` in a fresh process: wall time, bake-phase time, per-asset seconds."""
    cmd = [sys.executable, "-m", "cli.bake", "--cache", str(cache), "--json", *extra,
           *map(str, files)]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - start
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.strip()]
    m = re.search(r"(\d+) baked, (\d+) cached, \d+ skipped, (\d+) failed in ([\d.]+) s", proc.stderr)
    if not m or len(rows) != len(files):
        raise RuntimeError(f"asset-bake {' '.join(extra)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    size = sum(f.stat().st_size for f in (cache / "assets").rglob("*") if f.is_file())
    return {"wall": wall, "bake": float(m.group(4)), "failed": int(m.group(3)),
            "baked": int(m.group(1)), "seconds": [r["seconds"] for r in rows], "bytes": size,
            "keys": sorted(r.get("key", "") for r in rows)}


def _median_run(runs: list[dict]) -> dict:
    """The run with the median bake time, its wall time the median wall time."""
    out = dict(sorted(runs, key=lambda r: r["bake"])[len(runs) // 2])
    out["wall"] = statistics.median(r["wall"] for r in runs)
    out["failed"] = max(r["failed"] for r in runs)
    out["keys"] = runs[0]["keys"] if all(r["keys"] == runs[0]["keys"] for r in runs) else []
    return out


def ray_overheads(num_cpus: int) -> dict:
    """Cluster start, one no-op task's round trip (median of 50) and the driver's time per
    no-op task in a burst of 1000, on a local cluster like the bake's."""
    import ray

    start = time.perf_counter()
    ray.init(num_cpus=num_cpus, include_dashboard=False, logging_level="ERROR", log_to_driver=False)  # type: ignore[arg-type]  # a level name works
    started = time.perf_counter() - start
    try:
        noop = ray.remote(num_cpus=1)(_noop)
        ray.get([noop.remote() for _ in range(2 * num_cpus)])  # worker processes up
        trips = []
        for _ in range(50):
            t = time.perf_counter()
            ray.get(noop.remote())
            trips.append(time.perf_counter() - t)
        t = time.perf_counter()
        ray.get([noop.remote() for _ in range(1000)])
        burst = (time.perf_counter() - t) / 1000
    finally:
        ray.shutdown()
    return {"start": started, "round_trip": statistics.median(trips), "per_task_burst": burst}


def _noop() -> None:
    return None


# -- report -------------------------------------------------------------------------------------

def run(args: argparse.Namespace) -> int:
    try:
        import ray  # noqa: F401
    except ImportError:
        print("error: bench scale needs Ray: pip install 'asset-preview[ray]'", file=sys.stderr)
        return 2
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-scale-"))
    try:
        return _run_cluster(args, work) if args.cluster else _run(args, work)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


def _run(args: argparse.Namespace, work: Path) -> int:
    work.mkdir(parents=True, exist_ok=True)
    files = build_corpus(args.assets, work / "corpus", 18 if args.copies is None else args.copies)
    cores = os.cpu_count() or 1
    print(f"corpus: {len(files)} assets ({len(sample_files(args.assets))} samples + perturbed copies), "
          f"{cores} cores; cold bakes, fresh cache each")
    configs = [("local, 1 worker", ("--workers", "1")), ("local, 2 workers", ("--workers", "2")),
               ("ray, 2 CPUs", ("--executor", "ray", "--workers", "2"))]
    runs: dict[str, list[dict]] = {label: [] for label, _ in configs}
    for round_ in range(args.repeat):  # rotated so that each sees the machine's load alike
        for label, extra in configs[round_ % 3:] + configs[:round_ % 3]:
            cache = work / f"cache-{configs.index((label, extra))}-{len(runs[label])}"
            runs[label].append(bake_run(files, cache, *extra))
            shutil.rmtree(cache)
    results = {label: _median_run(rs) for label, rs in runs.items()}
    keys = {label: r["keys"] for label, r in results.items()}
    same = len({tuple(k) for k in keys.values()}) == 1
    one, two, ray_ = (results[c[0]] for c in configs)

    print(f"\nmedians of {args.repeat} cold bakes each")
    print(f"{'executor':18} {'wall s':>7} {'bake s':>7} {'assets/s':>9} {'x 1 worker':>10} "
          f"{'median asset ms':>15} {'failed':>6}")
    for label, r in results.items():
        print(f"{label:18} {r['wall']:7.1f} {r['bake']:7.1f} {len(files) / r['bake']:9.1f} "
              f"{one['bake'] / r['bake']:10.2f} {1000 * statistics.median(r['seconds']):15.1f} "
              f"{r['failed']:6d}")
    print(f"same cache keys in all three: {same}")

    ov = ray_overheads(2)
    per_asset_extra = (ray_["bake"] - two["bake"]) / len(files)
    print(f"\nray overhead: cluster start {ov['start']:.1f} s; one no-op task round trip "
          f"{1000 * ov['round_trip']:.2f} ms (median of 50); driver time per task in a burst of "
          f"1000: {1000 * ov['per_task_burst']:.2f} ms; bake wall per asset vs local 2 workers: "
          f"{1000 * per_asset_extra:+.1f} ms ({ray_['bake'] / two['bake']:.2f}x)")

    c = statistics.mean(one["seconds"])
    measured_e = one["bake"] / two["bake"] / 2
    o = max(per_asset_extra * 2, ov["round_trip"])  # per task, in worker-seconds on 2 slots
    b = one["bytes"] / len(files)
    d = ov["per_task_burst"]
    e = args.efficiency
    print(f"\nprojection: {CATALOGUE} assets like this corpus on N machines of {args.cores} cores "
          f"(model in bench/scale.py)")
    print(f"  measured: c = {1000 * c:.1f} ms/asset (mean in a worker), o = {1000 * o:.2f} ms/task, "
          f"d = {1000 * d:.2f} ms/task (driver), b = {b / 2**20:.2f} MiB/asset; "
          f"2-worker efficiency here {measured_e:.2f} (shared cores, not used)")
    print(f"  assumed: e = {e:.2f}, filesystem {args.fs_mb_s:.0f} MB/s")
    print(f"{'machines':>8} {'compute h':>9} {'driver h':>8} {'fs h':>6} {'T hours':>7} {'assets/s':>9}  bound")
    for n in (1, 4, 16, 64, 256):
        bounds = {"compute": CATALOGUE * (c + o) / (n * args.cores * e), "driver": CATALOGUE * d,
                  "filesystem": CATALOGUE * b / (args.fs_mb_s * 1e6)}
        which = max(bounds, key=bounds.__getitem__)
        t = bounds[which]
        print(f"{n:8d} {bounds['compute'] / 3600:9.3f} {bounds['driver'] / 3600:8.3f} "
              f"{bounds['filesystem'] / 3600:6.3f} {t / 3600:7.3f} {CATALOGUE / t:9.0f}  {which}")
    return 0 if same and not any(r["failed"] for r in results.values()) else 1


# -- the library job on a cluster that loses a node ----------------------------------------------

PEER_SUFFIXES = (".glb", ".gltf", ".ply", ".stl", ".obj")  # what f3d 4.0's wheel reads (no USD plugin)


def _summary_seconds(err: str) -> float | None:
    """The job's own time (after Ray connected) from asset-bake's summary line."""
    m = re.search(r"failed(?:; thumbnails: [^\n]*?)? in ([\d.]+) s", err)
    return float(m.group(1)) if m else None


def _check_job(files: list[Path], cache: Path, th: Path, out: str) -> dict:
    """What a finished library job left: result lines, manifest, cache entries, DIR."""
    from pipeline.cache import MANIFEST, Cache

    rows, stray = [], []
    for line in filter(str.strip, out.splitlines()):
        try:
            rows.append(json.loads(line))
        except ValueError:
            stray.append(line)  # stdout is for result lines only: counted as a failure
    paths = [r["path"] for r in rows]
    manifest = json.loads((th / "manifest.json").read_text())["assets"]
    store = Cache(cache)
    entries = [e for kind in ("assets", "thumbnails") for e in (cache / kind).iterdir()]
    whole = all(store.load(e.parent.name, e.name) is not None
                and {f.name for f in e.iterdir()} == {MANIFEST, *json.loads((e / MANIFEST).read_bytes())["files"]}
                for e in entries)
    placed = all(all((th / f).is_file() for f in e["files"]) for e in manifest.values())
    renderers = {(e.get("by") or {}).get("node") or (e.get("by") or {}).get("pid") for e in manifest.values()
                 if e["status"] == "rendered"}
    return {"once": sorted(paths) == sorted(map(str, files)) and sorted(manifest) == sorted(paths),
            "rendered": sum(e["status"] == "rendered" for e in manifest.values()),
            # a render a lost node stored in the cache before it died: its retry finds it there
            "cached": sum(e["status"] == "cached" for e in manifest.values()),
            "whole": whole and placed and not list(th.rglob("*.tmp*")),
            "entries": len(list((cache / "assets").iterdir())), "thumbs": len(list((cache / "thumbnails").iterdir())),
            "renderers": len(renderers), "stray": stray}


def _cluster_job(files: list[Path], work: Path, label: str, workers: int, kill: bool) -> dict:
    """One cold `asset-bake --thumbnails --executor ray` on a fresh loopback cluster; with
    `kill`, worker node 0's raylet is SIGKILLed once a quarter of the library is done."""
    from bench.cluster import LocalCluster

    cache, th = work / f"cache-{label}", work / f"th-{label}"
    cmd = [sys.executable, "-m", "cli.bake", "--cache", str(cache), "--thumbnails", str(th), "--size", "64",
           "--json", "--executor", "ray", *map(str, files)]
    with LocalCluster(workers=workers) as cluster:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, env=cluster.driver_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        killed_at = None
        if kill:
            while proc.poll() is None:
                try:
                    done = len(json.loads((th / "manifest.json").read_text())["assets"])
                except (FileNotFoundError, ValueError):
                    done = 0
                if done >= len(files) // 4:
                    cluster.kill_worker(0)
                    killed_at = done
                    break
                time.sleep(0.05)
        out, err = proc.communicate(timeout=3600)
        wall = time.perf_counter() - start
    return {"label": label, "code": proc.returncode, "wall": wall, "job": _summary_seconds(err),
            "killed_at": killed_at, "err": err[-1500:], **_check_job(files, cache, th, out)}


def _local_job(files: list[Path], cache: Path, th: Path, label: str, *extra: str) -> dict:
    """One local `asset-bake --thumbnails` in a fresh process."""
    cmd = [sys.executable, "-m", "cli.bake", "--cache", str(cache), "--thumbnails", str(th), "--size", "64",
           "--json", *extra, *map(str, files)]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - start
    return {"label": label, "code": proc.returncode, "wall": wall, "job": _summary_seconds(proc.stderr),
            "err": proc.stderr[-1500:], **_check_job(files, cache, th, proc.stdout)}


F3D_LIBRARY = """
import json, sys, time
start = time.perf_counter()
import f3d
job = json.load(sys.stdin)
f3d.Engine.autoload_plugins()
engine = f3d.Engine.create_egl()
engine.options["ui.loader_progress"] = False
engine.window.size = (job["size"], job["size"])
rows = []
for i, path in enumerate(job["files"]):
    t = time.perf_counter()
    try:
        engine.scene.clear()
        engine.scene.add(path)
        engine.window.camera.reset_to_bounds()
        engine.window.render_to_image().save(f"{job['out']}/{i:05d}.png")
        rows.append({"path": path, "ok": True, "seconds": time.perf_counter() - t})
    except Exception as exc:
        rows.append({"path": path, "ok": False, "error": str(exc)[:300], "seconds": time.perf_counter() - t})
with open(job["out"] + "/f3d.json", "w") as f:
    json.dump({"rows": rows, "in_process": time.perf_counter() - start}, f)
"""


def _f3d_library(files: list[Path], work: Path, size: int = 64) -> dict:
    """f3d rendering the library in ONE process (its Python module, EGL, its default look:
    no environment lighting), each file loaded, framed and written as a PNG."""
    out = work / "th-f3d"
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", F3D_LIBRARY], capture_output=True, text=True, timeout=3600,
                          input=json.dumps({"files": list(map(str, files)), "size": size, "out": str(out)}))
    wall = time.perf_counter() - start
    if proc.returncode or not (out / "f3d.json").is_file():
        return {"label": "f3d, 1 process", "code": proc.returncode or 1, "wall": wall, "err": proc.stderr[-1500:],
                "rendered": 0, "failed": len(files)}
    rows = json.loads((out / "f3d.json").read_text())["rows"]
    return {"label": "f3d, 1 process", "code": 0, "wall": wall, "rendered": sum(r["ok"] for r in rows),
            "failed": sum(not r["ok"] for r in rows), "errors": [r for r in rows if not r["ok"]][:3]}


def _run_cluster(args: argparse.Namespace, work: Path) -> int:
    work.mkdir(parents=True, exist_ok=True)
    samples = len(sample_files(args.assets))
    copies = args.copies if args.copies is not None else -(-CLUSTER_MIN_ASSETS // samples) - 1
    files = build_corpus(args.assets, work / "corpus", copies)
    cores = os.cpu_count() or 1
    print(f"library job on a loopback Ray cluster (head: 0 CPUs; worker nodes: 1 CPU each; token auth): "
          f"{len(files)} assets ({samples} samples + perturbed copies), --size 64 PNG thumbnails, each "
          f"rendered in the Ray task that baked it; {cores} cores on this machine, load before: "
          f"{os.getloadavg()[0]:.1f}")
    # 1 and 2 worker nodes --repeat times in rotating order (the cores are shared with other
    # work), then the lost node once; every run on a fresh cluster and an empty cache
    configs = [("1 worker node", 1), ("2 worker nodes", 2)]
    runs = []
    for round_ in range(args.repeat):
        for label, n in configs[round_ % 2:] + configs[:round_ % 2]:
            runs.append(_cluster_job(files, work / f"r{round_}", label, n, False))
            runs[-1]["load"] = os.getloadavg()[0]
    runs.append(_cluster_job(files, work / "kill", "2, one killed", 2, True))
    runs[-1]["load"] = os.getloadavg()[0]
    print(f"{'cluster':16} {'exit':>4} {'wall s':>7} {'job s':>6} {'assets/min':>10} {'killed at':>9} "
          f"{'exactly once':>12} {'rendered':>8} {'cached':>6} {'by':>3} {'entries':>7} {'thumbs':>6} "
          f"{'cache whole':>11} {'load':>5}")
    for r in runs:
        rate = 60 * len(files) / r["job"] if r["job"] else float("nan")
        print(f"{r['label']:16} {r['code']:4d} {r['wall']:7.1f} {r['job'] or 0:6.1f} {rate:10.1f} "
              f"{r['killed_at'] if r['killed_at'] is not None else '-':>9} {str(r['once']):>12} "
              f"{r['rendered']:8d} {r['cached']:6d} {r['renderers']:3d} {r['entries']:7d} {r['thumbs']:6d} "
              f"{str(r['whole']):>11} {r['load']:5.1f}")
        if r["code"]:
            print(r["err"], file=sys.stderr)
        for line in r["stray"]:
            print(f"  not a result line on stdout: {line[:300]!r}")
    for label, _ in configs:
        jobs = [r["job"] for r in runs if r["label"] == label and r["job"]]
        if jobs:
            print(f"median of {len(jobs)}, {label}: {60 * len(files) / statistics.median(jobs):.1f} assets/min")
    print("job s: asset-bake's own time after Ray connected (assets/min from it); wall: from the driver's "
          "start, cluster up; cached: rendered by the lost node, stored before it died, found by the "
          "retry; by: distinct Ray nodes that rendered; load: 1-min load average after the run")
    ok = all(r["code"] == 0 and r["once"] and r["whole"] and r["rendered"] + r["cached"] == len(files)
             and not r["stray"] for r in runs)

    # The peer: f3d in one process over the files it reads, against our local job on the same files.
    peer = [f for f in files if f.suffix.lower() in PEER_SUFFIXES]
    cache, th = work / "cache-ours", work / "th-ours"
    ours = _local_job(peer, cache, th, "ours, cold")
    shutil.rmtree(cache / "thumbnails")  # the bakes stay: the same job again renders only
    shutil.rmtree(th)
    warm = _local_job(peer, cache, th, "ours, bakes cached")
    theirs = _f3d_library(peer, work)
    print(f"\nlocal library job against f3d, one process each, {len(peer)} assets (the corpus less USD, "
          f"which f3d 4.0's wheel does not read), 64 px PNGs, cold (ours bakes too: an empty cache)")
    print(f"{'tool':18} {'exit':>4} {'wall s':>7} {'assets/min':>10} {'rendered':>8} {'failed':>6}")
    for r in (ours, warm, theirs):
        failed = r.get("failed", len(peer) - r["rendered"])
        print(f"{r['label']:18} {r['code']:4d} {r['wall']:7.1f} {60 * r['rendered'] / r['wall']:10.1f} "
              f"{r['rendered']:8d} {failed:6d}")
        if r["code"]:
            print(r["err"], file=sys.stderr)
    for e in theirs.get("errors", []):
        print(f"  f3d failed: {e['path']}: {e['error']}")
    print("wall: the process from its start (imports, GL context, every file) to its exit; ours: "
          "bake + render + manifest; f3d: load + render + PNG, its default look (no environment lighting)")
    ok = ok and all(r["code"] == 0 and r["once"] and r["rendered"] == len(peer) for r in (ours, warm))
    return 0 if ok else 1
