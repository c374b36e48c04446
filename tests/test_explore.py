"""The work explorer (raykernel/explore): its data model against brute-force recomputation from
the per-sample data and fresh renders, and the app through an HTTP client against a server in a
thread (page and callbacks behind the token, nothing from another host, the renderer's
cancellation), and `raykernel explore` as a process."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

pytest.importorskip("dash")

from raykernel.errors import OptionError  # noqa: E402
from raykernel.explorer import quality as q  # noqa: E402
from raykernel.explorer.model import Exploration, Run, explore_scene, read_settings, settings  # noqa: E402
from raykernel.rendering.explain import explain, text  # noqa: E402
from raykernel.rendering.render import TILE, render  # noqa: E402
from raykernel.rendering.structure import structure_use  # noqa: E402
from raykernel.scene.loading import load  # noqa: E402
from support import entered_masks  # noqa: E402

SCENE = "spd:tetra:2"
RES = 24
ACCELS = ["octree", "bvh(leaf=1,width=2)"]


@pytest.fixture(scope="module")
def scene():
    return load(SCENE)


@pytest.fixture(scope="module")
def ex(scene):
    return explore_scene(scene, settings(ACCELS, RES), SCENE)


# --- the data model --------------------------------------------------------------------------

def test_settings_name_the_bad_value():
    for kw, word in ((dict(accels=["nosuch("]), "nosuch"), (dict(resolution=1), "resolution"),
                     (dict(eye=(1, 2)), "eye"), (dict(angle=200), "angle"), (dict(counter="tests.nope"), "tests.nope"),
                     (dict(accels=[]), "accels"), (dict(accels=["auto"]), "auto")):
        with pytest.raises(OptionError, match=re.escape(word)):
            settings(**kw)
    s = settings(["grid", "bvh"], 16, eye=(1, 2, 3))
    assert read_settings(s.to_json()) == s
    with pytest.raises(OptionError, match="settings"):
        read_settings('{"path": "/etc/passwd"}')


def test_layers_and_image_equal_a_fresh_render(scene, ex):
    for accel in ACCELS:
        ref = render(scene, accel=accel, resolution=RES, work=True)
        run = ex.runs[accel]
        assert set(run.layers) == set(ref.work)
        assert all(np.array_equal(run.layers[k], ref.work[k]) for k in ref.work)
        assert np.array_equal(run.image, ref.image)


def test_each_sample_use_adds_up_to_the_render_use(scene, ex):
    """Summed over the samples, each box's visits and tests are those of structure --use's whole
    render (another code path); summed over the boxes, each sample's visits are its cells.visited."""
    for accel in ACCELS:
        run = ex.runs[accel]
        boxes, use, _ = structure_use(scene, accel, resolution=RES)
        assert len(boxes) == len(run.boxes) > 1
        for what in ("visits", "tests"):
            assert np.array_equal(run.use[what], use[what])
        s = run.samples
        per_row = np.zeros(int(run.rows.max()) + 1, np.int64)
        np.add.at(per_row, s.rows, s.visits)
        assert np.array_equal(per_row[run.rows], use["visits"])
        owner = np.repeat(np.arange(len(s.indptr) - 1), np.diff(s.indptr))
        per_sample = np.bincount(owner, weights=s.visits, minlength=len(s.indptr) - 1).astype(np.int64)
        assert np.array_equal(per_sample.reshape(run.shape), run.layers["cells.visited"])


