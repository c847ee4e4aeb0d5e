"""Thumbnail service under load: cached thumbnails, warm renders, cold uploads, over HTTP.

Starts `asset-preview serve` on a free loopback port with a fresh cache, then drives it for a
bounded time per phase with `wrk` when it is installed (C, one thread, a Lua script for
per-request URLs and exact percentiles) or else an asyncio httpx client (which saturates
sooner: the client shares the CPU and is itself Python). Peers, measured in the same run:

- cached: a bare Starlette app on the same uvicorn returning the same image bytes from
  memory: the floor of this HTTP stack, so the ratio is what our routing, validation, cache
  lookup and metrics cost;
- warm render: the same render called in-process (`renderer.raster.render` + encode, warm), one
  request at a time interleaved with ours, so the difference is HTTP, the worker pipe and the
  cache write (the warm-render throughput row is `workers` concurrent clients);
- cold upload: the same work in-process (`load_scene` + `bake_asset` + first render),
  interleaved with ours;
- under render load: cached thumbnails again, and the bare Starlette floor, while two clients
  keep 1024 px glass renders running; then 64 px cache-miss renders while two clients keep
  maximum-cost renders (2048 px glass, the longest budget) running, beside the same 64 px
  renders on the idle server (the scheduler's cheap lane: they should barely notice).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.assets import ASSETS

ROOT = Path(__file__).resolve().parents[1]

ROUNDS = 2  # alternating rounds of ours and the peer in the cached phase

_WRK_SCRIPT = """
counter = 0
request = function()
  if vary then
    counter = counter + 1
    return wrk.format("GET", wrk.path .. "&yaw=" .. string.format("%.2f", 0.01 * counter))
  end
  return wrk.format("GET", wrk.path)
end
done = function(summary, latency, requests)
  local bad = summary.errors.status + summary.errors.connect + summary.errors.read
            + summary.errors.write + summary.errors.timeout
  io.write(string.format("RESULT %d %d %d %d %d\\n", latency:percentile(50), latency:percentile(99),
                         summary.requests, summary.duration, bad))
end
"""

_PEER_APP = """
import sys, uvicorn
from starlette.applications import Starlette
from starlette.responses import Response
from starlette.routing import Route
data = open(sys.argv[1], "rb").read()
async def image(request):
    return Response(data, media_type="image/png", headers={"ETag": '"x"', "Cache-Control": "max-age=60"})
