"""The service under hostile and heavy use, over real HTTP on loopback: malformed zips, path-free
messages, the access matrix, cost-aware fair scheduling, storage and memory bounds, a fuzz."""
from __future__ import annotations

import io
import json
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image
from service_server import ROOT, Server
from test_service import decode, nontrivial, textured_quad_gltf, zip_bytes

KEYS = ("alpha-key-1", "beta-key-2")
ALPHA = {"Authorization": f"Bearer {KEYS[0]}"}
BETA = {"Authorization": f"Bearer {KEYS[1]}"}
THUMB_BUDGET = 400_000
HOSTILE_ENV = {"ASSET_PREVIEW_API_KEY": ",".join(KEYS), "ASSET_PREVIEW_PUBLIC_READ": "true",
               "ASSET_PREVIEW_ALLOWED_HOSTS": "preview.example",
               "ASSET_PREVIEW_MAX_THUMBNAIL_BYTES": str(THUMB_BUDGET),
               "ASSET_PREVIEW_QUOTA_ASSETS": "3", "ASSET_PREVIEW_MAX_ARCHIVE_DEPTH": "16",
               "ASSET_PREVIEW_BAKE_WAIT_SECONDS": "60", "ASSET_PREVIEW_MAX_THUMBNAIL_SIZE": "4096",
               "ASSET_PREVIEW_MAX_RENDER_COST_MS": "10000"}


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """Two workers, two API keys, thumbnails readable without one, a small thumbnail budget."""
    srv = Server(tmp_path_factory.mktemp("hostile") / "cache", "--workers", "2", "--no-seed",
                 env=HOSTILE_ENV)
    srv.client.headers.update(ALPHA)
    try:
        srv.wait_ready()
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def duck(hostile, assets) -> str:
    r = hostile.client.post("/assets", files={"file": ("Duck.glb", (assets / "gltf/Duck.glb").read_bytes())})
    assert r.status_code in (200, 201), r.text
    assert hostile.wait_status(r.json()["id"])["status"] == "ready"
    return r.json()["id"]


