"""The page at / in a real browser: Debian's headless Chromium driven by selenium against the real
server on loopback. Upload through the form, watch the card go from baking to ready without a
reload, open the detail view, turn the object, see errors, delete it."""
from __future__ import annotations

import shutil
import time

import pytest
from service_server import Server

KEY = "page-test-key"
INSTALL = "apt-get install -y chromium chromium-driver"


def _start_browser():
    """Headless Chromium, or pytest.fail saying why no browser could be started."""
    try:
        from selenium import webdriver
        from selenium.common.exceptions import WebDriverException
    except ImportError:
        pytest.fail("no browser can be started: the selenium package is missing (make install)")
    binary, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not binary or not driver:
        pytest.fail(f"no browser can be started: chromium and chromedriver are not installed ({INSTALL})")
    opts = webdriver.ChromeOptions()
    opts.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1280,1000"):
        opts.add_argument(arg)
    try:
        return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=driver))
    except WebDriverException as exc:
        pytest.fail(f"no browser can be started: Chromium failed to launch: {exc.msg}")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    # A key for writes; reads (the page, listings, thumbnails) open, as a shared library runs.
    srv = Server(tmp_path_factory.mktemp("page") / "cache", "--workers", "1", "--no-seed",
                 "--api-key", KEY, "--public-read")
    try:
        srv.wait_ready()
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def browser():
    b = _start_browser()
    yield b
    b.quit()


def wait(pred, timeout=90.0, what="condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = pred()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what() if callable(what) else what}")


def _alert(b):
    from selenium.common.exceptions import NoAlertPresentException
    try:
        alert = b.switch_to.alert
        alert.text  # noqa: B018 (raises when there is none)
        return alert
    except NoAlertPresentException:
        return None


def test_zip_with_several_entry_points_offers_them(server, browser, assets, tmp_path):
    """A zip of two models: the 422's candidates are offered in the form, and the upload that
    names the chosen one makes a card of that model."""
    import zipfile

    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    b = browser
    b.get(server.url + "/")
    find = lambda css: b.find_element(By.CSS_SELECTOR, css)  # noqa: E731
    kit = tmp_path / "kit.zip"
    with zipfile.ZipFile(kit, "w") as zf:
        zf.write(assets / "gltf/Duck.glb", "duck.glb")
        zf.write(assets / "gltf/BoxTextured.glb", "other.glb")
    assert not find("#main").is_displayed()
    find("#key").send_keys(KEY)
    find("#file").send_keys(str(kit))
    find("#send").click()
    wait(lambda: "2 entry points" in find("#msg").text, 30, lambda: f"the choice (page says {find('#msg').text!r})")
    choice = Select(find("#main"))
    assert find("#main").is_displayed()
    assert [o.text for o in choice.options] == ["duck.glb", "other.glb"]
    choice.select_by_visible_text("other.glb")
    find("#send").click()
    wait(lambda: "uploaded" in find("#msg").text, 60, lambda: f"the upload (page says {find('#msg').text!r})")
    assert not find("#main").is_displayed()
    listed = server.client.get("/assets").json()["assets"]
    assert [(a["name"], a["triangles"]) for a in listed] == [("kit.zip", 12)], listed  # the box, not the duck
    r = server.client.delete(f"/assets/{listed[0]['id']}", headers={"Authorization": f"Bearer {KEY}"})
    assert r.status_code == 200, r.text
    wait(lambda: not server.client.get("/assets").json()["assets"], 30, "the kit to be deleted")
    b.execute_script("sessionStorage.clear()")  # the next test starts without the key