app = Starlette(routes=[Route("/image", image)])
uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[2]), log_level="warning", access_log=False)
"""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=8.0, help="seconds per load phase")
    parser.add_argument("--connections", type=int, default=16, help="concurrent clients (throughput)")
    parser.add_argument("--workers", type=int, default=2, help="render worker processes")
    parser.add_argument("--size", type=int, default=256, help="thumbnail size in pixels")
    parser.add_argument("--uploads", type=int, default=8, help="cold uploads to time")
    parser.add_argument("--tool", choices=["auto", "wrk", "httpx"], default="auto",
                        help="load generator (auto: wrk when installed)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON too")


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_http(url: str, timeout: float = 300) -> None:
    import httpx
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            if httpx.get(url, timeout=5).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"{url} did not answer within {timeout} s")


class Load:
    """Drive one URL (optionally a fresh yaw per request) and return (p50 ms, p99 ms, req/s, bad)."""

    def __init__(self, tool: str):
        self.tool = "wrk" if tool == "wrk" or (tool == "auto" and shutil.which("wrk")) else "httpx"
        if tool == "wrk" and not shutil.which("wrk"):
            raise SystemExit("wrk is not installed (apt-get install -y wrk)")
        self._script: str | None = None

    def __call__(self, url: str, connections: int, duration: float, vary: bool = False):
        if self.tool == "wrk":
            return self._wrk(url, connections, duration, vary)
        return asyncio.run(self._httpx(url, connections, duration, vary))

    def _wrk(self, url, connections, duration, vary):
        if self._script is None:
            fd, self._script = tempfile.mkstemp(suffix=".lua")
            os.write(fd, _WRK_SCRIPT.encode())
            os.close(fd)
        script: str = self._script
        if vary:
            fd, script = tempfile.mkstemp(suffix=".lua")
            os.write(fd, b"vary = true\n" + _WRK_SCRIPT.encode())
            os.close(fd)
        out = subprocess.run(["wrk", "-t1", f"-c{connections}", f"-d{max(1, round(duration))}s",
                              "--timeout", "60s", "-s", script, url],
                             capture_output=True, text=True, check=True).stdout
        line = next(row for row in out.splitlines() if row.startswith("RESULT"))
        p50, p99, n, dur_us, bad = (int(x) for x in line.split()[1:])
        return p50 / 1000, p99 / 1000, n / (dur_us / 1e6), bad

    async def _httpx(self, url, connections, duration, vary):
        import httpx
        latencies: list[float] = []
        bad = 0
        counter = 0
        end = time.perf_counter() + duration
        limits = httpx.Limits(max_connections=connections, max_keepalive_connections=connections)
        async with httpx.AsyncClient(limits=limits, timeout=60) as client:
            async def one_client():
                nonlocal bad, counter
                while time.perf_counter() < end:
                    counter += 1
                    target = f"{url}&yaw={0.01 * counter:.2f}" if vary else url
                    t0 = time.perf_counter()
                    r = await client.get(target)
                    latencies.append(time.perf_counter() - t0)
                    bad += r.status_code != 200
            start = time.perf_counter()
            await asyncio.gather(*(one_client() for _ in range(connections)))
            elapsed = time.perf_counter() - start
        q = statistics.quantiles(latencies, n=100) if len(latencies) > 1 else latencies * 99
        return 1000 * statistics.median(latencies), 1000 * q[98], len(latencies) / elapsed, bad


def _distinct_glb(data: bytes, n: int) -> bytes:
    """The same GLB with 4*n spaces padding its JSON chunk: valid, and different bytes (so a
    new asset id and a real upload, ingest and bake each time)."""
    json_len = struct.unpack_from("<I", data, 12)[0]
    pad = b" " * (4 * n)
    body = data[20:20 + json_len] + pad
    rest = data[20 + json_len:]
    header = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(body) + len(rest))
    return header + struct.pack("<I4s", len(body), b"JSON") + body + rest


class Background:
    """`clients` threads asking for fresh (cache-miss) renders of `url` until stopped."""

    def __init__(self, url: str, clients: int):
        import threading
        self.url, self.stop_flag, self.done = url, threading.Event(), 0
        self.threads = [threading.Thread(target=self._loop, args=(i,), daemon=True) for i in range(clients)]
        for t in self.threads:
            t.start()

    def _loop(self, i: int) -> None:
        import httpx
        n = 0
        with httpx.Client(timeout=300) as c:
            while not self.stop_flag.is_set():
                n += 1
                c.get(f"{self.url}&yaw={100 + i * 1000 + n * 0.37:.2f}")
                self.done += 1

    def stop(self) -> None:
        self.stop_flag.set()
        for t in self.threads:
            t.join(300)


def _cheap_renders(client, url: str, seconds: float, start: float) -> list[float]:
    """Sequential fresh 64 px renders for `seconds` (at least 8): latencies in ms."""
    out: list[float] = []
    end = time.perf_counter() + seconds
    i = 0
    while time.perf_counter() < end or len(out) < 8:
        i += 1
        t0 = time.perf_counter()
        r = client.get(f"{url}&yaw={start + 0.01 * i:.2f}")
        out.append(1000 * (time.perf_counter() - t0))
        assert r.status_code == 200, r.text
    return out


def _stats(values: list[float]) -> tuple[float, float]:
    values = sorted(values)
    return statistics.median(values), values[min(len(values) - 1, round(0.99 * (len(values) - 1)))]


def run(args: argparse.Namespace) -> int:
    import httpx

    duck_bytes = (ASSETS / "gltf" / "Duck.glb").read_bytes()
    load = Load(args.tool)
    tmp = Path(tempfile.mkdtemp(prefix="bench-service-"))
    port, peer_port = free_port(), free_port()
    base = f"http://127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("ASSET_PREVIEW_")}
    log_path = tmp / "server.log"
    log_file = open(log_path, "wb")
    server = subprocess.Popen([sys.executable, "-m", "cli.main", "serve", "--port", str(port),
                               "--cache", str(tmp / "cache"), "--workers", str(args.workers),
                               "--no-seed", "--log-level", "warning"],
                              cwd=ROOT, env=env, stdout=log_file, stderr=subprocess.STDOUT)
    peer = None
    rows: list[tuple] = []
    try:
        try:
            wait_http(f"{base}/readyz")
        except TimeoutError:
            print(log_path.read_text()[-3000:], file=sys.stderr)
            raise
        client = httpx.Client(base_url=base, timeout=120)
        asset_id = client.post("/assets", files={"file": ("Duck.glb", duck_bytes)}).json()["id"]
        thumb = f"{base}/assets/{asset_id}/thumbnail?size={args.size}"
        first = client.get(thumb)  # waits for the bake, renders, caches
        assert first.status_code == 200, first.text
        png = tmp / "thumb.png"
        png.write_bytes(first.content)

        # 1. Cached thumbnails, and the bare-Starlette floor serving the same bytes. The two
        #    alternate in rounds so that both see the same load on the shared CPU.
        peer = subprocess.Popen([sys.executable, "-c", _PEER_APP, str(png), str(peer_port)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_http(f"http://127.0.0.1:{peer_port}/image")
        targets = {"cached thumbnail": thumb,
                   "peer: bare Starlette, same bytes": f"http://127.0.0.1:{peer_port}/image?size=256"}
        rounds: dict[str, list[tuple]] = {label: [] for label in targets}
        for _ in range(ROUNDS):
            for label, url in targets.items():
                p50, p99, _, bad1 = load(url, 1, args.duration / (2 * ROUNDS))
                _, _, rps, bad2 = load(url, args.connections, args.duration / (2 * ROUNDS))
                rounds[label].append((p50, p99, rps, bad1 + bad2))
        for label, runs in rounds.items():
            med = [statistics.median(r[i] for r in runs) for i in range(3)]
            rows.append((label, 1, *med, args.connections, sum(r[3] for r in runs)))
        peer.terminate()
        peer.wait()
        peer = None

        # 2. Warm renders: every request a new yaw (a cache miss) of the baked, uploaded Duck.
        #    Latency: one request at a time, interleaved with the same render in this process;
        #    throughput: `workers` clients at once.
        local = InProcess(duck_bytes, tmp / "inproc", args.size)
        for i in range(2 * args.workers):  # every worker has the asset and environment on its GPU
            client.get(thumb + f"&yaw={-1 - i}")
        http_ms: list[float] = []
        local_ms: list[float] = []
        end = time.perf_counter() + args.duration
        i = 0
        while time.perf_counter() < end or len(http_ms) < 10:
            i += 1
            t0 = time.perf_counter()
            r = client.get(thumb + f"&yaw={0.01 * i:.2f}&pitch=16")
            http_ms.append(1000 * (time.perf_counter() - t0))
            assert r.status_code == 200, r.text
            local_ms.append(local.warm(0.01 * i))
        _, _, rps, bad = load(thumb + "&pitch=14", args.workers, args.duration, vary=True)
        rows.append((f"warm render {args.size} px", 1, *_stats(http_ms), rps, args.workers, bad))
        rows.append(("peer: in-process render+encode", 1, *_stats(local_ms),
                     1000 / statistics.median(local_ms), 1, 0))

        # 3. Cold uploads: new bytes each time -> POST (ingest) and first thumbnail (bake+render),
        #    interleaved with the same work in this process.
        post_ms, first_ms, cold_ms = [], [], []
        for n in range(1, args.uploads + 1):
            data = _distinct_glb(duck_bytes, n)
            t0 = time.perf_counter()
            r = client.post("/assets", files={"file": (f"duck{n}.glb", data)})
            t1 = time.perf_counter()
            assert r.status_code == 201, r.text
            img = client.get(f"/assets/{r.json()['id']}/thumbnail", params={"size": args.size})
            t2 = time.perf_counter()
            assert img.status_code == 200, img.text
            post_ms.append(1000 * (t1 - t0))
            first_ms.append(1000 * (t2 - t0))
            cold_ms.append(local.cold(_distinct_glb(duck_bytes, 1000 + n)))
        rows.append(("cold upload: POST -> 201", 1, *_stats(post_ms), 1000 / statistics.median(post_ms), 1, 0))
        rows.append(("cold upload -> first thumbnail", 1, *_stats(first_ms),
                     1000 / statistics.median(first_ms), 1, 0))
        rows.append(("peer: in-process ingest+bake+render", 1, *_stats(cold_ms),
                     1000 / statistics.median(cold_ms), 1, 0))

        # 4. Under render load. Cached thumbnails (and the bare floor) while 1024 px glass
        #    renders keep the workers busy; then cheap renders while maximum-cost ones run.
        peer = subprocess.Popen([sys.executable, "-c", _PEER_APP, str(png), str(peer_port)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_http(f"http://127.0.0.1:{peer_port}/image")
        busy = Background(f"{base}/assets/{asset_id}/thumbnail?size=1024&transmission=1", 2)
        loaded = {"cached thumbnail, 1024 px renders running": thumb,
                  "peer: bare Starlette, renders running": f"http://127.0.0.1:{peer_port}/image?size=256"}
        rounds = {label: [] for label in loaded}
        for _ in range(ROUNDS):
            for label, url in loaded.items():
                p50, p99, _, bad1 = load(url, 1, args.duration / (2 * ROUNDS))
                _, _, rps, bad2 = load(url, args.connections, args.duration / (2 * ROUNDS))
                rounds[label].append((p50, p99, rps, bad1 + bad2))
        busy.stop()
        peer.terminate()
        peer.wait()
        peer = None
        for label, runs in rounds.items():
            med = [statistics.median(r[i] for r in runs) for i in range(3)]
            rows.append((label, 1, *med, args.connections, sum(r[3] for r in runs)))
        cheap = f"{base}/assets/{asset_id}/thumbnail?size=64"
        idle_ms = _cheap_renders(client, cheap, args.duration / 2, 500)
        heavy = Background(f"{base}/assets/{asset_id}/thumbnail?size=2048&transmission=1&ior=2.5"
                           "&budget_ms=60000", 2)
        time.sleep(1.0)  # both are queued or running
        loaded_ms = _cheap_renders(client, cheap, args.duration, 600)
        heavy.stop()
        rows.append(("64 px render, 2 max-cost renders running", 1, *_stats(loaded_ms),
                     1000 / statistics.median(loaded_ms), 1, 0))
        rows.append(("peer: 64 px render, idle server", 1, *_stats(idle_ms),
                     1000 / statistics.median(idle_ms), 1, 0))
        client.close()
    finally:
        if peer is not None:
            peer.terminate()
        server.terminate()
        server.wait(timeout=30)
        log_file.close()
    shutil.rmtree(tmp, ignore_errors=True)
    _print(rows, load.tool, args)
    return 0


class InProcess:
    """The service's work done directly in this process (warm: one GL context, kept)."""

    def __init__(self, duck_bytes: bytes, folder: Path, size: int):
        from pipeline.bake import bake_asset, bake_environment
        folder.mkdir(parents=True)
        self.folder, self.size, self.cache = folder, size, folder / "cache"
        self.env = bake_environment("footprint_court", self.cache)
        path = folder / "Duck.glb"
        path.write_bytes(duck_bytes)
        self.asset = bake_asset(path, self.cache)
        for yaw in (-1, -2):
            self.warm(yaw)

    def _render(self, asset, yaw: float) -> bytes:
        import renderer
        from core.options import RenderOptions
        opts = RenderOptions(width=self.size, height=self.size, yaw=yaw, pitch=15)
        return renderer.render(asset, self.env, opts).encode("png")

    def warm(self, yaw: float) -> float:
        t0 = time.perf_counter()
        self._render(self.asset, yaw)
        return 1000 * (time.perf_counter() - t0)

    def cold(self, data: bytes) -> float:
        from pipeline.bake import bake_asset
        from pipeline.ingest import load_scene
        path = self.folder / f"{time.monotonic_ns()}.glb"
        path.write_bytes(data)
        t0 = time.perf_counter()
        load_scene(path)
        self._render(bake_asset(path, self.cache), 30)
        return 1000 * (time.perf_counter() - t0)