def _zip_raw(entries: list[tuple[zipfile.ZipInfo | str, bytes]]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for info, data in entries:
            zf.writestr(info, data)
    return buf.getvalue()


def _flagged(name: str, data: bytes, *, flag_bits: int = 0, method: int | None = None) -> bytes:
    """A one-member zip whose member claims encryption or a compression method zipfile lacks."""
    raw = bytearray(_zip_raw([(name, data)]))
    for sig, flag_at, method_at in ((b"PK\x03\x04", 6, 8), (b"PK\x01\x02", 8, 10)):
        at = raw.find(sig)
        raw[at + flag_at] |= flag_bits
        if method is not None:
            raw[at + method_at:at + method_at + 2] = method.to_bytes(2, "little")
    return bytes(raw)


def _deflated(name: str, zeros: int) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(name, bytes(zeros))
    return buf.getvalue()


def test_malformed_zips_are_422_with_one_line_logs(hostile, assets):
    gltf = (assets / "gltf/rgb_cube_with_primitives.gltf").read_bytes()
    deep = "/".join(["d"] * 2000) + "/x.gltf"
    cases = {
        "file_and_folder.zip": _zip_raw([("a", b"1"), ("a/b.gltf", gltf)]),
        "long_name.zip": _zip_raw([("n" * 300 + ".gltf", gltf)]),
        "deep.zip": _zip_raw([(deep, gltf)]),
        "encrypted.zip": _flagged("a.gltf", gltf, flag_bits=0x1),
        "method99.zip": _flagged("a.gltf", gltf, method=99),
        "twice.zip": _zip_raw([("a.gltf", gltf), ("./a.gltf", gltf)]),
        "ratio.zip": _deflated("a.gltf", 24 * 2**20),  # 24 MiB from ~24 kB: never on disk
    }
    before = hostile.log.read_text()
    for name, data in cases.items():
        r = hostile.client.post("/assets", files={"file": (name, data)})
        assert r.status_code == 422, (name, r.status_code, r.text[:300])
        detail = r.json()["detail"]
        assert detail.startswith(name + ": ") and len(detail) < 400, detail
        assert "/tmp" not in detail and str(hostile.cache) not in detail
    log = hostile.log.read_text()[len(before):]
    assert "Traceback" not in log
    refused = [line for line in log.splitlines() if "refused" in line]
    assert len(refused) == len(cases), refused
    assert all(len(line) < 600 for line in refused)
    assert "size" in hostile.client.post("/assets", files={"file": ("ratio.zip", cases["ratio.zip"])}).json()["detail"]
    assert not list((hostile.cache / "service" / "tmp").iterdir())  # staging cleaned up


def test_messages_name_the_users_files_never_server_paths(hostile):
    doc = json.loads(textured_quad_gltf(8, 8))
    doc["images"] = [{"uri": "../../../../etc/secret.png"}]
    for name, data, shown in (("escape.gltf", json.dumps(doc).encode(), "escape.gltf"),
                              ("pack.zip", zip_bytes({"scene/a.gltf": json.dumps(doc).encode()}), "scene/a.gltf")):
        r = hostile.client.post("/assets", files={"file": (name, data)})
        text = r.text
        assert str(hostile.cache) not in text and "/service/" not in text and "/tmp/" not in text, text
        if r.status_code == 201:  # the reference is dropped with a warning naming it
            warnings = " ".join(r.json()["warnings"])
            assert "secret.png" in warnings and str(hostile.cache) not in warnings
            # the surface that asked: the upload and its files, not the CLI's --sandbox flag
            assert "--sandbox" not in warnings and "leaves the upload" in warnings, warnings
            hostile.client.delete(f"/assets/{r.json()['id']}")
        else:
            # named as uploaded: the file itself, or its path inside the zip
            assert r.status_code == 422 and r.json()["detail"].startswith(shown + ": "), text
            assert "secret.png" in text and "--sandbox" not in text and "the upload" in text, text


def test_unreferenced_zip_members_are_dropped(hostile, assets):
    files = {n: (assets / "gltf" / n).read_bytes() for n in ("TestScene.gltf", "TestScene.bin")}
    files |= {"readme.txt": b"notes " * 1000, "unused/big.bin": bytes(200_000)}
    r = hostile.client.post("/assets", files={"file": ("TestScene.zip", zip_bytes(files))})
    assert r.status_code == 201, r.text
    asset_id = r.json()["id"]
    src = hostile.cache / "service" / "assets" / asset_id / "src"
    kept = sorted(p.relative_to(src).as_posix() for p in src.rglob("*") if p.is_file())
    assert kept == ["TestScene.bin", "TestScene.gltf"], kept
    assert hostile.wait_status(asset_id)["status"] == "ready"
    assert hostile.client.delete(f"/assets/{asset_id}").status_code == 200


def test_access_matrix(hostile, duck):
    anon = httpx.Client(base_url=hostile.url, timeout=60)
    reads = ["/assets", f"/assets/{duck}", f"/assets/{duck}/thumbnail?size=32", "/environments", "/"]
    for path in reads:  # --public-read: reads need no key
        assert anon.get(path).status_code == 200, path
    for path in ("/healthz", "/readyz", "/metrics"):
        assert anon.get(path).status_code == 200, path
    writes = [("POST", "/assets"), ("DELETE", f"/assets/{duck}"), ("POST", "/environments")]
    for method, path in writes:
        for headers in ({}, {"Authorization": "Bearer nope"}, {"Authorization": f"Basic {KEYS[0]}"}):
            r = anon.request(method, path, headers=headers, files={"file": ("x.png", b"x")} if method == "POST" else None)
            assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", (method, path, headers)
    # With a key: another site's page cannot write through the browser (Origin), and a
    # rebound DNS name cannot reach the service at all (Host).
    port = hostile.url.rsplit(":", 1)[1]
    for origin, expect in (("https://evil.example", 403), ("null", 403), (hostile.url, 415),
                           (f"http://preview.example:{port}", 415), (f"http://localhost:{port}", 415),
                           ("http://localhost:3000", 403),  # another local page on another port
                           (f"https://127.0.0.1:{port}", 403), ("http://preview.example", 403),
                           (f"http://127.0.0.1:{port}.evil.com", 403), (f"http://127.0.0.1:{port}/x", 403)):
        r = anon.post("/assets", headers={**ALPHA, "Origin": origin}, files={"file": ("x.txt", b"x")})
        assert r.status_code == expect, (origin, r.status_code, r.text)
    for host, expect in (("evil.example", 421), (f"preview.example:{port}", 200), (f"localhost:{port}", 200),
                         ("preview.example", 421),  # no port: 80, not this server's
                         ("localhost:1", 421), (f"127.0.0.1:{port}.evil.com", 421), ("localhost:evil.com", 421),
                         (f"[::1]:{port}", 200), (f"127.0.0.1:{port}:{port}", 421), ("", 421)):
        assert anon.get("/assets", headers={"Host": host}).status_code == expect, host
    assert anon.get("/healthz", headers={"Host": "10.1.2.3:80"}).status_code == 200  # probes
    r = anon.get("/")
    assert "frame-ancestors 'none'" in r.headers["content-security-policy"]
    assert r.headers["x-content-type-options"] == "nosniff" and r.headers["x-frame-options"] == "DENY"
    r = anon.get(f"/assets/{duck}/thumbnail?size=32")
    assert r.headers["x-content-type-options"] == "nosniff" and "default-src 'none'" in r.headers["content-security-policy"]
    log = hostile.log.read_text()
    assert not [k for k in KEYS if k in log], "keys are never logged"
    anon.close()


def test_reads_without_a_key_cannot_buy_renders(hostile, duck):
    """--public-read: a read without a key renders up to the default thumbnail's estimated cost;
    beyond, 401 naming why, until someone with a key has rendered it (then it is served)."""
    anon = httpx.Client(base_url=hostile.url, timeout=120)
    url = f"/assets/{duck}/thumbnail"
    assert anon.get(url, params={"size": 200, "yaw": 7}).status_code == 200  # under the default's cost
    big = {"size": 160, "method": "raytrace", "bounces": 1, "yaw": 11}
    r = anon.get(url, params=big)
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", r.text
    assert "without an API key" in r.json()["detail"] and "estimated cost" in r.json()["detail"]
    assert anon.head(url, params=big).status_code == 401
    keyed = hostile.client.get(url, params=big)
    assert keyed.status_code == 200, keyed.text
    again = anon.get(url, params=big)  # cached now: served to anyone who may read
    assert again.status_code == 200 and again.content == keyed.content
    anon.close()


def test_no_key_refuses_a_public_address(tmp_path):
    cmd = [sys.executable, "-m", "cli.main", "serve", "--host", "0.0.0.0", "--port", "0",
           "--cache", str(tmp_path / "c"), "--no-seed"]
    env = {"PATH": "/usr/bin:/bin"}
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--insecure-no-auth" in r.stderr and "API key" in r.stderr
    assert not (tmp_path / "c").exists()


def test_cost_ceiling_and_budget_cap(hostile, duck):
    for params in ({"size": 4096, "method": "wyman"}, {"size": 2048, "method": "raytrace"}):
        r = hostile.client.get(f"/assets/{duck}/thumbnail", params=params)
        assert r.status_code == 422, r.text
        assert "ceiling of 10000 ms" in r.json()["detail"], r.text
    # A budget past the ceiling (and 0.8 x the deadline) is capped, not refused; the capped
    # request is cached under what actually ran, so both spellings are one thumbnail.
    r = hostile.client.get(f"/assets/{duck}/thumbnail", params={"size": 32, "budget_ms": 60000})
    assert r.status_code == 200, r.text
    again = hostile.client.get(f"/assets/{duck}/thumbnail", params={"size": 32, "budget_ms": 10000})
    assert again.headers["etag"] == r.headers["etag"]
    assert hostile.client.get(f"/assets/{duck}/thumbnail", params={"size": 32, "method": "raytrace",
                                                                    "bounces": 1}).status_code == 200
    # 16 x 16 rays a pixel at 24 bounces cost ~85 times the default 3 x 3 at 8 (the fitted model,
    # renderer.methods.auto.rt_ms): refused where the default passes
    ask = {"size": 256, "method": "raytrace", "bounces": 8}
    assert hostile.client.get(f"/assets/{duck}/thumbnail", params=ask).status_code == 200
    r = hostile.client.get(f"/assets/{duck}/thumbnail", params={**ask, "supersample": 16, "bounces": 24})
    assert r.status_code == 422 and "ceiling" in r.json()["detail"], r.text


def test_cheap_thumbnail_is_not_queued_behind_expensive_renders(hostile, duck):
    """Two maximum-cost renders (2048 px glass, the longest budget) are asked for first; a 64 px
    thumbnail asked for while they run finishes before both (ordering, not milliseconds)."""
    done: dict[str, float] = {}
    results: dict[str, int] = {}

    def get(tag: str, params: dict):
        with httpx.Client(base_url=hostile.url, timeout=300, headers=ALPHA) as c:
            r = c.get(f"/assets/{duck}/thumbnail", params=params)
        results[tag] = r.status_code
        done[tag] = time.monotonic()

    expensive = {"size": 2048, "transmission": 1, "ior": 2.5, "budget_ms": 60000}
    threads = [threading.Thread(target=get, args=(f"e{i}", dict(expensive, yaw=91 + i))) for i in range(2)]
    for t in threads:
        t.start()
        time.sleep(0.2)
    end = time.monotonic() + 60
    while time.monotonic() < end and not any(w["op"] == "render" for w in hostile.client.get("/readyz").json()["workers"]):
        time.sleep(0.02)
    get("cheap", {"size": 64, "yaw": 93})
    for t in threads:
        t.join(300)
    assert results == {"e0": 200, "e1": 200, "cheap": 200}, results
    assert done["cheap"] < done["e0"] and done["cheap"] < done["e1"], done


def _disk_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) if folder.exists() else 0


