"""The work explorer in headless Chromium: hover three samples and read every structure's counts
equal to the work layers, click one and read its rays equal to explain's, no request to another
host and no console error. The slow test makes the documentation's screenshots of the stadium
(docs/_static/explore-*.png)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from support import headless_chromium

pytest.importorskip("dash")

from raykernel.explorer.model import settings  # noqa: E402
from raykernel.rendering.explain import explain, text  # noqa: E402
from raykernel.rendering.render import render  # noqa: E402
from raykernel.scene.loading import load  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ACCELS = ["octree", "grid"]


@pytest.fixture(scope="module")
def browser():
    driver = headless_chromium("1400,1000", ("browser", "performance"))
    yield driver
    driver.quit()


GIVE_UP = 120       # seconds: a page that never answers fails rather than hangs (not a speed check)


def _until(driver, script, *args, give_up=GIVE_UP):
    """What `script` returns once it is truthy (the page answers through its own requests)."""
    from selenium.common.exceptions import JavascriptException
    end = time.monotonic() + give_up
    while time.monotonic() < end:
        try:
            value = driver.execute_script(script, *args)
        except JavascriptException:     # the element is not there yet: Dash draws the layout after the load
            value = None
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"the page never answered: {script}")


def _emit(driver, graph: str, event: str, x: int, y: int, curve: int) -> None:
    driver.execute_script(
        "var gd = document.getElementById(arguments[0]).querySelector('.js-plotly-plot');"
        "gd.emit(arguments[1], {points: [{x: arguments[2], y: arguments[3], curveNumber: arguments[4],"
        " pointNumber: [arguments[3], arguments[2]]}]});", graph, event, x, y, curve)


@pytest.fixture(scope="module")
def page(browser):
    from raykernel.explorer.server import start
    scene = load("spd:tetra:2")
    server = start(scene, "spd:tetra:2", settings(ACCELS, 24), port=0, timed=False)
    browser.get(server.url)
    _tab_rendered(server)
    _until(browser, "return document.querySelectorAll('#layers .heatmaplayer, #layers .hm').length > 0 || "
                    "document.querySelectorAll('#layers .js-plotly-plot .main-svg').length > 0")
    _until(browser, "return document.getElementById('status').textContent.indexOf('shown') >= 0")
    yield browser, server, scene
    server.stop()


def _tab_rendered(server) -> None:
    """Until the browser's tab (its session, made by its first request) has rendered in full."""
    end = time.monotonic() + GIVE_UP
    while server.renderer is None and time.monotonic() < end:
        time.sleep(0.05)
    assert server.renderer is not None and server.renderer.wait(1) == "full"


def test_hover_three_samples_reads_the_work_layers(page):
    browser, server, scene = page
    refs = {a: render(scene, accel=a, resolution=24, work=True).work for a in ACCELS}
    for x, y in ((3, 4), (12, 12), (20, 9)):
        _emit(browser, "layers", "plotly_hover", x, y, 1)
        counts = _until(browser, "var t = document.getElementById('hover-table');"
                                 "return t && t.getAttribute('data-x') == arguments[0] && "
                                 "t.getAttribute('data-y') == arguments[1] && t.getAttribute('data-counts');", x, y)
        assert json.loads(counts) == {a: {k: int(v[y, x]) for k, v in refs[a].items()} for a in ACCELS}


def test_click_a_sample_lists_its_rays_as_explain_does(page):
    browser, server, scene = page
    _emit(browser, "layers", "plotly_click", 12, 11, 1)
    want = text(explain(scene, 12, 11, accel=ACCELS[0], resolution=24))
    got = _until(browser, "var t = document.getElementById('rays').textContent;"
                          "return t.indexOf('pixel (12, 11)') == 0 && t;")
    assert got == want
    _until(browser, "return document.getElementById('node').textContent.indexOf('sample (12, 11)') >= 0")


