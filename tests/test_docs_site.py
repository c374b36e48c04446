"""The documentation site: built with warnings as errors, then every page opened in headless Chromium.

    make test-docs        (pytest -m docs tests/test_docs_site.py)

Every page must load with no console error, every image must have decoded (natural width above
0), and every link inside the site must reach a page that exists, and the anchor in it where it
names one. The build runs the gallery's examples, so the site's images are made here too.
"""

from __future__ import annotations

import functools
import http.server
import re
import subprocess
import sys
import threading
from pathlib import Path
from urllib.parse import unquote, urljoin, urlsplit

import pytest
from support import headless_chromium

pytestmark = pytest.mark.docs

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip("sphinx", reason="the docs extra: pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site") / "html"
    run = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                          str(ROOT / "docs"), str(out)], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, f"sphinx-build failed:\n{run.stdout[-4000:]}\n{run.stderr[-8000:]}"
    return out


@pytest.fixture(scope="module")
def server(site):
    handler = functools.partial(_QuietHandler, directory=str(site))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    httpd.shutdown()
    httpd.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture(scope="module")
def browser():
    driver = headless_chromium("1280,900", ("browser",))
    yield driver
    driver.quit()


def _pages(site: Path) -> list[str]:
    return sorted(str(p.relative_to(site)) for p in site.rglob("*.html"))


def test_the_site_has_every_part(site):
    pages = set(_pages(site))
    for page in ("index.html", "getting-started.html", "newsletter.html", "api.html", "benchmarks.html",
                 "design.html", "adding-a-kind.html", "auto_examples/index.html", "guide/scenes.html",
                 "guide/rendering.html", "guide/structures.html", "guide/statistics.html", "guide/comparing.html",
                 "guide/animation.html", "guide/explorer.html", "guide/ray-casting.html", "guide/performance.html"):
        assert page in pages, f"{page} is missing from the site"
    examples = sorted(ROOT.glob("examples/gallery/plot_*.py"))
    assert examples
    for example in examples:
        assert f"auto_examples/{example.stem}.html" in pages
        images = list((site / "_images").glob(f"sphx_glr_{example.stem}_0*.png"))
        assert images, f"the gallery made no picture for {example.name}"
    api = (site / "api.html").read_text()
    for name in ("raykernel.load", "raykernel.render", "raykernel.RayScene.intersect", "raykernel.Hits",
                 "raykernel.trimesh.RayMeshIntersector", "raykernel.cluster.Cluster",
                 "raykernel.analysis.costmodel.CostModel"):
        assert f'id="{name}"' in api, f"the API page does not document {name}"


def test_every_page_loads_with_its_images_and_no_console_error(site, server, browser):
    problems = []
    for page in _pages(site):
        browser.get(server + page)
        browser.execute_script("window.scrollTo(0, document.body.scrollHeight)")   # any lazy image
        broken = browser.execute_script(
            "return Array.from(document.images)"
            ".filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.getAttribute('src'))")
        if broken:
            problems.append(f"{page}: images that did not load: {broken}")
        errors = [e["message"] for e in browser.get_log("browser") if e["level"] == "SEVERE"]
        if errors:
            problems.append(f"{page}: console errors: {errors}")
    assert not problems, "\n".join(problems)


def test_internal_links_resolve(site, server):
    problems = []
    ids: dict[Path, set] = {}
    for page in _pages(site):
        text = (site / page).read_text()
        for href in re.findall(r'<a\s[^>]*href="([^"]+)"', text):
            url = urljoin(server + page, href.replace("&amp;", "&"))
            if not url.startswith(server):
                continue                                # another site, or mailto:
            parts = urlsplit(url)
            target = site / unquote(parts.path[len(urlsplit(server).path):])
            if target.is_dir():
                target = target / "index.html"
            if not target.exists():
                problems.append(f"{page}: {href} -> no such file")
                continue
            if parts.fragment and target.suffix == ".html":
                if target not in ids:
                    ids[target] = set(re.findall(r'\sid="([^"]+)"', target.read_text()))
                if unquote(parts.fragment) not in ids[target]:
                    problems.append(f"{page}: {href} -> no anchor #{parts.fragment}")
    assert not problems, "\n".join(problems[:50])


def test_a_broken_link_is_found(tmp_path):
    """The link check itself can fail: a page linking to a missing page and a missing anchor."""
    (tmp_path / "a.html").write_text('<a href="b.html#here">b</a><a href="missing.html">m</a><a href="b.html#nowhere">n</a>')
    (tmp_path / "b.html").write_text('<h1 id="here">b</h1>')
    with pytest.raises(AssertionError, match=r"missing.html -> no such file(.|\n)*b.html#nowhere -> no anchor"):
        test_internal_links_resolve(tmp_path, "http://127.0.0.1:1/")