# The budget is sized for thumbnails with a photographed panorama behind them (the default
# studio light and gradient backdrop compress to a fraction of that).
PANORAMA = {"env": "footprint_court", "background": "env"}


def test_thumbnail_disk_budget_evicts_least_recently_used(hostile, duck):
    thumbs = hostile.cache / "service" / "thumbs"
    first = hostile.client.get(f"/assets/{duck}/thumbnail", params={"size": 200, "yaw": 0, **PANORAMA})
    assert first.status_code == 200
    for yaw in range(5, 5 + 5 * 14, 5):
        assert hostile.client.get(f"/assets/{duck}/thumbnail", params={
            "size": 200, "yaw": yaw, **PANORAMA}).status_code == 200
        time.sleep(0.05)
    time.sleep(1.0)  # the disk copies are written off the request path
    assert 0 < _disk_bytes(thumbs) <= THUMB_BUDGET, _disk_bytes(thumbs)
    newest = list((thumbs / duck).glob("*.png"))
    assert newest and len(newest) < 15


def test_delete_frees_bake_and_thumbnails(hostile, assets):
    r = hostile.client.post("/assets", headers=BETA,
                            files={"file": ("BoxTextured.glb", (assets / "gltf/BoxTextured.glb").read_bytes())})
    assert r.status_code in (200, 201), r.text
    asset_id = r.json()["id"]
    assert hostile.wait_status(asset_id)["status"] == "ready"
    assert hostile.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 64}).status_code == 200
    thumbs = hostile.cache / "service/thumbs" / asset_id
    end = time.monotonic() + 60  # the disk copy is written off the request path
    while time.monotonic() < end and not list(thumbs.glob("*.png")):
        time.sleep(0.05)
    record = json.loads((hostile.cache / "service/assets" / asset_id / "record.json").read_text())
    bake = hostile.cache / "assets" / record["bake_key"]
    pieces = [bake, hostile.cache / "service/thumbs" / asset_id, hostile.cache / "service/assets" / asset_id]
    sizes = [_disk_bytes(p) for p in pieces]
    assert all(sizes), sizes
    total = _disk_bytes(hostile.cache)
    assert hostile.client.delete(f"/assets/{asset_id}", headers=BETA).status_code == 200
    assert [p.exists() for p in pieces] == [False, False, False]
    assert _disk_bytes(hostile.cache) <= total - sum(sizes)


