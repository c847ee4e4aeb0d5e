"""The page's detail view never shows stale state, and the page works behind a key: headless
Chromium (as tests/test_page.py) against a real keyed server on loopback."""
from __future__ import annotations

import time

import pytest
from service_server import Server
from test_page import _start_browser, wait

KEY = "state-test-key"


@pytest.fixture(scope="module")
def server(tmp_path_factory, assets):
    # A key and no --public-read: the page must still load and ask for it.
    srv = Server(tmp_path_factory.mktemp("state") / "cache", "--workers", "2", "--no-seed", "--api-key", KEY,
                 env={"ASSET_PREVIEW_MAX_RENDER_COST_MS": "1e9", "ASSET_PREVIEW_CLIENT_SHARE": "1"})
    srv.client.headers.update({"Authorization": f"Bearer {KEY}"})
    try:
        srv.wait_ready()
        srv.ids = {}
        for name in ("Duck.glb", "BoxTextured.glb"):
            r = srv.client.post("/assets", files={"file": (name, (assets / "gltf" / name).read_bytes())})
            assert r.status_code == 201, r.text
            assert srv.wait_status(r.json()["id"])["status"] == "ready"
            srv.ids[name] = r.json()["id"]
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def page(server):
    from selenium.webdriver.common.by import By
    b = _start_browser()
    b.get(server.url + "/")
    find = lambda css: b.find_element(By.CSS_SELECTOR, css)  # noqa: E731
    # Behind the key the page loads and asks for it; given, the cards come.
    wait(lambda: "needs its API key" in find("#msg").text, 30, "the page to ask for the key")
    assert not b.find_elements(By.CSS_SELECTOR, ".card")
    find("#key").send_keys(KEY)
    b.execute_script("document.getElementById('key').dispatchEvent(new Event('change'))")
    wait(lambda: len(b.find_elements(By.CSS_SELECTOR, ".card[data-status=ready]")) == 2, 30, "both cards")
    assert b.execute_script("return sessionStorage.getItem('apiKey')") == KEY
    assert b.execute_script("return localStorage.getItem('apiKey')") is None
    yield b, find
    b.quit()


def _open(b, find, server, name):
    b.execute_script(f"document.querySelector('.card[data-id=\"{server.ids[name]}\"]').click()")
    wait(lambda: find("#d-name").text == name, 10, f"the detail view of {name}")
    # generous: on a loaded 2-core host the still queues behind the other card's turntable
    wait(lambda: find("#canvas").get_attribute("data-state") == "ready", 240,
         lambda: f"the still of {name} (canvas {find('#canvas').get_attribute('data-state')!r}, "
                 f"page says {find('#hint').text!r} {find('#d-plan').text!r} {find('#d-error').text!r}; "
                 f"{_server_state(server)})")


def _server_state(server) -> str:
    """What the server was doing, for a timeout's message: its workers, and its log's end."""
    try:
        workers = server.client.get("/readyz", timeout=10).json()["workers"]
    except Exception as e:  # a blocked event loop is itself the answer
        workers = f"/readyz failed: {e!r}"
    return f"workers {workers}; log ends:\n{server.log.read_text()[-2500:]}"


def _set(b, **values):
    """Set controls without events, then one change on the yaw (a still only, no turntable)."""
    for name, value in values.items():
        b.execute_script("const s = document.getElementById('c-' + arguments[0]);"
                         "if (s.tagName === 'SELECT' && ![...s.options].some(o => o.value === arguments[1]))"
                         "  s.add(new Option(arguments[1], arguments[1]));"
                         "s.value = arguments[1];", name, str(value))
    b.execute_script("document.getElementById('c-yaw').dispatchEvent(new Event('change', {bubbles: true}))")


def _idle(server, timeout=180.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if not any(w["busy"] for w in server.client.get("/readyz").json()["workers"]):
            return
        time.sleep(0.2)
    raise AssertionError("the workers never went idle")


def test_a_slow_render_followed_by_a_fast_one_shows_the_fast_one(server, page):
    b, find = page
    _open(b, find, server, "Duck.glb")
    _idle(server)  # the turntable too: both workers free
    _set(b, method="raytrace", size=1024, yaw=-20)   # slow: ray traced, 1024 px
    time.sleep(0.3)                                   # its request is on its way
    _set(b, method="opaque", size=256, yaw=-15)      # fast: raster, 256 px
    wait(lambda: find("#canvas").get_attribute("data-state") == "ready", 90, "the fast still")
    assert find("#d-plan").text.startswith("Method opaque") and "yaw -15" in find("#d-plan").text
    _idle(server)  # the slow render has finished on the server (its answer went nowhere)
    time.sleep(0.5)
    assert find("#d-plan").text.startswith("Method opaque") and "yaw -15" in find("#d-plan").text
    assert b.execute_script("return document.getElementById('canvas').width") == 256
    assert find("#d-error").text == ""


def test_a_refusal_is_marked_over_the_image_and_cleared_by_the_next_success(server, page):
    b, find = page
    _open(b, find, server, "Duck.glb")
    plan_before = find("#d-plan").text
    _set(b, size=4000)  # over max_thumbnail_size (2048): 422
    wait(lambda: find("#canvas").get_attribute("data-state") == "error", 30, "the refusal")
    assert "limit is" in find("#d-error").text
    assert find("#d-stale").is_displayed() and "not updated" in find("#d-stale").text
    assert "stale" in find("#d-plan").get_attribute("class") and find("#d-plan").text == plan_before
    _set(b, size=256)
    wait(lambda: find("#canvas").get_attribute("data-state") == "ready", 60, "the next still")
    assert find("#d-error").text == "" and not find("#d-stale").is_displayed()
    assert "stale" not in find("#d-plan").get_attribute("class")


def test_closing_and_opening_another_asset_at_once_shows_its_still(server, page):
    """The dialog's close event fires after close() returns: closing one asset and opening
    another in the same task must not let that late event abort the new asset's requests
    (its still stayed 'loading' for good)."""
    b, find = page
    _open(b, find, server, "Duck.glb")
    box = server.ids["BoxTextured.glb"]
    b.execute_script("document.getElementById('detail').close();"
                     f"document.querySelector('.card[data-id=\"{box}\"]').click()")
    wait(lambda: find("#d-name").text == "BoxTextured.glb", 10, "the detail view of BoxTextured.glb")
    wait(lambda: find("#canvas").get_attribute("data-state") == "ready", 240,
         lambda: f"the still (canvas {find('#canvas').get_attribute('data-state')!r})")
    assert b.execute_script("return document.getElementById('detail').open")


def test_opening_another_asset_resets_the_view(server, page):
    b, find = page
    _open(b, find, server, "Duck.glb")
    b.execute_script("for (const [id, v] of [['c-size', '256'], ['c-background', 'env']]) document.getElementById(id).value = v")
    _set(b, size=4000)  # leave an error behind
    wait(lambda: find("#canvas").get_attribute("data-state") == "error", 30, "the refusal")
    b.execute_script("document.getElementById('detail').close()")
    _open(b, find, server, "BoxTextured.glb")
    assert find("#d-error").text == "" and not find("#d-stale").is_displayed()
    assert find("#c-size").get_attribute("value") == "512"
    assert find("#c-background").get_attribute("value") == "gradient"
    plan = find("#d-plan").text
    assert plan.startswith("Method auto") and "background gradient" in plan
