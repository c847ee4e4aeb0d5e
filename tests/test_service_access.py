"""The page behind a key, HEAD wherever GET answers, per-client render rates, finite values, and
workers replaced past their memory bound, on a real server over loopback."""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from service_server import Server

KEY = "access-test-key"
AUTH = {"Authorization": f"Bearer {KEY}"}


@pytest.fixture(scope="module")
def keyed(tmp_path_factory, assets):
    srv = Server(tmp_path_factory.mktemp("access") / "cache", "--workers", "1", "--no-seed",
                 "--api-key", KEY, env={"ASSET_PREVIEW_RENDERS_PER_MINUTE": "3",
                      # every job leaves the worker over this: each is replaced after each job
                      "ASSET_PREVIEW_WORKER_MAX_RSS_BYTES": "1"})
    srv.client.headers.update(AUTH)
    try:
        srv.wait_ready()
        r = srv.client.post("/assets", files={"file": ("Duck.glb", (assets / "gltf/Duck.glb").read_bytes())})
        assert r.status_code == 201, r.text
        assert srv.wait_status(r.json()["id"])["status"] == "ready"
        srv.asset_id = r.json()["id"]
        yield srv
    finally:
        srv.stop()


def test_the_page_is_served_without_the_key_and_nothing_else(keyed):
    anon = httpx.Client(base_url=keyed.url, timeout=60)
    page = anon.get("/")
    assert page.status_code == 200 and 'id="key"' in page.text and "text/html" in page.headers["content-type"]
    for path in ("/static/page.js", "/static/page.css", "/favicon.ico"):
        assert anon.get(path).status_code == 200, path
    for path in ("/assets", f"/assets/{keyed.asset_id}", "/environments", "/docs"):
        r = anon.get(path)
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", path
    # a cookie is never a key
    assert anon.get("/assets", headers={"Cookie": f"apiKey={KEY}"}).status_code == 401
    anon.close()


def test_head_answers_wherever_get_does(keyed):
    c = keyed.client
    for path in ("/", "/assets", f"/assets/{keyed.asset_id}", "/environments", "/healthz", "/readyz",
                 "/metrics", "/static/page.js", "/favicon.ico", f"/assets/{keyed.asset_id}/thumbnail?size=48"):
        get, head = c.get(path), c.head(path)
        assert get.status_code == 200 and head.status_code == 200, (path, head.status_code)
        assert head.content == b"" and head.headers["content-type"] == get.headers["content-type"], path
        if "thumbnail" in path:  # the same cached image: the same validator
            assert head.headers["etag"] == get.headers["etag"]
    assert c.head("/nowhere").status_code == 404 and c.head("/assets/" + "0" * 32).status_code == 404
    assert c.post("/healthz").status_code == 405  # HEAD is GET's: other methods still are not


def test_renders_per_client_are_rate_limited_with_retry_after(keyed):
    # Asked at once (the rate is checked on arrival, before any render): of 6 distinct renders
    # at 3 a minute, at most 3 start; the rest are 429 with Retry-After.
    url = f"/assets/{keyed.asset_id}/thumbnail"
    with ThreadPoolExecutor(6) as ex:
        answers = list(ex.map(lambda yaw: keyed.client.get(url, params={"size": 40, "yaw": yaw}), range(1, 7)))
    codes = [r.status_code for r in answers]
    assert 200 in codes and codes.count(429) >= 3 and set(codes) <= {200, 429}, codes
    refused = next(r for r in answers if r.status_code == 429)
    assert int(refused.headers["retry-after"]) >= 1 and "renders within a minute" in refused.json()["detail"]
    done = next(yaw for yaw, r in zip(range(1, 7), answers) if r.status_code == 200)
    assert keyed.client.get(url, params={"size": 40, "yaw": done}).status_code == 200  # cached: still served


def test_a_worker_over_its_memory_bound_is_replaced_between_jobs(keyed):
    # Its bound is 1 byte: the upload's inspect and bake and every render so far each replaced it.
    c = keyed.client
    end = time.monotonic() + 60
    while time.monotonic() < end:
        w = c.get("/readyz").json()["workers"][0]
        if w["alive"] and w["restarts"] >= 2 and w["rss_bytes"]:  # replaced, then warmed up
            break
        time.sleep(0.2)
    assert w["restarts"] >= 2 and w["rss_bytes"] > 50 * 2**20, w  # a warm GL worker, measured
    assert 'asset_preview_worker_restarts_total{reason="memory"}' in c.get("/metrics").text
    assert c.get("/readyz").json()["ready"]  # the replacement serves


def test_non_finite_values_are_refused_as_such(keyed):
    r = keyed.client.get(f"/assets/{keyed.asset_id}/thumbnail", params={"yaw": "nan"})
    assert r.status_code == 422 and "finite number" in r.json()["detail"], r.text