def test_quota_per_key(hostile, assets):
    made = []
    for i in range(3):
        r = hostile.client.post("/assets", headers=BETA, files={"file": (f"q{i}.gltf", textured_quad_gltf(8 + i, 8))})
        assert r.status_code == 201, r.text
        made.append(r.json()["id"])
    r = hostile.client.post("/assets", headers=BETA, files={"file": ("q3.gltf", textured_quad_gltf(12, 8))})
    assert r.status_code == 413 and "quota of 3" in r.json()["detail"], r.text
    # Another key is not charged for beta's assets.
    r = hostile.client.post("/assets", headers=ALPHA, files={"file": ("a.gltf", textured_quad_gltf(13, 8))})
    assert r.status_code == 201, r.text
    made.append(r.json()["id"])
    for asset_id in made:
        hostile.wait_status(asset_id)
        hostile.client.delete(f"/assets/{asset_id}")
    r = hostile.client.post("/assets", headers=BETA, files={"file": ("q3.gltf", textured_quad_gltf(12, 8))})
    assert r.status_code == 201  # deleting frees the quota
    hostile.wait_status(r.json()["id"])
    hostile.client.delete(f"/assets/{r.json()['id']}")


def test_fuzz_the_api_from_its_openapi_schema(hostile, duck):
    """Schemathesis generates requests for every operation from /openapi.json; none may answer
    500 or break the schema. Bounded: a few examples per operation, no shrinking deadline."""
    import schemathesis
    from hypothesis import HealthCheck, given, settings
    from schemathesis.checks import (
        content_type_conformance,
        not_a_server_error,
        response_schema_conformance,
        status_code_conformance,
    )

    spec = hostile.client.get("/openapi.json").json()
    schema = schemathesis.openapi.from_dict(spec)
    checks = [not_a_server_error, status_code_conformance, content_type_conformance,
              response_schema_conformance]
    seen = []
    for result in schema.get_all_operations():
        operation = result.ok()
        if operation.method.upper() == "DELETE":
            continue  # deleting the fixture's asset would starve the other operations; 404s are tested

        @settings(max_examples=12, deadline=None, derandomize=True, database=None,
                  suppress_health_check=list(HealthCheck))
        @given(case=operation.as_strategy())
        def run(case):
            if "asset_id" in (case.path_parameters or {}) and len(seen) % 2 == 0:
                case.path_parameters["asset_id"] = duck  # half the cases reach a real asset
            if case.query and "size" in case.query:  # keep renders thumbnail-sized
                case.query["size"] = min(int(case.query["size"]) if str(case.query["size"]).isdigit() else 64, 64)
            seen.append(case.operation.label)
            case.call_and_validate(base_url=hostile.url, headers=dict(ALPHA), checks=checks, timeout=120)

        run()
    print("fuzz:", len(seen), "cases over", sorted(set(seen)))
    assert len(set(seen)) >= 6, set(seen)