def test_upload_watch_open_turn_delete(server, browser, assets, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    b = browser
    b.get(server.url + "/")
    find = lambda css: b.find_element(By.CSS_SELECTOR, css)  # noqa: E731
    # Record every status a card shows, and mark the page: a reload would lose the mark.
    b.execute_script("""
        window.__mark = 1; window.__statuses = [];
        new MutationObserver(ms => ms.forEach(m => {
          if (m.attributeName === 'data-status') window.__statuses.push(m.target.dataset.status);
          m.addedNodes.forEach(n => n.dataset && n.dataset.status && window.__statuses.push(n.dataset.status));
        })).observe(document.getElementById('grid'), {subtree: true, childList: true, attributes: true});""")

    # An upload without the key is refused, and the page says so.
    find("#file").send_keys(str(assets / "gltf/Duck.glb"))
    find("#send").click()
    wait(lambda: "error 401" in find("#msg").text, 30, "the 401 to be shown")

    # With the key: progress, then a card that goes baking -> ready without a reload.
    find("#key").send_keys(KEY)
    find("#file").send_keys(str(assets / "gltf/Duck.glb"))
    find("#send").click()
    card = wait(lambda: b.find_elements(By.CSS_SELECTOR, ".card"), 30, "a card")[0]
    wait(lambda: card.get_attribute("data-status") == "ready", 120, "the card to be ready")
    wait(lambda: b.execute_script("const i = document.querySelector('.card img');"
                                  "return i && i.complete && i.naturalWidth > 0"), 60, "the thumbnail")
    statuses = b.execute_script("return window.__statuses")
    assert statuses[0] == "baking" and "ready" in statuses, statuses
    assert b.execute_script("return window.__mark") == 1  # no reload happened

    # A bad file: the error is shown, not "uploading..." forever.
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00" + b"\x00" * 20)
    find("#file").send_keys(str(bad))
    find("#send").click()
    wait(lambda: find("#msg").text.startswith("error 4"), 30, "the upload error")
    assert "broken.glb" in find("#msg").text

    # Detail view: the still, the plan in words, then the turntable frames.
    card.click()
    wait(lambda: find("#detail").get_attribute("open") is not None, 10, "the detail view")
    canvas = find("#canvas")
    wait(lambda: canvas.get_attribute("data-state") == "ready", 60, "the still")
    plan = find("#d-plan").text
    assert plan.startswith("Method auto") and "Lit by studio" in plan and "yaw 35" in plan
    assert find("#d-download").get_attribute("href").startswith("blob:")
    wait(lambda: canvas.get_attribute("data-frames") == "24", 120,
         lambda: f"the turntable frames (page says: {find('#hint').text!r} {find('#d-error').text!r})")

    # Drag to turn: other frames are drawn while dragging; on release the yaw moves and the
    # still is rendered again.
    before = b.execute_script("return arguments[0].toDataURL()", canvas)
    chain = ActionChains(b).click_and_hold(canvas).move_by_offset(-60, 0).move_by_offset(-60, 0)
    chain.perform()
    assert canvas.get_attribute("data-frame") not in (None, "0")
    assert b.execute_script("return arguments[0].toDataURL()", canvas) != before
    ActionChains(b).release().perform()
    wait(lambda: find("#c-yaw").get_attribute("value") != "35", 10, "the yaw to follow the drag")
    wait(lambda: canvas.get_attribute("data-state") == "ready", 60, "the re-render")

    # A control change re-renders with the new parameter (environment panel kept).
    b.execute_script("const s = document.getElementById('c-background'); s.value = 'env';"
                     "s.dispatchEvent(new Event('change', {bubbles: true}))")
    wait(lambda: "background env" in find("#d-plan").text, 60, "the plan of the new render")

    # Delete: without the key the page asks for it; refused, the 401 is shown; given, the
    # card goes.
    b.execute_script("document.getElementById('key').value = ''; sessionStorage.clear()")
    find("#d-delete").click()
    b.switch_to.alert.accept()  # "Delete Duck.glb?"
    wait(lambda: _alert(b), 10, "the API key prompt").dismiss()
    wait(lambda: "error 401" in find("#d-error").text, 10, "the delete error")
    find("#d-delete").click()
    b.switch_to.alert.accept()
    prompt = wait(lambda: _alert(b), 10, "the API key prompt")
    prompt.send_keys(KEY)
    prompt.accept()
    wait(lambda: not b.find_elements(By.CSS_SELECTOR, ".card"), 10, "the card to go")
    assert server.client.get("/assets").json()["assets"] == []