def test_node_masks_equal_a_brute_force_check(scene, ex):
    for accel in ACCELS:
        run = ex.runs[accel]
        order = np.argsort(-run.use["visits"], kind="stable")
        wanted = np.unique(np.concatenate([order[:4], order[len(order) // 2:len(order) // 2 + 2], order[-1:]]))
        masks, tile_visits = entered_masks(scene, accel, RES, wanted)
        for k, box in enumerate(wanted):
            got = run.node_mask(int(box))
            assert np.array_equal(got > 0, masks[k]), (accel, box)
            assert got[:TILE, :TILE].sum() == tile_visits[k]
        assert masks.any()


def test_a_4_wide_bvh_says_its_boxes_are_walked_binary_and_its_layers_are_not(scene, ex):
    """bvh renders 4-wide, its boxes walked binary: the page says so, and its visits summed over the
    boxes are bvh(width=2)'s cells.visited, not its own layers' (which hold fewer)."""
    wide = explore_scene(scene, settings(["bvh(leaf=1)"], RES), SCENE).runs["bvh(leaf=1)"]
    binary = ex.runs["bvh(leaf=1,width=2)"]
    assert "4-wide BVH" in wide.note and "4-wide" not in binary.note and "4-wide" not in ex.runs["octree"].note
    assert np.array_equal(wide.use["visits"], binary.use["visits"])
    assert wide.layers["cells.visited"].sum() < binary.layers["cells.visited"].sum() == binary.use["visits"].sum()


def test_a_lazy_structure_has_node_masks_and_tile_times_of_itself_as_its_render_left_it(scene):
    """lazyoctree and rc: the boxes are those structure --use draws after its refining render,
    and every box's mask equals the brute-force check run on the structure a render of its own
    (render's job loop, two threads) left."""
    from raykernel.rendering.render import RenderJob
    for accel in ("lazyoctree", "rc"):
        run = explore_scene(scene, settings([accel], RES), SCENE).runs[accel]
        assert run.samples is not None and run.tile_seconds.shape == (2, 2) and (run.tile_seconds > 0).all()
        assert "as its render left it" in run.note
        boxes, use, _ = structure_use(scene, accel, resolution=RES)
        assert np.array_equal(run.boxes.corners, boxes.corners) and np.array_equal(run.use["refined"], use["refined"])
        job = RenderJob(scene, accel=accel, resolution=RES, work=True)
        for p in range(len(job.passes)):
            job.trace_pass(p, 2)
            job.end_pass(p)
        wanted = np.arange(len(run.boxes))
        masks, tile_visits = entered_masks(scene, accel, RES, wanted, frozen=job)
        for k, box in enumerate(wanted):
            got = run.node_mask(int(box))
            assert np.array_equal(got > 0, masks[k]), (accel, box)
            assert got[:TILE, :TILE].sum() == tile_visits[k]
        assert masks.any()
    assert use["refined"].sum() == 0 and run.use["refined"].sum() == 0      # rc refines no octree cells
    lazy = explore_scene(scene, settings(["lazyoctree"], RES), SCENE).runs["lazyoctree"]
    assert lazy.use["refined"].sum() > 0


def test_a_pixel_boxes_are_those_its_masks_hold(ex):
    run = ex.runs["octree"]
    y, x = np.unravel_index(np.argmax(run.layers["cells.visited"]), run.shape)
    visited, tested = run.pixel_boxes(int(x), int(y))
    assert len(visited) and set(tested) <= set(visited)
    for box in range(len(run.boxes)):
        assert (run.node_mask(box)[y, x] > 0) == (box in set(visited))
    assert all(run.node_mask(int(b), "tests")[y, x] > 0 for b in tested)


def test_hottest_counts_and_ranges_against_brute_force(ex):
    h, w = ex.shape
    name = "tests.total"
    stack = {a: ex.layer(a, name) for a in ACCELS}
    hot = ex.hottest(name, 7)
    top = max(stack[a].max() for a in ACCELS)
    assert max(hot[0][2].values()) == top
    for x, y, values in hot:
        assert values == {a: int(stack[a][y, x]) for a in ACCELS}
    worst = sorted((max(int(stack[a][j, i]) for a in ACCELS) for j in range(h) for i in range(w)), reverse=True)
    assert [max(v.values()) for _, _, v in hot] == worst[:7]
    for x, y in ((0, 0), (w - 1, h - 1), (w // 2, h // 3)):
        counts = ex.counts_at(x, y)
        assert all(counts[a][k] == int(ex.runs[a].layers[k][y, x]) for a in ACCELS for k in ex.runs[a].layers)
    lo, hi = 2, 6
    mask = ex.in_range("octree", name, lo, hi)
    assert np.array_equal(mask, np.vectorize(lambda v: lo <= v <= hi)(stack["octree"]))
    with pytest.raises(OptionError, match="outside"):
        ex.counts_at(w, 0)


def _fake(layers: dict) -> Exploration:
    runs = {a: Run(a, np.zeros(v.shape + (3,)), {"tests.total": v}, {}, None, {}, np.zeros(0), None, None)
            for a, v in layers.items()}
    return Exploration("fake", settings(list(layers)), runs)


def test_the_scale_is_log_where_values_span_decades():
    wide = _fake({"grid": np.array([[5, 75840]]), "bvh": np.array([[0, 40]])})
    assert wide.scale("tests.total") == (0.0, 75840.0, "log")
    narrow = _fake({"grid": np.array([[5, 80]]), "bvh": np.array([[0, 40]])})
    assert narrow.scale("tests.total")[2] == "linear"


def test_node_quality_against_hand_counts(ex):
    boxes = ex.runs["octree"].boxes
    got = q.quality(boxes)
    assert (got["overlap"] == 0).all()          # an octree's boxes tile space
    lo, hi = boxes.corners.min(axis=1), boxes.corners.max(axis=1)
    root = np.prod(hi[0] - lo[0])
    for k in range(len(boxes)):
        s = hi[k] - lo[k]
        area = 2 * (s[0] * s[1] + s[1] * s[2] + s[2] * s[0])
        assert np.isclose(got["area"][k], area)
    assert root > 0
    bvh = ex.runs["bvh(leaf=1,width=2)"].boxes
    b = q.quality(bvh)
    leaf = bvh.leaf == 1
    s = bvh.corners.max(axis=(0, 1)) - bvh.corners.min(axis=(0, 1))
    whole = 2 * (s[0] * s[1] + s[1] * s[2] + s[2] * s[0])
    assert np.isclose(b["sah"].sum(), (b["area"][~leaf].sum() + (b["area"][leaf] * bvh.items[leaf]).sum()) / whole)
    depths, counts = q.depth_histogram(bvh)
    assert counts.sum() == leaf.sum() and set(depths) == set(bvh.depth[leaf])
    sizes, counts = q.leaf_size_histogram(bvh)
    assert (sizes * counts).sum() == bvh.items[leaf].sum()


# --- the app, over HTTP -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def server(scene):
    from raykernel.explorer.server import start
    srv = start(scene, SCENE, settings(ACCELS, RES), port=0, timed=False)
    srv.test_session = _session(srv)          # the page's, as a load of it gives
    _version(srv)                               # its first request: its renderer begins
    assert srv.sessions.get(srv.test_session).wait(1) == "full"
    yield srv
    srv.stop()


def _get(url):
    with urllib.request.urlopen(url) as r:
        return r.status, r.read().decode("utf-8", "replace")


def _session(server):
    """A new page load's session id: the data of the layout's store "session"."""
    def find(node):
        if isinstance(node, dict):
            if node.get("props", {}).get("id") == "session":
                return node["props"]["data"]
            return next((f for f in map(find, node.values()) if f), None)
        if isinstance(node, list):
            return next((f for f in map(find, node) if f), None)
        return None
    return find(json.loads(_get(server.url + "_dash-layout")[1]))


PAGE = object()     # call's session: the module's page


def call(server, output, inputs, state=(), changed=None, session=PAGE):
    """A callback through Dash's own endpoint, as the page calls it; `output` names its key. The
    page's session id is sent as the last State, as the page sends it (session: another's)."""
    app = server.app
    key = next(k for k in app.callback_map if k.split("@")[0] == output or f".{output}." in k)
    spec = app.callback_map[key]
    if len(state) == len(spec["state"]) - 1 and spec["state"][-1]["id"] == "session":
        state = [*state, server.test_session if session is PAGE else session]
    outs = key.strip(".").split("...") if key.startswith("..") else [key.split("@")[0]]
    outputs = [dict(zip(("id", "property"), o.rsplit(".", 1))) for o in outs]
    body = {"output": key, "outputs": outputs if key.startswith("..") else outputs[0],
            "inputs": [{**d, "value": v} for d, v in zip(spec["inputs"], inputs)],
            "state": [{**d, "value": v} for d, v in zip(spec["state"], state)],
            "changedPropIds": changed or [f"{spec['inputs'][0]['id']}.{spec['inputs'][0]['property']}"]}
    body["inputs"] = [{k: v for k, v in d.items() if k in ("id", "property", "value")} for d in body["inputs"]]
    body["state"] = [{k: v for k, v in d.items() if k in ("id", "property", "value")} for d in body["state"]]
    req = urllib.request.Request(server.url + "_dash-update-component", json.dumps(body).encode(),
                                 {"Content-Type": "application/json"})
    with urllib.request.urlopen(req) as r:
        text = r.read().decode()
    return json.loads(text)["response"] if text else {}


def _mine(server):
    """The Renderer of the module's page (its session's)."""
    return server.sessions.get(server.test_session)


def _version(server, session=PAGE):
    return call(server, "version.data", [1], [-1], session=session)["version"]["data"]


def test_the_page_needs_its_token_and_fetches_nothing_from_elsewhere(server):
    status, page = _get(server.url)
    assert status == 200 and "raykernel explore" in page
    root = server.url.split("/", 3)[:3]
    for path in ("", "_dash-layout", "_dash-dependencies", server.url.split("/")[3] + "x/"):
        with pytest.raises(urllib.error.HTTPError) as e:
            _get("/".join(root) + "/" + path)
        assert e.value.code == 404
    assert not re.findall(r"https?://", page)
    sources = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert sources and all(s.startswith("/" + server.url.split("/")[3] + "/") for s in sources)
    for s in sources:
        assert _get("/".join(root) + s)[0] == 200         # every script the page loads, served here
    layout = _get(server.url + "_dash-layout")[1]
    assert "http://" not in layout and "https://" not in layout


def test_hover_reads_every_structure_count(server, ex):
    v = _version(server)
    for x, y in ((1, 2), (12, 12), (23, 7)):
        out = call(server, "hover.children", [{"points": [{"x": x, "y": y}]}, None])
        table = out["hover"]["children"]["props"]
        counts = json.loads(table["data-counts"])
        assert (table["data-x"], table["data-y"]) == (x, y)
        assert counts == {a: {k: int(val[y, x]) for k, val in ex.runs[a].layers.items()} for a in ACCELS}
    assert v >= 1


def test_two_tabs_at_once_each_get_their_answers(server, ex):
    # two pages polling and hovering at the same time: each call answers its own pixel
    from concurrent.futures import ThreadPoolExecutor
    pixels = [(x, y) for x in range(0, 24, 5) for y in range(0, 24, 7)]
    other = _session(server)
    _version(server, other)
    assert server.sessions.get(other).wait(1) == "full"

    def tab(job):
        pixels, sid = job
        seen = []
        for x, y in pixels:
            call(server, "status.children", [1], [None], session=sid)                # the page's poll
            table = call(server, "hover.children", [{"points": [{"x": x, "y": y}]}, None],
                         session=sid)["hover"]["children"]
            seen.append((table["props"]["data-x"], table["props"]["data-y"], json.loads(table["props"]["data-counts"])))
        return seen

    with ThreadPoolExecutor(2) as pool:
        tabs = list(pool.map(tab, [(pixels, server.test_session), (pixels[::-1], other)]))
    for seen, asked in zip(tabs, [pixels, pixels[::-1]]):
        assert [(x, y) for x, y, _ in seen] == asked
        for x, y, counts in seen:
            assert counts == {a: {k: int(val[y, x]) for k, val in ex.runs[a].layers.items()} for a in ACCELS}


def _layer_over_http(server, sid, accel, name="tests.total"):
    v = _version(server, sid)
    fig = call(server, "layers.figure", [v, name, "auto", None], session=sid)["layers"]["figure"]
    heat = {t["name"]: t for t in fig["data"] if t["type"] == "heatmap"}
    return _array(heat[accel]["customdata"])


def test_two_sessions_render_their_own_structures_and_a_forged_id_reads_nothing(scene):
    """Two page loads, each its own session: different structures and resolutions, both live,
    each page's layers and hover those of a fresh render of its own settings; the memory budget
    is split so that together they hold it; a fifth tab closes the least recently used; an id
    the server did not sign reads nothing and makes no session."""
    from raykernel.aggregates.memory import memory_limit
    from raykernel.explorer.jobs import MAX_SESSIONS
    from raykernel.explorer.server import start
    total = 4 * 600 * 1024      # each tab's share (600 KiB) is too small for the octree's 640 KiB
    srv = start(scene, SCENE, settings(ACCELS, RES), port=0, timed=False, max_memory=total)
    try:
        a, b = _session(srv), _session(srv)
        assert a != b
        for sid in (a, b):      # the first request of each (the server's settings) needs more than its share
            _version(srv, sid)
            assert srv.sessions.get(sid).wait(1) == "failed"
            assert "memory budget" in call(srv, "version.data", [1], [-1], session=sid)["error"]["children"]
        first = call(srv, "error.children", [1], ["octree(depth=2)", 20, "", "", "", None, "tests.total"], session=a)
        assert first["error"]["children"] == ""
        call(srv, "error.children", [1], ["grid\nbvh(leaf=1,width=2)", 16, "", "", "", None, "tests.total"], session=b)
        ra, rb = srv.sessions.get(a), srv.sessions.get(b)
        assert ra is not rb and ra.wait(ra.generation) == "full" and rb.wait(rb.generation) == "full"
        assert explore_scene(scene, settings(["octree"], RES), max_memory=total, timed=False).runs   # fits the whole
        assert ra.max_memory == rb.max_memory == memory_limit(total) // MAX_SESSIONS
        wanted = {a: ({"octree(depth=2)": 20}), b: {"grid": 16, "bvh(leaf=1,width=2)": 16}}
        for sid in (a, b, a):           # both live: b's render did not replace a's view
            for accel, res in wanted[sid].items():
                ref = render(scene, accel=accel, resolution=res, work=True).work
                assert np.array_equal(_layer_over_http(srv, sid, accel).reshape(res, res), ref["tests.total"])
                table = call(srv, "hover.children", [{"points": [{"x": 3, "y": 5}]}, None], session=sid)
                counts = json.loads(table["hover"]["children"]["props"]["data-counts"])
                assert set(counts) == set(wanted[sid]) and counts[accel] == {k: int(v[5, 3]) for k, v in ref.items()}
        # forged: a's id with its signature changed, one unsigned, none
        forged = [a[:-1] + ("0" if a[-1] != "0" else "1"), a.split(".")[0], "x.y", "", None]
        for sid in forged:
            poll = call(srv, "version.data", [1], [-1], session=sid)
            assert "reload the page" in poll["error"]["children"] and "version" not in poll
            assert call(srv, "layers.figure", [1, "tests.total", "auto", None], session=sid) == {}
            hover = call(srv, "hover.children", [{"points": [{"x": 3, "y": 5}]}, None], session=sid)
            assert "data-counts" not in json.dumps(hover)
            assert "rays" not in call(srv, "rays.children", [{"x": 3, "y": 5}, "grid", 1], session=sid) or \
                "click a sample" in call(srv, "rays.children", [{"x": 3, "y": 5}, "grid", 1], session=sid)["rays"]["children"]
        assert set(srv.sessions.live()) == {a, b}
        # MAX_SESSIONS at once: a fifth tab closes the one used least recently (a; b was used since)
        _version(srv, b)
        more = [_session(srv) for _ in range(MAX_SESSIONS - 1)]
        for sid in more:
            _version(srv, sid)
        assert set(srv.sessions.live()) == {b, *more}
        assert "closed to make room" in call(srv, "version.data", [1], [-1], session=a)["error"]["children"]
        assert set(srv.sessions.live()) == {b, *more}       # its poll did not take a place back
    finally:
        srv.stop()


def test_the_views_draw_on_one_scale_and_light_a_selection(server, ex):
    v = _version(server)
    out = call(server, "layers.figure", [v, "tests.total", "auto", None])
    layers = out["layers"]["figure"]
    heat = [t for t in layers["data"] if t["type"] == "heatmap"]
    assert [t["name"] for t in heat] == ACCELS
    assert all(t.get("coloraxis") == "coloraxis" for t in heat)
    assert out["counter"]["options"] == ex.layer_names()
    rows = out["hottest"]["children"]["props"]["children"][1:]
    first = [c["props"]["children"] for c in rows[0]["props"]["children"]]
    x, y, values = ex.hottest("tests.total", 1)[0]
    assert first == [x, y] + [f"{values[a]:,}" for a in ACCELS]
    sel = call(server, "selection.data", [{"range": {"x2": [3, 5]}}, None, 0], ["tests.total", "octree"],
               ["histograms.selectedData"])["selection"]["data"]
    assert sel == {"kind": "range", "accel": ACCELS[1], "counter": "tests.total", "low": 3.0, "high": 5.0}
    lit = call(server, "layers.figure", [v, "tests.total", "auto", sel])["layers"]["figure"]
    assert "tests.total in 3 to 5" in lit["layout"]["annotations"][0]["text"]
    box = call(server, "selection.data", [None, {"points": [{"customdata": 2}]}, 0], ["tests.total", "octree"],
               ["structure.clickData"])["selection"]["data"]
    assert box == {"kind": "box", "accel": "octree", "box": 2}
    mask = ex.runs["octree"].node_mask(2) > 0
    lit = call(server, "layers.figure", [v, "tests.total", "auto", box])["layers"]["figure"]
    assert f"{int(mask.sum())} samples' rays entered box 2" in lit["layout"]["annotations"][0]["text"]


def test_a_click_explains_the_sample(server, scene):
    v = _version(server)
    out = call(server, "rays.children", [{"x": 12, "y": 11}, "octree", v])
    assert out["rays"]["children"] == text(explain(scene, 12, 11, accel="octree", resolution=RES))
    fig = call(server, "structure.figure", [v, "octree", "visits", "", "", {"x": 12, "y": 11}, None])
    names = [t.get("name", "") for t in fig["structure"]["figure"]["data"]]
    assert any(n.startswith("entered (level 0)") for n in names) and any(n.startswith("ray 1: eye") for n in names)
    assert "entered" in fig["node"]["children"]


def _array(value):
    """A plotly array as it comes over the wire: a list, or typed ({"dtype", "bdata"}: base64)."""
    import base64
    if isinstance(value, dict):
        shape = [int(n) for n in str(value.get("shape", "-1")).split(",")]
        return np.frombuffer(base64.b64decode(value["bdata"]), value["dtype"]).reshape(shape)
    return np.asarray([np.nan if v is None else v for v in value], np.float64)


def test_a_click_draws_every_item_each_ray_tested(server, scene):
    """The 3D view of a clicked sample draws, for each ray, every item it tested (hit or not):
    the set explain's JSON lists, each box that of the scene's polygon (from its corners)."""
    v = _version(server)
    sets = list(scene.root.primitive_sets())
    polys = sets[0]         # spd:tetra: one set of polygons, flattened in order
    assert list(scene.root.children) == [] and len(sets) == 1
    for accel, (x, y) in (("octree", (12, 11)), ("bvh(leaf=1,width=2)", (9, 14))):
        want = json.loads(json.dumps(explain(scene, x, y, accel=accel, resolution=RES)))     # explain --json
        fig = call(server, "structure.figure", [v, accel, "visits", "", "", {"x": x, "y": y}, None])
        data = fig["structure"]["figure"]["data"]
        missed = 0
        for k, ray in enumerate(want["rays"]):
            tests = [t for step in ray["steps"] for t in step["tests"]] + ray.get("tests", [])
            missed += sum(t["t"] is None for t in tests)
            wires = [t for t in data if t.get("name", "").startswith(f"ray {k + 1}: tested (level")]
            drawn = {}
            for t in wires:
                xyz = np.stack([_array(t[a]) for a in "xyz"], axis=1).reshape(-1, 36, 3)
                for name, pts in zip(t["text"][::36], xyz):
                    drawn[name] = (np.nanmin(pts, axis=0), np.nanmax(pts, axis=0))
            assert set(drawn) == {f"{t['primitive']} {t['index']}" for t in tests}, (accel, k)
            for name, (lo, hi) in drawn.items():
                kind, i = name.split()
                corners = polys.vertices[polys.start[int(i)]:polys.start[int(i)] + polys.count[int(i)]]
                assert kind == "polygon" and np.allclose(lo, corners.min(axis=0)) and np.allclose(hi, corners.max(axis=0))
            shapes = [t for t in data if t.get("name", "").startswith(f"ray {k + 1}: tested shapes")]
            assert sum(len(_array(t["x"])) for t in shapes) == sum(int(polys.count[int(n.split()[1])]) for n in drawn)
            assert all(t["line"]["color"] == t2["color"] for t in wires for t2 in shapes)
        assert missed > 0, "the sample's rays tested no item they missed: pick another"


def test_a_bad_spec_is_an_error_in_the_page_and_the_next_good_one_renders(server, scene):
    form = [RES, "", "", "", None, "tests.total"]
    out = call(server, "error.children", [1], ["octree\nnosuch(", *form])
    assert "nosuch" in out["error"]["children"]
    out = call(server, "error.children", [2], ["bvh(leaf=1,width=2)", 20, "", "", "", None, "tests.total"])
    assert out["error"]["children"] == ""
    assert _mine(server).wait(_mine(server).generation) == "full"
    _, shown, error, _ = _mine(server).snapshot()
    assert error is None and shown.accels == ["bvh(leaf=1,width=2)"] and shown.shape == (20, 20)
    ref = render(scene, accel="bvh(leaf=1,width=2)", resolution=20, work=True)
    assert all(np.array_equal(shown.runs["bvh(leaf=1,width=2)"].layers[k], ref.work[k]) for k in ref.work)
    # a structure the build refuses is the renderer's error, shown by the poll
    call(server, "error.children", [3], ["bvh", 20, "0,0,0", "0,0,0", "", None, "tests.total"])
    _mine(server).wait(_mine(server).generation)
    assert "eye and look_at" in call(server, "version.data", [2], [-1])["error"]["children"]


def test_a_newer_request_cancels_the_older(scene):
    from raykernel.explorer.jobs import Renderer
    r = Renderer(scene, SCENE, timed=False)
    first = r.submit(settings(["octree"], 160))
    while f"request {first}: rendering" not in r.snapshot()[3] and r.outcome(first) is None:
        time.sleep(0.001)       # until the worker has begun it
    assert r.outcome(first) is None, "the first request ended before a second could cancel it"
    second = r.submit(settings(["octree"], 12))
    assert r.wait(second) == "full"
    assert r.wait(first) == "cancelled"
    assert r.snapshot()[1].settings.resolution == 12
    third, fourth = r.submit(settings(["octree"], 10)), r.submit(settings(["octree"], 11))
    assert r.wait(fourth) == "full" and r.wait(third) == "cancelled"


def test_the_server_warms_each_structure_kernels_and_a_request_waits_cancellably(scene, server):
    """As it starts, the server renders each structure 2x2 in a thread (the kernels compiled or
    loaded), its status in the page; a request made before that ends waits, and a newer one
    cancels it without its having traced anything."""
    import threading
    from raykernel.explorer.jobs import Renderer
    from raykernel.rendering.render import RenderJob
    assert server.warm.done.wait(600) and server.warm.warmed == ACCELS
    assert call(server, "version.data", [1], [-1])["status"]["children"].startswith("kernels: ready | ")
    ready, traced = threading.Event(), []
    real = RenderJob.trace

    def trace(self, *args, **kw):
        traced.append(self.width)
        return real(self, *args, **kw)

    RenderJob.trace = trace
    try:
        r = Renderer(scene, SCENE, timed=False, ready=ready)
        first = r.submit(settings(["octree"], 16))
        while "waiting for the kernels" not in r.snapshot()[3]:
            time.sleep(0.001)
        second = r.submit(settings(["octree"], 12))
        assert r.wait(first) == "cancelled" and traced == [] and r.outcome(second) is None
        ready.set()
        assert r.wait(second) == "full" and set(traced) == {12}
        r.close()
    finally:
        RenderJob.trace = real


@pytest.mark.parametrize("phase", ["render", "samples", "timing"])
def test_a_newer_request_stops_the_first_after_at_most_one_chunk(scene, phase):
    """A renderer's first request, cancelled while it renders its layers, traces its samples alone
    or times its tiles: after the newer request arrived it traces at most one chunk (one
    call of CHUNK tiles; SAMPLE_CHUNK one-sample calls; CHUNK one-tile calls), counted, not timed."""
    import threading
    from raykernel.explorer.jobs import Renderer
    from raykernel.explorer.model import CHUNK, SAMPLE_CHUNK
    from raykernel.rendering.render import RenderJob
    lock, events = threading.Lock(), []
    real = RenderJob.trace

    def trace(self, p, lo, hi, threads=1, report=None):
        kind = "samples" if self.probe is not None else ("render" if self.layer is not None else "timing")
        with lock:
            events.append(("start", self.width, kind, hi - lo))
        real(self, p, lo, hi, threads, report)
        with lock:
            events.append(("end", self.width, kind, hi - lo))

    RenderJob.trace = trace
    try:
        r = Renderer(scene, SCENE, timed=True)
        first = r.submit(settings(["octree"], 128))         # its coarse pass 32x32, then 128x128
        # five calls into the phase: inside a chunk of samples or tile times, three chunks of tiles before the end
        while sum(e[0] == "end" and e[1] == 128 and e[2] == phase for e in list(events)) < 5:
            assert r.outcome(first) is None
            time.sleep(0.001)
        with lock:          # no chunk begins or ends between the newer request and this mark
            second = r.submit(settings(["octree"], 12))
            mark = len(events)
        assert r.wait(second) == "full" and r.wait(first) == "cancelled"
        after = [e for e in events[mark:] if e[1] == 128 and e[0] == "end"]
        limit = {"render": 1, "samples": SAMPLE_CHUNK, "timing": CHUNK}[phase]
        assert len(after) <= limit, after
        assert all(e[2] == phase for e in after) and all(e[3] <= CHUNK for e in events if e[1] == 128)
        r.close()
    finally:
        RenderJob.trace = real


def test_explore_command_prints_its_address_and_serves(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "raykernel", "explore", SCENE, "--accel", "octree",
                             "--resolution", "12", "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        url = lines[1].strip()
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/[\w-]{16,}/", url), lines
        assert _get(url)[0] == 200
        with pytest.raises(urllib.error.HTTPError):
            _get(url.rsplit("/", 2)[0] + "/")
    finally:
        proc.terminate()
        proc.communicate()
    saved = tmp_path / "settings.json"
    saved.write_text(settings(["grid", "octree"], 12).to_json())
    proc = subprocess.Popen([sys.executable, "-m", "raykernel", "explore", SCENE, "--settings", str(saved),
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "with grid, octree;" in proc.stdout.readline()
        assert _get(proc.stdout.readline().strip())[0] == 200
    finally:
        proc.terminate()
        proc.communicate()
    bad = subprocess.run([sys.executable, "-m", "raykernel", "explore", SCENE, "--accel", "nosuch("],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "nosuch" in bad.stderr


def test_export_writes_the_report_and_settings_that_reopen(server, tmp_path):
    from raykernel.explorer.server import initial_settings
    _, shown, _, _ = _mine(server).snapshot()
    out = call(server, "download-report.data", [1], ["tests.total"])["download-report"]["data"]
    assert out["filename"] == "explore-report.html"
    page = out["content"]
    assert "http://" not in page and "https://" not in page and "<section class='work'" in page
    data = json.loads(re.search(r"class='work-data'>(.*?)</script>", page, re.S).group(1))
    assert data["accels"] == shown.accels and data["counter"] == "tests.total"
    out = call(server, "download.data", [1])["download"]["data"]
    path = tmp_path / "settings.json"
    path.write_text(out["content"])
    assert initial_settings([], None, path) == shown.settings
    assert initial_settings(["grid"], 16, path).accels == ("grid",)


def test_the_time_panel_is_time_on_its_own_scale(scene):
    from raykernel.explorer import figures
    ex = explore_scene(scene, settings(["octree", "grid"], 20), SCENE)
    for run in ex.runs.values():
        assert run.tile_seconds.shape == (2, 2) and (run.tile_seconds > 0).all()
    fig = figures.time_figure(ex)
    assert "TIME" in fig.layout.coloraxis.colorbar.title.text
    assert all(t.coloraxis == "coloraxis" for t in fig.data)
    layers = figures.layers_figure(ex, "tests.total")
    assert "TIME" not in layers.layout.coloraxis.colorbar.title.text
    ex.runs["grid"].tile_seconds = ex.runs["octree"].tile_seconds * 1000      # decades apart: log
    assert "(log)" in figures.time_figure(ex).layout.coloraxis.colorbar.title.text


def test_an_orbit_of_the_3d_view_becomes_the_camera_and_renders_from_there(server):
    from raykernel.explorer import figures
    _, shown, _, _ = _mine(server).snapshot()
    run = next(iter(shown.runs.values()))
    frame = figures.view_frame(run)
    lo, hi, mid, side = frame
    corners = run.boxes.corners.reshape(-1, 3)
    assert np.allclose(lo, corners.min(axis=0)) and np.isclose(side, (corners.max(axis=0) - lo).max())
    view = {"eye": {"x": 0.0, "y": -2.0, "z": 0.5}, "center": {"x": 0.1, "y": 0.0, "z": 0.0},
            "up": {"x": 0, "y": 0, "z": 1}}
    page = [run.accel, "\n".join(shown.settings.accels), shown.settings.resolution, None, "tests.total"]   # the controls
    before = _mine(server).generation
    out = call(server, "eye.value", [{"scene.camera": view}], page)
    assert np.allclose([float(v) for v in out["eye"]["value"].split(",")], mid + np.array([0.0, -2.0, 0.5]) * side)
    assert np.allclose([float(v) for v in out["look-at"]["value"].split(",")], mid + np.array([0.1, 0, 0]) * side)
    assert out["up"]["value"] == "0.0,0.0,1.0"
    # and renders from there, without a press of the render button
    assert _mine(server).generation == before + 1
    assert _mine(server).wait(before + 1) == "full"
    _, orbited, _, _ = _mine(server).snapshot()
    assert orbited.settings.eye == tuple(float(v) for v in out["eye"]["value"].split(","))
    assert orbited.settings.accels == shown.settings.accels and orbited.shape == shown.shape
    assert call(server, "eye.value", [{"xaxis.range": [0, 1]}], page) == {}     # not an orbit: nothing
    assert _mine(server).generation == before + 1
    assert _mine(server).wait(_mine(server).submit(shown.settings)) == "full"     # as the other tests left it


def test_a_request_renders_coarse_then_full_and_the_memory_budget_holds(scene):
    from raykernel.explorer.jobs import Renderer
    r = Renderer(scene, SCENE, timed=False)
    assert r.wait(r.submit(settings(["octree"], 32))) == "full"
    version, shown, error, _ = r.snapshot()
    assert version == 2 and shown.stage == "full" and shown.shape == (32, 32) and error is None  # coarse, then full
    r.close()
    tight = Renderer(scene, SCENE, max_memory=4096, timed=False)
    assert tight.wait(tight.submit(settings(["octree"], 32))) == "failed"
    _, shown, error, _ = tight.snapshot()
    assert shown is None and "memory budget" in error[1]
    tight.close()


def test_raykernel_explore_is_the_function_whatever_was_imported_before():
    # the explorer's modules live in raykernel.explorer: importing them must not put a module where
    # raykernel.explore, the function, is (a package named explore did, in a process that had imported it)
    import raykernel
    import raykernel.explorer.server
    assert callable(raykernel.explore) and raykernel.explore is raykernel.explorer.server.explore