# ---------------------------------------------------------------------------------------------
# Memory by bytes: a worker with tight caches renders 20 distinct heavy assets


WORKER_CACHE = 48 * 2**20
GPU_BUDGET = 48 * 2**20
OVERHEAD = 200 * 2**20  # above the warm worker's RSS: allocator slack, encoder and frame buffers


def heavy_asset(i: int, size: int = 1024) -> bytes:
    """A quad with three distinct size x size textures (PNG; decoded 4 MB each)."""
    import base64
    doc = json.loads(textured_quad_gltf(4, 4))
    images = []
    y, x = np.mgrid[0:size, 0:size]
    for k in range(3):
        rgb = np.stack([(x * (i + 1) + k * 50) % 256, (y * (k + 2) + i * 7) % 256, (x ^ y) % 256], -1)
        buf = io.BytesIO()
        Image.fromarray(rgb.astype(np.uint8)).save(buf, "PNG", compress_level=1)
        images.append({"uri": "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()})
    doc["images"] = images
    doc["textures"] = [{"source": k} for k in range(3)]
    doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                  "metallicRoughnessTexture": {"index": 1}},
                         "normalTexture": {"index": 2}}]
    return json.dumps(doc).encode()


def _rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


@pytest.mark.slow
def test_worker_memory_stays_bounded_over_20_heavy_assets(tmp_path):
    env = {"ASSET_PREVIEW_WORKER_CACHE_BYTES": str(WORKER_CACHE), "ASSET_PREVIEW_GPU_BYTES": str(GPU_BUDGET),
           "ASSET_PREVIEW_CACHE_MAX_BYTES": str(120 * 2**20), "ASSET_PREVIEW_BAKE_WAIT_SECONDS": "120"}
    srv = Server(tmp_path / "cache", "--workers", "1", "--no-seed", env=env)
    try:
        srv.wait_ready()
        pid = srv.client.get("/readyz").json()["workers"][0]["pid"]
        warm = _rss(pid)
        ids = []
        for i in range(20):
            r = srv.client.post("/assets", files={"file": (f"heavy{i}.gltf", heavy_asset(i))})
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
            assert srv.wait_status(ids[-1], timeout=300)["status"] == "ready"
            t = srv.client.get(f"/assets/{ids[-1]}/thumbnail", params={"size": 512})
            assert t.status_code == 200 and nontrivial(decode(t.content))
        peak = _rss(pid)
        assert peak <= warm + WORKER_CACHE + GPU_BUDGET + OVERHEAD, (warm / 2**20, peak / 2**20)
        # The bake cache stayed under its budget (plus the entry being written), and an
        # evicted asset is baked again on demand.
        assert _disk_bytes(tmp_path / "cache" / "assets") <= 120 * 2**20 + 20 * 2**20
        r = srv.client.get(f"/assets/{ids[0]}/thumbnail", params={"size": 96})
        assert r.status_code == 200, r.text
    finally:
        srv.stop()