def _print(rows, tool: str, args) -> None:
    print(f"asset-preview bench service  (load: {tool}, {os.cpu_count()} CPUs, "
          f"{args.workers} render workers, Duck.glb at {args.size} px)")
    print(f"{'phase':44} {'p50 ms':>8} {'p99 ms':>8} {'req/s':>9}  (latency at 1 client, req/s at N clients)")
    for label, _, p50, p99, rps, conns, bad in rows:
        print(f"{label:44} {p50:8.2f} {p99:8.2f} {rps:9.1f}  N={conns}" + (f"  ({bad} failed)" if bad else ""))
    by = {r[0]: r for r in rows}
    cached, floor = by["cached thumbnail"], by["peer: bare Starlette, same bytes"]
    warm = by[f"warm render {args.size} px"]
    inproc = by["peer: in-process render+encode"]
    print(f"cached vs bare Starlette: p50 x{cached[2] / floor[2]:.2f}, req/s x{cached[4] / floor[4]:.2f}")
    print(f"warm render over HTTP vs in-process: p50 x{warm[2] / inproc[2]:.2f} "
          f"(+{warm[2] - inproc[2]:.1f} ms for HTTP, worker pipe and cache write)")
    if "cached thumbnail, 1024 px renders running" in by:
        busy, bare = by["cached thumbnail, 1024 px renders running"], by["peer: bare Starlette, renders running"]
        cheap, idle = by["64 px render, 2 max-cost renders running"], by["peer: 64 px render, idle server"]
        print(f"renders running: cached p50 {busy[2]:.2f} ms / p99 {busy[3]:.2f} ms, {busy[4]:.0f} req/s "
              f"(bare Starlette {bare[2]:.2f} / {bare[3]:.2f} ms, {bare[4]:.0f} req/s); "
              f"64 px p99 {cheap[3]:.0f} ms under max-cost load vs {idle[3]:.0f} ms idle")
    print(f"targets: cached p50 <= 2 ms: {cached[2]:.2f} ms; cached >= 1000 req/s: {cached[4]:.0f}; "
          f"warm {args.size} px p50 <= 30 ms: {warm[2]:.1f} ms")
    if args.json:
        print(json.dumps([dict(zip(("phase", "clients_latency", "p50_ms", "p99_ms", "req_s",
                                    "clients_throughput", "bad"), r)) for r in rows]))
