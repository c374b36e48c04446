"""The HTML report: self-contained, and it loads in a real headless browser with every image decoded."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from raykernel.analysis import compare as cm
from raykernel.analysis.report import render_html, write_report


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    cmp = cm.compare(["spd:balls:1", "spd:tetra:1"], ["list", "bvh"], resolution=16, threads=1, model=None,
                     warm_up=False, command="raykernel compare spd:balls:1 spd:tetra:1 --accel list --accel bvh")
    path = tmp_path_factory.mktemp("report") / "report.html"
    write_report(cmp, path, plots=[("Counts", cm.compare_figure_png(cmp))])
    return path


def test_report_is_self_contained(report):
    text = report.read_text()
    assert "http://" not in text and "https://" not in text
    assert not re.search(r"<(link|iframe|object|embed)\b", text)
    assert not re.search(r"<script[^>]*\bsrc=", text)
    assert "url(" not in text and "@import" not in text
    srcs = re.findall(r"<img[^>]*\bsrc='([^']*)'", text)
    assert len(srcs) == 1 + 4                       # one plot, two scenes x two structures
    assert all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "raykernel compare spd:balls:1" in text
    assert "N_IT" in text and "spd:tetra:1" in text


def test_report_flags_disagreement():
    cmp = cm.Comparison(runs=[], options={}, machine={}, command="x",
                        disagreements=[cm.Disagreement("s", "bvh", "grid", {"rays.shadow": (1, 2)})])
    assert "CORRECTNESS FAILURE" in render_html(cmp)


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-logging=stderr", "--v=0", "--virtual-time-budget=5000"]


def _chromium(args, tmp_path):
    return subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", *args],
                          capture_output=True, text=True, timeout=120)


def _console_errors(log: str) -> list:
    return [line for line in log.splitlines() if "CONSOLE" in line and ("ERROR" in line or "Uncaught" in line)]


needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed "
                                    "(apt-get install -y chromium); the headless browser test needs it")


@needs_chromium
def test_console_error_detection_works(tmp_path):
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('deliberate'); nosuchfunction();</script></body></html>")
    proc = _chromium(["--dump-dom", bad.as_uri()], tmp_path)
    assert _console_errors(proc.stderr), proc.stderr[-2000:]


@needs_chromium
def test_report_in_headless_chromium(report, tmp_path):
    proc = _chromium(["--dump-dom", report.as_uri()], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert not _console_errors(proc.stderr), _console_errors(proc.stderr)
    dom = proc.stdout
    n = int(re.search(r'data-images="(\d+)"', dom).group(1))
    decoded = int(re.search(r'data-images-decoded="(\d+)"', dom).group(1))
    assert n == 5 and decoded == n
    widths = [int(w) for w in re.findall(r'data-natural-width="(\d+)"', dom)]
    assert len(widths) == n and all(w > 0 for w in widths)
    assert sorted(widths)[:4] == [16, 16, 16, 16]

    shot = tmp_path / "shot.png"
    proc = _chromium([f"--screenshot={shot}", "--window-size=1000,1400", report.as_uri()], tmp_path)
    assert shot.exists(), proc.stderr[-2000:]
    from PIL import Image
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3)
    assert len(np.unique(pixels, axis=0)) > 50       # text, table, plot and renders, not a blank page


@pytest.fixture(scope="module")
def work_report(tmp_path_factory):
    cmp = cm.compare(["scene:stadium:ratio=50"], ["list", "grid", "bvh"], resolution=12, threads=1, model=None,
                     warm_up=False, command="raykernel compare --work tests.total", work="tests.total")
    path = tmp_path_factory.mktemp("work") / "work.html"
    write_report(cmp, path)
    return cmp, path


def test_work_section_carries_every_layer(work_report):
    cmp, path = work_report
    text = path.read_text()
    assert text.count("<section class='work'") == 1
    data = re.search(r"<script type='application/json' class='work-data'>(.*?)</script>", text).group(1)
    import base64
    import json
    d = json.loads(data)
    assert d["accels"] == ["list", "grid", "bvh"] and (d["width"], d["height"]) == (12, 12)
    for run, layer in zip(cmp.runs, d["layers"]):
        decoded = np.frombuffer(base64.b64decode(layer), "<u4").reshape(12, 12)
        assert np.array_equal(decoded, run.work)


@needs_chromium
@pytest.mark.parametrize("x, y", [(0, 0), (7, 3), (11, 11)])
def test_work_section_in_headless_chromium(work_report, tmp_path, x, y):
    cmp, path = work_report
    proc = _chromium(["--dump-dom", path.as_uri() + f"#probe={x},{y}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert not _console_errors(proc.stderr), _console_errors(proc.stderr)
    dom = proc.stdout
    assert 'data-work-sections="1"' in dom and 'data-drawn="list"' in dom
    assert int(re.search(r'data-images-decoded="(\d+)"', dom).group(1)) == int(
        re.search(r'data-images="(\d+)"', dom).group(1))
    readout = re.search(r'class="readout" data-x="(\d+)" data-y="(\d+)" data-values="([^"]*)"', dom)
    assert readout, dom[-3000:]
    assert (int(readout.group(1)), int(readout.group(2))) == (x, y)
    import html
    import json
    values = json.loads(html.unescape(readout.group(3)))
    assert values == [int(run.work[y, x]) for run in cmp.runs]


def test_work_data_cannot_end_its_script_element():
    odd = "b</script><b>vh"
    runs = [cm.Run(scene="s", accel=a, stats={}, image=np.zeros((2, 2, 3), np.uint8), primitives=1,
                   work=np.array([[1, 2], [3, k]])) for k, a in enumerate(["list", odd])]
    cmp = cm.Comparison(runs=runs, options={}, machine={}, command="x", work="tests.total")
    text = render_html(cmp)
    data = re.search(r"<script type='application/json' class='work-data'>(.*?)</script>", text, re.S).group(1)
    import json
    assert json.loads(data)["accels"] == ["list", odd]
    assert "</script><b>" not in text


def _work_comparison(top: int):
    runs = [cm.Run(scene="s", accel=a, stats={"time.trace": 0.1, "tests.per_ray": 1.0}, image=np.zeros((2, 2, 3), np.uint8),
                   primitives=1, work=np.array([[5, 9], [40, top * (k + 1) // 2]]))
            for k, a in enumerate(["octree", "bvh"])]
    return cm.Comparison(runs=runs, options={}, machine={}, command="x", work="tests.total")


def test_the_work_section_opens_on_a_log_scale_where_values_span_decades():
    # the stadium's tests per sample ran from 5 to 75,840: linear showed one flat colour
    assert "class='log' checked>" in render_html(_work_comparison(75840))
    assert "class='log'>" in render_html(_work_comparison(80))


def test_no_cost_model_panel_without_a_calibration():
    cmp = _work_comparison(80)
    assert len(cm.compare_figure(cmp).axes) == 3          # no empty frame
    for run in cmp.runs:
        run.predicted = 0.12
    axes = cm.compare_figure(cmp).axes
    assert len(axes) == 4 and axes[3].get_title().startswith("cost model")