def test_click_a_box_lights_the_samples_whose_walks_entered_it(page):
    from support import entered_masks
    browser, server, scene = page
    run = server.renderer.snapshot()[1].runs[ACCELS[0]]
    box = int(np.argsort(-run.use["visits"], kind="stable")[len(run.boxes) // 50])
    _emit_box(browser, box)
    lit = _until(browser, "var e = document.querySelector('#lit span');"
                          "return e && e.textContent.indexOf('box ' + arguments[0] + ' ') >= 0 && e.getAttribute('data-lit');",
                 box)
    masks, _ = entered_masks(scene, ACCELS[0], 24, np.array([box]))
    assert json.loads(lit) == np.flatnonzero(masks[0]).tolist() != []


def _emit_box(browser, box: int) -> None:
    # a click on the marker at the box's centre (the second trace), as plotly reports it
    browser.execute_script(
        "var gd = document.getElementById('structure').querySelector('.js-plotly-plot');"
        "var trace = gd.data[1], k = trace.customdata.indexOf(arguments[0]);"
        "gd.emit('plotly_click', {points: [{curveNumber: 1, pointNumber: k, data: trace,"
        " customdata: arguments[0]}]});", box)


def test_a_bad_spec_shows_an_error_then_a_changed_parameter_renders_as_a_fresh_render(page):
    from selenium.webdriver.common.keys import Keys
    browser, server, scene = page
    accels = browser.find_element("id", "accels")
    button = browser.find_element("id", "render")
    accels.send_keys(Keys.CONTROL, "a")         # typed over, as a user would: React sees each key
    accels.send_keys("octree(depth=nine)")
    button.click()
    error = _until(browser, "var t = document.getElementById('error').textContent; return t.length > 0 && t;")
    assert "depth" in error
    accels.send_keys(Keys.CONTROL, "a")
    accels.send_keys("octree(depth=2)\ngrid")
    button.click()
    _until(browser, "var t = document.getElementById('status').textContent;"
                    "return t.indexOf('shown: octree(depth=2), grid') >= 0 && t.indexOf('(full') >= 0;")
    assert browser.find_element("id", "error").text == ""
    ref = render(scene, accel="octree(depth=2)", resolution=24, work=True).work
    for x, y in ((12, 12), (5, 17)):
        _emit(browser, "layers", "plotly_hover", x, y, 1)
        counts = _until(browser, "var t = document.getElementById('hover-table');"
                                 "return t && t.getAttribute('data-x') == arguments[0] && "
                                 "t.getAttribute('data-y') == arguments[1] && t.getAttribute('data-counts');", x, y)
        assert json.loads(counts)["octree(depth=2)"] == {k: int(v[y, x]) for k, v in ref.items()}


def test_no_console_error_and_nothing_from_another_host(page):
    browser, server, _ = page
    errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    host = server.url.split("/")[2]
    urls = []
    for entry in browser.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message["method"] == "Network.requestWillBeSent":
            urls.append(message["params"]["request"]["url"])
    assert urls and all(u.split("/")[2] == host or u.startswith(("data:", "blob:")) for u in urls), urls


@pytest.mark.slow
def test_screenshots_of_the_stadium_for_the_docs(browser):
    """docs/guide/explorer.md's pictures: the stadium with the octree, the BVH and the grid."""
    from raykernel.explorer.server import start
    scene = load("scene:stadium")
    server = start(scene, "scene:stadium", settings(["octree", "bvh", "grid"], 64), port=0)
    try:
        browser.set_window_size(1400, 1000)
        browser.get(server.url)
        _tab_rendered(server)
        _until(browser, "return document.getElementById('status').textContent.indexOf('(full') >= 0")
        _until(browser, "return document.getElementById('hottest-table')")
        ex = server.renderer.snapshot()[1]
        y, x = np.unravel_index(np.argmax(ex.layer("octree", "tests.total")), ex.shape)
        _emit(browser, "layers", "plotly_hover", int(x), int(y), 1)
        _until(browser, "return document.getElementById('hover-table')")
        out = ROOT / "docs" / "_static"
        _shot(browser, "layers", out / "explore-layers.png", 0)
        _emit(browser, "layers", "plotly_click", int(x), int(y), 1)
        # explaining a sample of the stadium builds its structure again (and compiles the probed
        # kernel for its geometry once): minutes on a small machine
        _until(browser, "return document.getElementById('node').textContent.indexOf('entered') >= 0", give_up=1500)
        _shot(browser, "structure", out / "explore-structure.png", 0)
        _shot(browser, "time", out / "explore-time.png", 0)
    finally:
        server.stop()


def _shot(browser, element: str, path: Path, _) -> None:
    browser.execute_script("document.getElementById(arguments[0]).scrollIntoView();", element)
    time.sleep(1.0)         # plotly finishes drawing after its data arrived
    browser.find_element("id", element).screenshot(str(path))
