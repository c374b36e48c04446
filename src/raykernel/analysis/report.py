"""A self-contained HTML report of a comparison or sweep: one file, no external resources.

    write_report(cmp, "report.html", plots=[("sweep", png_bytes)])

Images and plots are PNG data URIs; the style sheet and the one small script
(which records each image's decoded width in the page, for headless checks)
are inline. Nothing is fetched from anywhere.
"""

from __future__ import annotations

import base64
import html

from ..rendering.imageio import png_data_uri
from .compare import COLUMNS, Comparison, prediction_summary, table_rows

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


def _e(text) -> str:
    return html.escape(str(text))


def _png_uri(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def render_html(cmp: Comparison, title: str = "raykernel comparison", plots=()) -> str:
    parts = ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
             f"<title>{_e(title)}</title>", f"<style>{STYLE}</style>", f"<script>{SCRIPT}</script>",
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
