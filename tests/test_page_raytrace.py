"""The page offers method=raytrace with the service's cost estimate beside it, and a refused
raytrace says so over the image it did not replace: headless Chromium (as tests/test_page.py)
against a real server on loopback with a render ceiling of 2 s (max_render_cost_ms): the
cost model refitted on CPU time (issue 26's front) puts a whole-frame 512 px ray trace of the
duck at ~2.8 s and 256 px at ~1.4 s, under the default ceiling of 60 s both."""
from __future__ import annotations

import pytest
from service_server import Server
from test_page import _start_browser, wait
from test_page_state import _idle, _set

KEY = "raytrace-page-key"
CEILING_MS = 2000


@pytest.fixture(scope="module")
def server(tmp_path_factory, assets):
    srv = Server(tmp_path_factory.mktemp("rtpage") / "cache", "--workers", "1", "--no-seed", "--api-key", KEY,
                 env={"ASSET_PREVIEW_MAX_RENDER_COST_MS": str(CEILING_MS)})
    srv.client.headers.update({"Authorization": f"Bearer {KEY}"})
    try:
        srv.wait_ready()
        r = srv.client.post("/assets", files={"file": ("Duck.glb", (assets / "gltf" / "Duck.glb").read_bytes())})
        assert r.status_code == 201, r.text
        srv.duck = r.json()["id"]
        assert srv.wait_status(srv.duck)["status"] == "ready"
        yield srv
    finally:
        srv.stop()


def test_estimate_is_the_admission_model(server):
    def estimate(**params):
        r = server.client.get(f"/assets/{server.duck}/estimate", params=params)
        assert r.status_code == 200, r.text
        return r.json()
    small, big = estimate(method="raytrace", size=256), estimate(method="raytrace", size=512)
    assert small["method"] == "raytrace" and small["width"] == 256
    assert 0 < small["estimated_ms"] < big["estimated_ms"]
    ceiling = big["ceiling_ms"]
    # what the estimate calls refused is what the thumbnail refuses, and the other way round
    for e in (small, big):
        assert (e["refused"] is not None) == (e["estimated_ms"] > ceiling), e
    refused = next((e, s) for e, s in ((small, 256), (big, 512)) if e["refused"])
    r = server.client.get(f"/assets/{server.duck}/thumbnail", params={"method": "raytrace", "size": refused[1]})
    assert r.status_code == 422 and "over the ceiling" in r.json()["detail"], r.text
    raster = estimate(method="opaque", size=512)
    assert raster["refused"] is None and raster["estimated_ms"] < small["estimated_ms"]
    bad = server.client.get(f"/assets/{server.duck}/estimate", params={"size": "huge"})
    assert bad.status_code == 422
    assert server.client.get("/assets/nope/estimate").status_code == 404
    assert server.client.get(f"/assets/{server.duck}/estimate", headers={"Authorization": ""}).status_code == 401


def test_estimate_counts_frames_and_the_path_tracers_budget(server):
    def cost(**params) -> float:
        r = server.client.get(f"/assets/{server.duck}/estimate", params={"size": 256, **params})
        assert r.status_code == 200, r.text
        return r.json()["estimated_ms"]
    still = cost(method="opaque")
    # a turntable is its frames' cost, an animated image the most frames it may have (the cap)
    assert cost(method="opaque", turntable=24, format="webp") == pytest.approx(24 * still, rel=1e-3)
    assert cost(method="opaque", animate=12, format="webp") == pytest.approx(120 * still, rel=1e-3)
    # the path tracer costs by its paths a pixel (over a fixed part: renderer.methods.auto.rt_ms),
    # and stops before its budget
    few, many = cost(method="raytrace", integrator="path", samples=16), cost(method="raytrace", integrator="path", samples=256)
    assert 8 * few < many < 16 * few
    assert cost(method="raytrace", integrator="path", samples=256, budget_ms=2000) <= 2000


def test_page_offers_raytrace_with_its_cost_and_marks_its_refusal(server):
    from selenium.webdriver.common.by import By
    b = _start_browser()
    try:
        find = lambda css: b.find_element(By.CSS_SELECTOR, css)  # noqa: E731
        b.get(server.url + "/")
        find("#key").send_keys(KEY)
        b.execute_script("document.getElementById('key').dispatchEvent(new Event('change'))")
        wait(lambda: b.find_elements(By.CSS_SELECTOR, ".card[data-status=ready]"), 30, "the card")
        b.execute_script("document.querySelector('.card').click()")
        wait(lambda: find("#canvas").get_attribute("data-state") == "ready", 90, "the first still")
        # the option carries its cost at the view's settings (512 px: over this server's ceiling)
        option = find("#c-method option[value=raytrace]")
        wait(lambda: "≈" in option.text, 30, lambda: f"the estimate on the option ({option.text!r})")
        expected = server.client.get(f"/assets/{server.duck}/estimate",
                                     params={"method": "raytrace", "size": 512}).json()
        assert expected["refused"], expected  # the ceiling refuses a 512 px raytrace of the duck
        assert "refused here" in option.text and "it would be refused" in find("#d-cost").text
        plan_before = find("#d-plan").text
        _idle(server)
        _set(b, method="raytrace")
        wait(lambda: find("#canvas").get_attribute("data-state") == "error", 30, "the refusal")
        assert "over the ceiling" in find("#d-error").text
        assert find("#d-stale").is_displayed() and "not updated" in find("#d-stale").text
        assert "stale" in find("#d-plan").get_attribute("class") and find("#d-plan").text == plan_before
        # fewer pixels: the estimate drops under the ceiling and says so
        b.execute_script("const s = document.getElementById('c-size'); s.value = '256';"
                         "s.dispatchEvent(new Event('change', {bubbles: true}))")
        small = server.client.get(f"/assets/{server.duck}/estimate", params={"method": "raytrace", "size": 256}).json()
        assert small["refused"] is None, small
        wait(lambda: "refused" not in option.text and "≈" in option.text, 30, "the smaller estimate")
        assert "would be refused" not in find("#d-cost").text and "estimated" in find("#d-cost").text
    finally:
        b.quit()
