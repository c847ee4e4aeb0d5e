"""Operating the service: seeding, the API key, baking waits, deadlines, restarts."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import httpx
import pytest
from service_server import Server
from test_service import decode, nontrivial, upload

KEY = "s3cret-key"
SAMPLES = Path(__file__).resolve().parents[1] / "service" / "samples"
# The render deadline is far above any cheap render's time however loaded the machine (workers
# are warm before they take requests); the blockers below are far above it.
OPS_ENV = {"ASSET_PREVIEW_API_KEY": KEY, "ASSET_PREVIEW_BAKE_WAIT_SECONDS": "0",
           "ASSET_PREVIEW_RENDER_SECONDS": "8", "ASSET_PREVIEW_MAX_THUMBNAIL_SIZE": "4096",
           "ASSET_PREVIEW_MAX_RENDER_COST_MS": "1e9", "ASSET_PREVIEW_SAMPLES": str(SAMPLES)}
AUTH = {"Authorization": f"Bearer {KEY}"}
# Ray-traced glass at 2048 px, 32 bounces: over 30 s on an idle 2-core CPU, far past the deadline.
BLOCKER = {"size": 2048, "method": "raytrace", "transmission": 1, "bounces": 32}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("ops") / "cache"


@pytest.fixture(scope="module")
def ops(cache):
    """One worker, an API key, no waiting for bakes, a short render deadline, seeded."""
    srv = Server(cache, "--workers", "1", env=OPS_ENV)
    srv.client.headers.update(AUTH)
    try:
        srv.wait_ready()
        yield srv
    finally:
        srv.stop()


def seeded(srv: Server, count: int = 2) -> list[dict]:
    end = time.monotonic() + 120
    while time.monotonic() < end:
        recs = srv.client.get("/assets").json()["assets"]
        if len(recs) >= count and all(r["status"] != "baking" for r in recs):
            return recs
        time.sleep(0.2)
    raise TimeoutError("samples not seeded")


def test_empty_store_is_seeded_with_the_samples(ops):
    recs = seeded(ops)
    assert {r["name"] for r in recs} == {"Duck.glb", "BoxTextured.glb"}
    assert all(r["status"] == "ready" for r in recs)
    listed = {a["id"]: a for a in ops.client.get("/assets").json()["assets"]}  # what the page shows
    for r in recs:
        assert listed[r["id"]]["thumbnail"] == f'/assets/{r["id"]}/thumbnail'
        img = ops.client.get(f'/assets/{r["id"]}/thumbnail', params={"size": 128})
        assert img.status_code == 200 and nontrivial(decode(img.content))


def test_api_key_guards_every_endpoint_but_probes(ops, assets):
    data = (assets / "mesh/suzanne.ply").read_bytes()
    anon = httpx.Client(base_url=ops.url, timeout=60)  # the fixture's client carries the key
    r = anon.post("/assets", files={"file": ("suzanne.ply", data)})
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    for bad in ("Bearer wrong", f"Basic {KEY}", "Bearer", f"Bearer {KEY}x"):
        assert upload(ops, "suzanne.ply", data, headers={"Authorization": bad}).status_code == 401
    r = upload(ops, "suzanne.ply", data, headers=AUTH)
    assert r.status_code == 201, r.text
    asset_id = r.json()["id"]
    for path in (f"/assets/{asset_id}", "/assets", f"/assets/{asset_id}/thumbnail", "/environments",
                 "/docs", "/openapi.json", "/nowhere"):
        assert anon.get(path).status_code == 401, path
        assert anon.head(path).status_code == 401, path
    # The page itself (no data) is served, so its key field can be used.
    for path in ("/healthz", "/readyz", "/metrics", "/", "/static/page.js", "/static/page.css", "/favicon.ico"):
        assert anon.get(path).status_code == 200, path
    assert anon.delete(f"/assets/{asset_id}").status_code == 401
    assert anon.post("/environments", files={"file": ("a.png", b"x")}).status_code == 401
    assert ops.client.get(f"/assets/{asset_id}", headers=AUTH).status_code == 200
    assert KEY not in ops.log.read_text(), "keys are never logged"
    assert ops.client.delete(f"/assets/{asset_id}", headers=AUTH).status_code == 200
    anon.close()


@pytest.fixture(scope="module")
def blocked(ops, assets):
    """One blocker for the two tests below: a 2048 px ray-traced glass render at 32 bounces
    (over 30 s on an idle 2-core CPU) runs into the 8 s render deadline whatever the load, and
    while it holds the only worker a new asset's bake must queue behind it. Each blocker costs
    the whole deadline, so both tests read this one's outcome."""
    duck = next(r for r in seeded(ops) if r["name"] == "Duck.glb")["id"]
    out: dict[str, httpx.Response] = {}
    blocker = threading.Thread(target=lambda: out.setdefault("blocker", httpx.get(
        f"{ops.url}/assets/{duck}/thumbnail", timeout=120, headers=AUTH,
        params=BLOCKER | {"yaw": 1})))
    blocker.start()
    time.sleep(0.3)
    r_up = upload(ops, "torus.STL", (assets / "mesh/torus.STL").read_bytes(), headers=AUTH)
    asset_id = r_up.json()["id"]
    out["while_baking"] = ops.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 64})
    blocker.join(60)
    return duck, asset_id, out


def test_thumbnail_of_a_baking_asset_answers_202(ops, blocked):
    _, asset_id, out = blocked
    r = out["while_baking"]
    assert r.status_code == 202, r.text
    assert int(r.headers["retry-after"]) > 0 and "baking" in r.json()["detail"]
    assert ops.wait_status(asset_id)["status"] == "ready"
    assert ops.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 64}).status_code == 200


@pytest.mark.slow
def test_render_past_its_deadline_is_stopped(ops, blocked):
    duck, _, out = blocked
    r = out["blocker"]
    assert r.status_code == 504, r.text
    assert "deadline" in r.json()["detail"]
    r = ops.client.get(f"/assets/{duck}/thumbnail", params={"size": 64, "yaw": 1})
    assert r.status_code == 200
    restarts = [line for line in ops.client.get("/metrics").text.splitlines()
                if line.startswith('asset_preview_worker_restarts_total{reason="deadline"}')]
    assert restarts and float(restarts[0].split()[-1]) >= 1


def test_restart_keeps_assets_thumbnails_and_etags(ops, cache):
    recs = seeded(ops)
    asset_id = recs[0]["id"]
    first = ops.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 100})
    assert first.status_code == 200
    ops.stop()
    leftover = cache / "service" / "tmp" / "half-written.upload"
    leftover.write_bytes(b"partial")  # what a killed server could leave behind
    again = Server(cache, "--workers", "1", env=OPS_ENV)
    again.client.headers.update(AUTH)
    try:
        again.wait_ready()
        assert not leftover.exists()
        after = again.client.get("/assets").json()["assets"]
        assert {r["id"]: r["status"] for r in after} == {r["id"]: r["status"] for r in recs}
        jobs = again.worker_jobs()
        r = again.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 100})
        assert r.status_code == 200 and r.headers["etag"] == first.headers["etag"]
        assert r.content == first.content and again.worker_jobs() == jobs
        r = again.client.get(f"/assets/{asset_id}/thumbnail", params={"size": 100},
                             headers={"If-None-Match": first.headers["etag"]})
        assert r.status_code == 304
    finally:
        again.stop()
