"""The thumbnail service over real HTTP: a uvicorn server process with render workers."""
from __future__ import annotations

import io
import json
import os
import re
import signal
import threading
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest
from PIL import Image
from service_server import MAX_QUEUE, UNPACKED_LIMIT, UPLOAD_LIMIT, Server

# `server` (conftest.py): the session's shared service, SERVER_ENV in service_server.py.


def zip_bytes(files: dict[str, bytes], links: dict[str, str] | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in files.items():
            zf.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = 0o120777 << 16  # a symbolic link
            zf.writestr(info, target)
    return buf.getvalue()


def folder_zip(folder, main_dir: str = "") -> bytes:
    return zip_bytes({(main_dir + p.relative_to(folder).as_posix()): p.read_bytes()
                      for p in sorted(folder.rglob("*")) if p.is_file()
                      and p.suffix.lower() in (".usd", ".usda", ".png", ".jpg", ".gltf", ".bin")})


def upload(srv: Server, name: str, data: bytes, headers=None, **form) -> httpx.Response:
    return srv.client.post("/assets", files={"file": (name, data)}, data=form or None, headers=headers)


def decode(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"), dtype=np.float32)


def nontrivial(img: np.ndarray) -> bool:
    """Not blank: colours vary across the frame."""
    return float(img[..., :3].std()) > 4.0 and len(np.unique(img[..., 0])) > 16


@pytest.fixture(scope="module")
def samples(server, assets):
    """Every kind of sample asset, uploaded once, baked: name -> asset record."""
    uploads = {
        "Duck.glb": ((assets / "gltf/Duck.glb").read_bytes(), {}),
        "BoxTextured.glb": ((assets / "gltf/BoxTextured.glb").read_bytes(), {}),
        "CesiumMilkTruck.glb": ((assets / "gltf/CesiumMilkTruck.glb").read_bytes(), {}),
        "TestScene.zip": (zip_bytes({n: (assets / "gltf" / n).read_bytes()
                                     for n in ("TestScene.gltf", "TestScene.bin")}), {}),
        "suzanne.ply": ((assets / "mesh/suzanne.ply").read_bytes(), {}),
        "primvar_interpolation.usda": ((assets / "usd/primvar_interpolation.usda").read_bytes(), {}),
        "Teapot.zip": (folder_zip(assets / "usd/Teapot"), {"main": "Teapot.usd"}),
        "TextureCoordinateTest.zip": (folder_zip(assets / "usd/TextureCoordinateTest", "T/"),
                                      {"main": "T/TextureCoordinateTest.usda"}),
        "rgb_cube_with_primitives.gltf": ((assets / "gltf/rgb_cube_with_primitives.gltf").read_bytes(), {}),
    }
    records = {}
    for name, (data, form) in uploads.items():
        r = upload(server, name, data, **form)
        assert r.status_code == 201, (name, r.text)
        body = r.json()
        assert body["status"] in ("baking", "ready") and body["triangles"] > 0 and body["materials"] >= 1
        records[name] = body
    for name, rec in records.items():
        records[name] = server.wait_status(rec["id"])
        assert records[name]["status"] == "ready", records[name]
    return records


def test_health_ready_and_docs(server):
    assert server.client.get("/healthz").json() == {"status": "ok"}
    ready = server.client.get("/readyz").json()
    assert ready["ready"] and len(ready["workers"]) == 2 and all(w["alive"] for w in ready["workers"])
    assert "llvmpipe" in ready["gl_renderer"] or ready["gl_renderer"]
    spec = server.client.get("/openapi.json").json()
    assert {"/assets", "/assets/{asset_id}", "/assets/{asset_id}/thumbnail", "/environments",
            "/healthz", "/readyz", "/metrics"} <= set(spec["paths"])
    # /docs works offline: its scripts and styles come from this server, not a CDN.
    page = server.client.get("/docs").text
    assets = re.findall(r'(?:src|href)="([^"]+\.(?:js|css))"', page) + re.findall(r"url: '([^']+)'", page)
    assert assets and not [a for a in assets if a.startswith("http")], assets
    for url in assets:
        assert server.client.get(url).status_code == 200, url


def test_thumbnails_of_every_sample_in_every_format(server, samples):
    for name, rec in samples.items():
        assert rec["format"] and rec["triangles"] > 0, rec
        for fmt, mime in (("png", "image/png"), ("jpeg", "image/jpeg"), ("webp", "image/webp")):
            r = server.client.get(f"/assets/{rec['id']}/thumbnail", params={"size": 96, "format": fmt})
            assert r.status_code == 200, (name, fmt, r.text)
            assert r.headers["content-type"] == mime
            img = decode(r.content)
            assert img.shape[:2] == (96, 96)
            assert nontrivial(img), (name, fmt)
            plan = json.loads(r.headers["x-render-plan"])
            assert plan["auto"]["objects"], plan  # auto's decisions (renderer.methods.auto) reach clients
    # Non-square sizes and a transparent background come through.
    duck = samples["Duck.glb"]["id"]
    r = server.client.get(f"/assets/{duck}/thumbnail", params={"width": 120, "height": 64,
                                                               "background": "transparent"})
    img = decode(r.content)
    assert img.shape[:2] == (64, 120)
    assert img[0, 0, 3] == 0 and img[..., 3].max() == 255  # corner clear, the duck opaque


def test_time_budget_lets_auto_ray_trace_where_raster_fails(server, assets):
    """A glass torus (genus 1) is a raster failure case: without a budget auto keeps `wyman`,
    with one it ray traces the frame, and X-Render-Plan says so."""
    torus = upload(server, "torus.STL", (assets / "mesh/torus.STL").read_bytes()).json()["id"]
    assert server.wait_status(torus)["status"] == "ready"
    glass = {"size": 48, "transmission": 1, "ior": 1.5, "metallic": 0, "roughness": 0}
    plans = {}
    for budget in (None, 60000):
        params = dict(glass, **({"budget_ms": budget} if budget else {}))
        r = server.client.get(f"/assets/{torus}/thumbnail", params=params)
        assert r.status_code == 200, r.text
        assert nontrivial(decode(r.content))
        plans[budget] = json.loads(r.headers["x-render-plan"])["auto"]
    assert [o["method"] for o in plans[None]["objects"]] == ["wyman"]
    assert plans[60000]["frame_method"] == "raytrace", plans[60000]


def test_turntable_and_views_over_http(server, samples):
    duck = samples["Duck.glb"]["id"]
    r = server.client.get(f"/assets/{duck}/thumbnail", params={"size": 48, "turntable": 4, "format": "gif"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/gif"
    im = Image.open(io.BytesIO(r.content))
    assert im.n_frames == 4 and im.size == (48, 48)
    assert json.loads(r.headers["x-render-plan"])["turntable"]["frames"] == 4
    r = server.client.get(f"/assets/{duck}/thumbnail", params={"size": 48, "turntable": 4})
    assert r.status_code == 422 and "webp or gif" in r.json()["detail"]
    r = server.client.get(f"/assets/{duck}/thumbnail", params={"size": 64, "views": "true"})
    assert r.status_code == 200 and json.loads(r.headers["x-render-plan"])["views"][0] == "front"


def test_etag_304_and_cache_hits_skip_workers(server, samples):
    url = f"/assets/{samples['Duck.glb']['id']}/thumbnail"
    params = {"size": 80, "yaw": 10}
    first = server.client.get(url, params=params)
    assert first.status_code == 200
    etag = first.headers["etag"]
    assert etag.startswith('"') and not etag.startswith("W/")
    assert "max-age" in first.headers["cache-control"]
    jobs = server.worker_jobs()
    again = server.client.get(url, params={"yaw": 10.0, "size": 80})  # same parameters, other spelling
    assert again.status_code == 200 and again.content == first.content and again.headers["etag"] == etag
    for header in (etag, f"W/{etag}", f'"nope", {etag}', "*"):
        r = server.client.get(url, params=params, headers={"If-None-Match": header})
        assert r.status_code == 304 and r.content == b"" and r.headers["etag"] == etag
    r = server.client.get(url, params=params, headers={"If-None-Match": '"other"'})
    assert r.status_code == 200 and r.content == first.content
    assert server.worker_jobs() == jobs, "a cached thumbnail must not touch a worker"
    other = server.client.get(url, params={"size": 80, "yaw": 20})
    assert other.headers["etag"] != etag


def test_same_upload_twice_is_one_asset_and_one_bake(server, samples, assets):
    bakes = _metric(server, 'asset_preview_bakes_total{result="ready"}')
    r = upload(server, "again.glb", (assets / "gltf/Duck.glb").read_bytes())
    assert r.status_code == 200 and r.json()["id"] == samples["Duck.glb"]["id"]
    assert r.json()["status"] == "ready"
    time.sleep(0.3)
    assert _metric(server, 'asset_preview_bakes_total{result="ready"}') == bakes
    ids = [a["id"] for a in server.client.get("/assets").json()["assets"]]
    assert ids.count(samples["Duck.glb"]["id"]) == 1


def test_error_codes_name_the_file_and_reason(server, samples):
    c = server.client
    r = upload(server, "notes.txt", b"hello")
    assert r.status_code == 415 and "notes.txt" in r.json()["detail"] and ".txt" in r.json()["detail"]
    r = upload(server, "broken.glb", b"glTF\x02\x00\x00\x00garbage" * 10)
    assert r.status_code == 422 and r.json()["detail"].startswith("broken.glb: ")
    assert "/service/tmp/" not in r.json()["detail"], "server paths stay private"
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 0]}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "buffers": [{"uri": "http://example.com/x.bin", "byteLength": 36}]}
    r = upload(server, "remote.gltf", json.dumps(gltf).encode())
    assert r.status_code == 422 and "http" in r.json()["detail"], r.text
    r = upload(server, "empty.glb", b"")
    assert r.status_code == 422
    assert c.get("/assets/" + "0" * 32).status_code == 404
    assert c.get("/assets/nope/thumbnail").status_code == 404
    assert c.delete("/assets/" + "0" * 32).status_code == 404
    duck = samples["Duck.glb"]["id"]
    r = c.get(f"/assets/{duck}/thumbnail", params={"size": 4096})
    assert r.status_code == 422 and "4096" in r.json()["detail"]
    for bad in ({"format": "gif"}, {"method": "magic"}, {"background": "plaid"}, {"size": 0},
                {"roughness": 2}, {"unknown": 1}):
        assert c.get(f"/assets/{duck}/thumbnail", params=bad).status_code == 422, bad
    r = c.get(f"/assets/{duck}/thumbnail", params={"env": "nowhere"})
    assert r.status_code == 422 and "nowhere" in r.json()["detail"]


def test_upload_limit_413(server):
    r = upload(server, "big.glb", b"\0" * (UPLOAD_LIMIT + 1))
    assert r.status_code == 413 and "limit" in r.json()["detail"]

    def chunked():  # no Content-Length: counted as it arrives
        yield (b'--xyz\r\nContent-Disposition: form-data; name="file"; filename="big.glb"\r\n'
               b"Content-Type: application/octet-stream\r\n\r\n")
        for _ in range(UPLOAD_LIMIT // 2**20 + 2):
            yield b"\0" * 2**20
        yield b"\r\n--xyz--\r\n"
    r = server.client.post("/assets", content=chunked(),
                           headers={"content-type": "multipart/form-data; boundary=xyz"})
    assert r.status_code == 413


def textured_quad_gltf(width: int, height: int) -> bytes:
    """A one-quad glTF with its buffer and a width x height PNG texture embedded as data URIs."""
    import base64
    import struct
    pos = struct.pack("<12f", 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0)
    uv = struct.pack("<8f", 0, 1, 1, 1, 1, 0, 0, 0)
    idx = struct.pack("<6H", 0, 1, 2, 0, 2, 3)
    buf = pos + uv + idx
    png = io.BytesIO()
    Image.new("RGB", (width, height), (200, 40, 40)).save(png, "PNG")
    uri = lambda mime, b: f"data:{mime};base64," + base64.b64encode(b).decode()  # noqa: E731
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2,
                                       "material": 0}]}],
           "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
           "textures": [{"source": 0}], "images": [{"uri": uri("image/png", png.getvalue())}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]},
                         {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                         {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                           {"buffer": 0, "byteOffset": 48, "byteLength": 32},
                           {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
           "buffers": [{"byteLength": len(buf), "uri": uri("application/octet-stream", buf)}]}
    return json.dumps(doc).encode()


def test_content_limits_triangles_and_texture_pixels(server, assets):
    r = upload(server, "bunny.ply", (assets / "mesh/bunny.ply").read_bytes())
    assert r.status_code == 422 and r.json()["detail"].startswith("bunny.ply: ")
    assert "triangles" in r.json()["detail"] and "10000" in r.json()["detail"].replace(",", "")
    small = upload(server, "small.gltf", textured_quad_gltf(64, 64))
    assert small.status_code == 201, small.text
    assert server.wait_status(small.json()["id"])["status"] == "ready"
    # A texture over the pixel limit is checked from its header, never decoded: the pipeline
    # drops it (the material keeps its factors) and says so in the asset's warnings.
    r = upload(server, "huge.gltf", textured_quad_gltf(4096, 1100))
    assert r.status_code == 201, r.text
    warnings = " ".join(r.json()["warnings"])
    assert "4096x1100" in warnings and "limit" in warnings and "/service/" not in warnings
    assert server.wait_status(r.json()["id"])["status"] == "ready"


def test_archives_refuse_escapes_links_and_bombs(server, assets):
    gltf = (assets / "gltf/rgb_cube_with_primitives.gltf").read_bytes()
    cases = {
        "escape.zip": zip_bytes({"../evil.gltf": gltf}),
        "absolute.zip": zip_bytes({"/etc/evil.gltf": gltf}),
        "link.zip": zip_bytes({"a.gltf": gltf}, links={"b.bin": "/etc/passwd"}),
        "many.zip": zip_bytes({f"f{i}.bin": b"x" for i in range(65)} | {"a.gltf": gltf}),
        "bomb.zip": _bomb(),
        "nothing.zip": zip_bytes({"readme.txt": b"hi"}),
        "garbage.zip": b"PK\x03\x04 not really",
    }
    for name, data in cases.items():
        r = upload(server, name, data)
        assert r.status_code == 422, (name, r.status_code, r.text)
        assert r.json()["detail"].startswith(name + ": "), r.text
    assert "limit" in upload(server, "many.zip", cases["many.zip"]).json()["detail"]


def _bomb() -> bytes:
    """More zeros than the unpacked limit, deflated to a few kB: refused before inflating."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("a.gltf", "w") as f:
            chunk = b"\0" * 2**22
            for _ in range(UNPACKED_LIMIT // 2**22 + 1):
                f.write(chunk)
    return buf.getvalue()


def test_concurrent_clients_all_get_correct_answers(server, samples):
    ids = [samples[n]["id"] for n in ("Duck.glb", "BoxTextured.glb", "suzanne.ply")]
    # The answers rendered one at a time are the reference.
    expected = {}
    for asset_id in ids:
        r = server.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 72, "yaw": 45})
        expected[asset_id] = r.content

    def fetch(i):
        asset_id = ids[i % len(ids)]
        with httpx.Client(base_url=server.url, timeout=60) as c:
            r = c.get(f"/assets/{asset_id}/thumbnail", params={"size": 72, "yaw": 45})
            fresh = c.get(f"/assets/{asset_id}/thumbnail", params={"size": 64, "yaw": 100 + i % 2})
        return asset_id, r, fresh

    with ThreadPoolExecutor(8) as pool:
        results = list(pool.map(fetch, range(16)))
    for asset_id, r, fresh in results:
        assert r.status_code == 200 and r.content == expected[asset_id]
        assert fresh.status_code == 200 and nontrivial(decode(fresh.content))
    # The same fresh thumbnail asked for by several clients at once is one image.
    by_key = {}
    for asset_id, _, fresh in results:
        by_key.setdefault(fresh.url.params["yaw"] + asset_id, set()).add(fresh.headers["etag"])
    assert all(len(v) == 1 for v in by_key.values()), by_key


def test_full_queue_answers_503_with_retry_after(server, samples):
    duck = samples["Duck.glb"]["id"]
    statuses = []

    def fetch(i):
        with httpx.Client(base_url=server.url, timeout=120) as c:
            r = c.get(f"/assets/{duck}/thumbnail", params={"size": 320, "yaw": 200 + i})
            return r.status_code, r.headers.get("retry-after"), r.text

    with ThreadPoolExecutor(MAX_QUEUE * 3) as pool:
        statuses = list(pool.map(fetch, range(MAX_QUEUE * 3)))
    codes = [s for s, _, _ in statuses]
    assert set(codes) <= {200, 503}, statuses
    assert 503 in codes and 200 in codes
    assert all(ra and int(ra) > 0 for s, ra, _ in statuses if s == 503)
    assert _metric(server, 'asset_preview_rejected_total{reason="queue_full"}') >= 1


@pytest.mark.slow
def test_killed_worker_fails_one_request_then_recovers(server, samples):
    duck = samples["Duck.glb"]["id"]
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("r", httpx.get(
        f"{server.url}/assets/{duck}/thumbnail", params={"size": 2048, "yaw": 33}, timeout=120)))
    t.start()
    victim = None
    end = time.monotonic() + 30
    while victim is None and time.monotonic() < end:
        busy = [w for w in server.client.get("/readyz").json()["workers"] if w["op"] == "render"]
        victim = busy[0]["pid"] if busy else None
        time.sleep(0.01)
    assert victim, "the render never showed up as busy"
    os.kill(victim, signal.SIGKILL)
    t.join(120)
    r = out["r"]
    assert r.status_code == 500, r.text
    assert "crashed" in r.json()["detail"] and str(victim) in r.json()["detail"]
    workers = server.client.get("/readyz").json()["workers"]
    assert victim not in [w["pid"] for w in workers] and all(w["alive"] for w in workers)
    r = server.client.get(f"/assets/{duck}/thumbnail", params={"size": 64, "yaw": 33})
    assert r.status_code == 200 and nontrivial(decode(r.content))
    assert _metric(server, 'asset_preview_worker_restarts_total{reason="crash"}') >= 1


def test_environments_bundled_and_uploaded(server, samples):
    envs = server.client.get("/environments").json()["environments"]
    names = {e["name"] for e in envs}
    assert "footprint_court" in names and sum(e["default"] for e in envs) == 1
    # A small synthetic panorama: warm orange above, blue below.
    pano = np.zeros((32, 64, 3), np.uint8)
    pano[:16] = (255, 140, 20)
    pano[16:] = (20, 60, 255)
    buf = io.BytesIO()
    Image.fromarray(pano).save(buf, "PNG")
    r = server.client.post("/environments", files={"file": ("sunset.png", buf.getvalue())},
                           data={"name": "sunset"})
    assert r.status_code == 201, r.text
    assert r.json()["name"] == "sunset" and r.json()["source"] == "uploaded"
    assert "sunset" in {e["name"] for e in server.client.get("/environments").json()["environments"]}
    duck = samples["Duck.glb"]["id"]
    a = server.client.get(f"/assets/{duck}/thumbnail", params={"size": 64, "env": "sunset",
                                                               "background": "env"})
    b = server.client.get(f"/assets/{duck}/thumbnail", params={"size": 64, "env": "pisa",
                                                               "background": "env"})
    assert a.status_code == 200 and b.status_code == 200 and a.headers["etag"] != b.headers["etag"]
    bg = decode(a.content)[:4, :4, :3].mean(axis=(0, 1))
    assert bg[0] > bg[2] or bg[2] > bg[0]  # the panorama shows behind the asset
    r = server.client.post("/environments", files={"file": ("bad.png", b"\x89PNG\r\n\x1a\n broken")})
    assert r.status_code == 422 and "bad.png" in r.json()["detail"]
    r = server.client.post("/environments", files={"file": ("x.gif", b"GIF89a")})
    assert r.status_code == 415


def test_delete_removes_asset_and_thumbnails(server, assets):
    r = upload(server, "torus.STL", (assets / "mesh/torus.STL").read_bytes())
    asset_id = r.json()["id"]
    assert server.wait_status(asset_id)["status"] == "ready"
    assert server.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 48}).status_code == 200
    assert server.client.delete(f"/assets/{asset_id}").json() == {"id": asset_id, "deleted": True}
    assert server.client.get(f"/assets/{asset_id}").status_code == 404
    assert server.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 48}).status_code == 404
    assert not (server.cache / "service/thumbs" / asset_id).exists()


def test_metrics_are_prometheus_text(server, samples):
    url = f"/assets/{samples['BoxTextured.glb']['id']}/thumbnail"
    before = {k: _metric(server, f'asset_preview_thumbnail_cache_total{{result="{k}"}}')
              for k in ("hit", "miss", "not_modified")}
    etag = server.client.get(url, params={"size": 40, "yaw": 3}).headers["etag"]  # miss
    server.client.get(url, params={"size": 40, "yaw": 3})  # hit
    server.client.get(url, params={"size": 40, "yaw": 3}, headers={"If-None-Match": etag})  # 304
    for k in before:
        assert _metric(server, f'asset_preview_thumbnail_cache_total{{result="{k}"}}') == before[k] + 1, k
    text = server.client.get("/metrics").text
    for name in ("asset_preview_http_requests_total", "asset_preview_http_request_duration_seconds_bucket",
                 "asset_preview_thumbnail_cache_total", "asset_preview_render_seconds_count",
                 "asset_preview_bake_seconds_count", "asset_preview_worker_restarts_total",
                 "asset_preview_render_queue"):
        assert name in text
    assert _metric(server, 'asset_preview_render_seconds_count') >= 1
    from prometheus_client.parser import text_string_to_metric_families
    families = {f.name for f in text_string_to_metric_families(text)}  # parses: labels escaped
    assert {"asset_preview_http_requests", "asset_preview_render_queue"} <= families


def test_page_and_its_files_work_offline(server, samples):
    """The page draws its cards from GET /assets in the browser (tests/test_page.py drives it);
    here: it is served with its script and style, the defaults inlined, and nothing external."""
    page = server.client.get("/")
    assert page.status_code == 200 and "<form" in page.text and 'type="file"' in page.text
    assert '"yaw": 35.0' in page.text  # the defaults come from RenderOptions
    for name, kind in (("page.js", "javascript"), ("page.css", "css")):
        r = server.client.get(f"/static/{name}")
        assert r.status_code == 200 and kind in r.headers["content-type"]
        assert "http://" not in r.text and "https://" not in r.text  # no CDN
    assert "http://" not in page.text and "https://" not in page.text
    assert server.client.get("/static/../app.py").status_code == 404
    assert server.client.get("/static/nothing.js").status_code == 404


def _metric(server: Server, series: str) -> float:
    for line in server.client.get("/metrics").text.splitlines():
        if line.startswith(series + " "):
            return float(line.rsplit(" ", 1)[1])
    return 0.0
