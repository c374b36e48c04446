"""A self-contained HTML report of a comparison or sweep: one file, no external resources.

    write_report(cmp, "report.html", plots=[("sweep", png_bytes)])

Images and plots are PNG data URIs; the style sheet and the scripts are inline.
Nothing is fetched from anywhere. A comparison made with compare(..., work=COUNTER)
gets a work section per scene: the counter's layers as raw counts in the page, drawn
in a canvas by its script on one scale; buttons or a slider flip between the
structures, the mouse reads out every structure's count at the sample under it, and
two range sliders over a histogram of the values set the colour scale, which opens on a
log scale where the values above zero span more than two decades (linear ones would show one
flat colour). The page
records what it did in attributes (decoded images, the structure drawn, the last
read-out), and `#probe=X,Y` in its address moves the mouse there once it has loaded,
so a headless browser can check it.
"""

from __future__ import annotations

import base64
import html
import json

import numpy as np

from ..rendering.imageio import png_data_uri
from .compare import COLUMNS, Comparison, prediction_summary, spans_decades, table_rows

STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
table { border-collapse: collapse; font-size: 0.85em; }
th, td { border-bottom: 1px solid #ddd; padding: 2px 8px; }
td.n { text-align: right; font-variant-numeric: tabular-nums; }
tr.first td { border-top: 2px solid #999; }
.images { display: flex; flex-wrap: wrap; gap: 12px; margin-bottom: 10px; }
figure { margin: 0; } figcaption { font-size: 0.8em; text-align: center; }
.render { image-rendering: pixelated; width: 160px; height: auto; border: 1px solid #ccc; }
.plot { max-width: 100%; }
.work canvas.layer { image-rendering: pixelated; width: 480px; max-width: 100%; border: 1px solid #ccc; cursor: crosshair; }
.work .controls { margin: 6px 0; font-size: 0.85em; } .work .controls label { margin-right: 10px; }
.work .readout { font-family: monospace; font-size: 0.85em; min-height: 1.2em; }
.work canvas.hist { display: block; width: 480px; max-width: 100%; height: 80px; border: 1px solid #ddd; }
.fail { background: #fdd; border: 2px solid #c00; padding: 0.6em; font-weight: bold; }
code, pre { background: #f4f4f4; padding: 2px 4px; white-space: pre-wrap; }
"""

SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.getElementsByTagName('img'), ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    imgs[i].setAttribute('data-natural-width', String(imgs[i].naturalWidth));
    if (imgs[i].complete && imgs[i].naturalWidth > 0) ok++;
  }
  document.body.setAttribute('data-images', String(imgs.length));
  document.body.setAttribute('data-images-decoded', String(ok));
});
"""


WORK_SCRIPT = """
function rkBytes(text) {
  var bin = atob(text), out = new Uint8Array(bin.length);
  for (var i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out.buffer;
}
function rkWork(section) {
  var d = JSON.parse(section.querySelector('script.work-data').textContent);
  var W = d.width, H = d.height;
  var layers = d.layers.map(function (t) {
    return d.dtype === 'uint32' ? new Uint32Array(rkBytes(t)) : new Float64Array(rkBytes(t));
  });
  var canvas = section.querySelector('canvas.layer'), hist = section.querySelector('canvas.hist');
  var lo = section.querySelector('input.lo'), hi = section.querySelector('input.hi');
  var pick = section.querySelector('input.pick'), logScale = section.querySelector('input.log');
  var shown = section.querySelector('.shown'), range = section.querySelector('.range');
  var readout = section.querySelector('.readout');
  var radios = section.querySelectorAll('input.accel');
  canvas.width = W; canvas.height = H;
  var ctx = canvas.getContext('2d'), img = ctx.createImageData(W, H), current = 0;
  function f(v) { return d.dtype === 'uint32' ? String(v) : v.toPrecision(6); }
  function position(v, a, b) {
    if (logScale.checked) { v = Math.log(1 + Math.max(v, 0)); a = Math.log(1 + Math.max(a, 0)); b = Math.log(1 + Math.max(b, 0)); }
    if (b <= a) return v >= b ? 1 : 0;
    return Math.min(1, Math.max(0, (v - a) / (b - a)));
  }
  function drawHistogram(a, b) {
    var L = layers[current], bins = 64, counts = new Array(bins).fill(0), span = d.max - d.min || 1;
    for (var i = 0; i < L.length; i++) counts[Math.min(bins - 1, Math.floor((L[i] - d.min) / span * bins))]++;
    var g = hist.getContext('2d'), top = Math.log(1 + Math.max.apply(null, counts));
    hist.width = 480; hist.height = 80;
    g.fillStyle = '#eef'; g.fillRect((a - d.min) / span * 480, 0, Math.max(1, (b - a) / span * 480), 80);
    g.fillStyle = '#555';
    for (var k = 0; k < bins; k++) {
      var h = top > 0 ? Math.log(1 + counts[k]) / top * 76 : 0;
      g.fillRect(k * 480 / bins, 80 - h, 480 / bins - 1, h);
    }
  }
  function draw() {
    var L = layers[current], a = Number(lo.value), b = Number(hi.value), px = img.data;
    if (a > b) { var t = a; a = b; b = t; }
    for (var i = 0; i < W * H; i++) {
      var k = Math.floor(position(L[i], a, b) * 255.999) * 3;
      px[4 * i] = d.lut[k]; px[4 * i + 1] = d.lut[k + 1]; px[4 * i + 2] = d.lut[k + 2]; px[4 * i + 3] = 255;
    }
    ctx.putImageData(img, 0, 0);
    shown.textContent = d.accels[current];
    range.textContent = f(a) + ' to ' + f(b) + (logScale.checked ? ' (log)' : ' (linear)');
    pick.value = String(current);
    for (var r = 0; r < radios.length; r++) radios[r].checked = (r === current);
    section.setAttribute('data-drawn', d.accels[current]);
    drawHistogram(a, b);
  }
  function show(k) { current = Math.max(0, Math.min(layers.length - 1, k)); draw(); }
  function read(event) {
    var box = canvas.getBoundingClientRect();
    var x = Math.floor((event.clientX - box.left) / box.width * W), y = Math.floor((event.clientY - box.top) / box.height * H);
    if (x < 0 || y < 0 || x >= W || y >= H) return;
    var values = layers.map(function (L) { return L[y * W + x]; });
    readout.textContent = 'sample (' + x + ', ' + y + ') ' + d.counter + ': ' +
      d.accels.map(function (name, k) { return name + ' ' + f(values[k]); }).join(' | ');
    readout.setAttribute('data-x', String(x)); readout.setAttribute('data-y', String(y));
    readout.setAttribute('data-values', JSON.stringify(values.map(Number)));
  }
  canvas.addEventListener('mousemove', read);
  pick.addEventListener('input', function () { show(Number(pick.value)); });
  for (var r = 0; r < radios.length; r++) radios[r].addEventListener('change', (function (k) { return function () { show(k); }; })(r));
  lo.addEventListener('input', draw); hi.addEventListener('input', draw); logScale.addEventListener('change', draw);
  draw();
  return canvas;
}
window.addEventListener('load', function () {
  var sections = document.querySelectorAll('section.work'), canvases = [];
  for (var i = 0; i < sections.length; i++) canvases.push(rkWork(sections[i]));
  var probe = /probe=(\\d+),(\\d+)/.exec(window.location.hash);
  if (probe && canvases.length) {
    var c = canvases[0], box = c.getBoundingClientRect();
    var x = Number(probe[1]) + 0.5, y = Number(probe[2]) + 0.5;
    c.dispatchEvent(new MouseEvent('mousemove', {bubbles: true, clientX: box.left + x * box.width / c.width,
                                                 clientY: box.top + y * box.height / c.height}));
  }
  document.body.setAttribute('data-work-sections', String(sections.length));
});
"""


def _layer_text(values: np.ndarray) -> tuple:
    """A layer as base64 of little-endian uint32 (counts) or float64, and which."""
    v = np.asarray(values)
    if v.dtype.kind in "iu" and (v.size == 0 or (v.min() >= 0 and v.max() < 2 ** 32)):
        return base64.b64encode(np.ascontiguousarray(v, "<u4").tobytes()).decode("ascii"), "uint32"
    return base64.b64encode(np.ascontiguousarray(v, "<f8").tobytes()).decode("ascii"), "float64"


def _work_section(cmp: Comparison, scene: str) -> str:
    """A scene's interactive work images (see the module's docstring) and the ratio and winner figure."""
    import matplotlib

    from .workimages import figure_png, work_images
    w = work_images(cmp, scene)
    h, wd = next(iter(w.layers.values())).shape
    texts = [_layer_text(v) for v in w.layers.values()]
    dtype = "uint32" if all(t[1] == "uint32" for t in texts) else "float64"
    if dtype == "float64":
        texts = [_layer_text(np.asarray(v, np.float64)) for v in w.layers.values()]
    low, high = w.scale()
    positive = [float(v[v > 0].min()) for v in map(np.asarray, w.layers.values()) if (v > 0).any()]
    log = " checked" if spans_decades([min(positive, default=0.0), high]) else ""     # open on what shows something
    lut = (matplotlib.colormaps["viridis"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round().astype(int)
    data = {"counter": w.counter, "accels": w.accels, "width": wd, "height": h, "dtype": dtype,
            "min": low, "max": high, "lut": lut.ravel().tolist(), "layers": [t for t, _ in texts]}
    payload = json.dumps(data).replace("</", "<\\/")       # no "</script>" inside the script element
    step = "1" if dtype == "uint32" else "any"
    radios = "".join(f"<label><input type='radio' class='accel' name='accel-{_e(scene)}'>{_e(a)}</label>"
                     for a in w.accels)
    shares = ", ".join(f"{a} {v:.1%}" for a, v in w.shares.items())
    return (f"<section class='work' data-scene='{_e(scene)}'><h3>{_e(scene)}: {_e(w.counter)}</h3>"
            f"<div class='controls'>{radios} <input type='range' class='pick' min='0' max='{len(w.accels) - 1}' "
            f"step='1' value='0'> showing <b class='shown'></b></div>"
            f"<canvas class='layer'></canvas><div class='readout'>move the mouse over the image</div>"
            f"<canvas class='hist'></canvas><div class='controls'>colour scale from "
            f"<input type='range' class='lo' min='{low}' max='{high}' step='{step}' value='{low}'> to "
            f"<input type='range' class='hi' min='{low}' max='{high}' step='{step}' value='{high}'> "
            f"<label><input type='checkbox' class='log'{log}>log</label> <span class='range'></span></div>"
            f"<p>Samples won (least {_e(w.counter)}): {_e(shares)}.</p>"
            f"<img class='plot' alt='{_e(scene)} work ratios' src='{_png_uri(figure_png(w))}'>"
            f"<script type='application/json' class='work-data'>{payload}</script></section>")


def _e(text) -> str:
    return html.escape(str(text))


def _png_uri(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def render_html(cmp: Comparison, title: str = "raykernel comparison", plots=()) -> str:
    parts = ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
             f"<title>{_e(title)}</title>", f"<style>{STYLE}</style>", f"<script>{SCRIPT}</script>",
             *([f"<script>{WORK_SCRIPT}</script>"] if cmp.work else []),
             "</head><body>", f"<h1>{_e(title)}</h1>"]
    if cmp.disagreements:
        parts.append("<div class='fail'>CORRECTNESS FAILURE: ray counts differ between structures<ul>"
                     + "".join(f"<li>{_e(d.text())}</li>" for d in cmp.disagreements) + "</ul></div>")
    parts.append(f"<p>Command: <code>{_e(cmp.command)}</code></p>")
    m = cmp.machine
    parts.append("<p>Machine: " + _e(f"{m.get('cpu')}, {m.get('cores')} cores, {m.get('threads')} threads; "
                                     f"Python {m.get('python')}, numpy {m.get('numpy')}, numba {m.get('numba')}, "
                                     f"raykernel {m.get('raykernel')}, {m.get('system')}") + "</p>")
    opts = cmp.options
    parts.append("<p>Options: " + _e(", ".join(f"{k}={v}" for k, v in opts.items())) + "</p>")

    parts.append("<h2>Counts and times</h2>")
    parts.append("<p>Per-ray figures divide by all rays cast (eye, reflection, refraction, shadow). "
                 "N_IT: ray/primitive tests; N_TS: traversal steps (cells or nodes visited); N_ETS: leaves "
                 "visited; N_EETS: empty leaves visited. Predicted: the cost model's trace time.</p>")
    head = "".join(f"<th>{_e(h)}</th>" for h, _, _ in COLUMNS)
    rows = []
    last = None
    for scene, accel, cells in table_rows(cmp):
        cls = " class='first'" if scene != last else ""
        rows.append(f"<tr{cls}><td>{_e(scene if scene != last else '')}</td><td>{_e(accel)}</td>"
                    + "".join(f"<td class='n'>{_e(c)}</td>" for c in cells) + "</tr>")
        last = scene
    parts.append(f"<table><tr><th>scene</th><th>structure</th>{head}</tr>{''.join(rows)}</table>")

    summary = prediction_summary(cmp)
    if summary:
        parts.append("<h2>Cost model</h2><p>Predicted trace time against measured, per structure "
                     "(relative error; goal: within 25%).</p><table><tr><th>structure</th><th>runs</th>"
                     "<th>mean |error|</th><th>worst error</th></tr>")
        for accel, worst, mean, n in summary:
            parts.append(f"<tr><td>{_e(accel)}</td><td class='n'>{n}</td><td class='n'>{mean:.0%}</td>"
                         f"<td class='n'>{worst:+.0%}</td></tr>")
        parts.append("</table>")
        if cmp.model is not None:
            costs = cmp.model.costs
            parts.append("<p>Calibrated costs (nanoseconds per operation, at "
                         f"{_e(cmp.model.threads)} threads): "
                         + _e(", ".join(f"{k} {v * 1e9:.1f}" for k, v in sorted(costs.items()) if v))
                         + "</p>")

    for name, data in plots:
        parts.append(f"<h2>{_e(name)}</h2><img class='plot' alt='{_e(name)}' src='{_png_uri(data)}'>")

    if cmp.work:
        parts.append(f"<h2>Where the work was done: {_e(cmp.work)}</h2><p>Each sample's count of {_e(cmp.work)} "
                     "over its whole ray tree, every structure on one colour scale. The figure under each: "
                     f"each structure's log2 ratio against {_e(cmp.accels()[0])}, and which structure did "
                     "the least work at each sample.</p>")
        parts += [_work_section(cmp, scene) for scene in cmp.scenes()]

    parts.append("<h2>Images</h2>")
    for scene in cmp.scenes():
        figs = []
        for run in cmp.runs:
            if run.scene == scene:
                figs.append(f"<figure><img class='render' alt='{_e(scene)} {_e(run.accel)}' "
                            f"src='{png_data_uri(run.image)}'><figcaption>{_e(run.accel)}</figcaption></figure>")
        parts.append(f"<h3>{_e(scene)}</h3><div class='images'>{''.join(figs)}</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(cmp: Comparison, path, title: str = "raykernel comparison", plots=()) -> None:
    from ..atomicfile import atomic_write
    text = render_html(cmp, title=title, plots=plots)
    with atomic_write(path) as f:
        f.write(text)
