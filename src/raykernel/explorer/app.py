"""The explorer's page (Dash): its layout and the callbacks that link its views.

    tabs = Sessions(scene, "scene:stadium", settings(["octree", "bvh"]))
    app = make_app(tabs, settings(["octree", "bvh"]), token="...")   # app.server: a Flask app
    # server.py serves it; the callbacks are plain functions too (app.callback_map), which tests call

Each page load is a session of its own (jobs.Sessions): the layout is made afresh for it, with a
new session id in the store "session", which every callback sends back (its last State) and
reads its tab's Renderer by; a request whose id the server did not sign reads nothing. The page
polls its renderer and redraws when something new is shown. Linking: a hover
on any image names a sample (every structure's counts there); a click on one explains it (its
rays, listed and drawn in 3D over the structure with the boxes they entered); a range selected
on a histogram, or a click on a box in 3D, lights the samples it names on the image.
"""

from __future__ import annotations

import json
import threading

import numpy as np

from ..errors import OptionError, RayKernelError
from ..rendering.explain import explain, text
from . import figures
from .model import Settings, settings, tested_items, viewed

POLL_MS = 600


def _vector_text(v) -> str:
    return "" if v is None else ",".join(repr(float(x)) for x in v)      # exact: the same camera renders again


def _parse_vector(text, name):
    if text is None or not str(text).strip():
        return None
    parts = str(text).replace(" ", "").split(",")
    try:
        return tuple(float(p) for p in parts)
    except ValueError:
        raise OptionError(f"{name} must be three numbers X,Y,Z, got {text!r}") from None


def settings_from_page(accels_text, resolution, eye, look_at, up, angle, counter) -> Settings:
    """The settings the page's controls give (OptionError names a bad one)."""
    accels = [line.strip() for line in str(accels_text or "").splitlines() if line.strip()]
    try:
        res = int(resolution) if resolution is not None and float(resolution) == int(float(resolution)) else resolution
    except (TypeError, ValueError):
        res = resolution
    return settings(accels, res, _parse_vector(eye, "eye"), _parse_vector(look_at, "look_at"),
                    _parse_vector(up, "up"), angle if angle not in ("", None) else None, counter or "tests.total")


def layout(s: Settings, scene_label: str, camera=None, session: str = ""):
    """The page of session `session`; the camera fields hold the settings' camera, else the
    scene's (`camera`)."""
    from dash import dcc, html
    if camera is not None:
        s = Settings(s.accels, s.resolution, s.eye or tuple(camera.eye), s.look_at or tuple(camera.look_at),
                     s.up or tuple(camera.up), s.angle if s.angle is not None else camera.angle, s.counter)
    field = {"style": {"marginRight": "12px", "display": "inline-block", "verticalAlign": "top"}}
    cam = [html.Label([name, dcc.Input(id=name.replace(" ", "-"), type="text", value=value, debounce=True,
                                       style={"width": "110px"})], **field)
           for name, value in (("eye", _vector_text(s.eye)), ("look at", _vector_text(s.look_at)),
                               ("up", _vector_text(s.up)))]
    return html.Div([
        html.H2(f"raykernel explore: {scene_label}"),
        html.Div([
            html.Label(["structures, one spec a line", dcc.Textarea(id="accels", value="\n".join(s.accels),
                                                                    style={"width": "260px", "height": "70px"})],
                       **field),
            html.Label(["resolution", dcc.Input(id="resolution", type="number", value=s.resolution, min=2,
                                                style={"width": "70px"})], **field),
            *cam,
            html.Label(["angle", dcc.Input(id="angle", type="number", value=s.angle, style={"width": "60px"})], **field),
            html.Button("render", id="render", n_clicks=0),
            html.Button("export settings", id="export", n_clicks=0, style={"marginLeft": "8px"}),
            html.Button("export report", id="export-report", n_clicks=0, style={"marginLeft": "8px"}),
            dcc.Download(id="download"), dcc.Download(id="download-report"),
        ]),
        html.Div(id="error", role="alert", style={"color": "#b00", "fontWeight": "bold", "minHeight": "1.2em"}),
        html.Div(id="status", style={"color": "#555", "fontSize": "0.85em"}),
        html.Div([html.Label(["counter ", dcc.Dropdown(id="counter", value=s.counter, options=[s.counter],
                                                       clearable=False, style={"width": "260px"})], **field),
                  html.Label(["scale ", dcc.RadioItems(id="scale", value="auto", inline=True,
                                                       options=["auto", "linear", "log"])], **field)]),
        dcc.Graph(id="layers", clear_on_unhover=False),
        html.Div(id="lit", style={"fontSize": "0.85em"}),
        html.Div(id="hover", style={"fontFamily": "monospace", "fontSize": "0.8em", "maxHeight": "180px",
                                    "overflowY": "auto"}),
        dcc.Graph(id="compare"),
        dcc.Graph(id="histograms"),
        html.H4("hottest samples"), html.Div(id="hottest"),
        html.H4("time (wall clock, not counts)"), html.Div(id="time-note"), dcc.Graph(id="time"),
        html.H4("one sample's rays (click a sample on an image)"),
        html.Label(["structure ", dcc.Dropdown(id="accel", value=s.accels[0], options=list(s.accels),
                                               clearable=False, style={"width": "260px"})]),
        html.Pre(id="rays", style={"maxHeight": "260px", "overflowY": "auto", "fontSize": "0.75em"}),
        html.H4("the structure in 3D (click a box: the samples whose rays entered it)"),
        html.Div([html.Label(["colour by ", dcc.Dropdown(id="colour-by", value="visits", clearable=False,
                                                          options=list(figures.COLOUR_BY), style={"width": "160px"})],
                             **field),
                  html.Label(["levels ", dcc.Input(id="levels", type="text", value="", placeholder="all (or 0-1)",
                                                   debounce=True, style={"width": "90px"})], **field),
                  html.Label(["depths ", dcc.Input(id="depths", type="text", value="", placeholder="all (or 0-3)",
                                                   debounce=True, style={"width": "90px"})], **field),
                  html.Button("clear selection", id="clear", n_clicks=0)]),
        html.Div(id="node", style={"fontSize": "0.85em"}),
        dcc.Graph(id="structure"), dcc.Graph(id="quality"),
        dcc.Interval(id="poll", interval=POLL_MS),
        dcc.Store(id="version", data=-1), dcc.Store(id="pixel"), dcc.Store(id="selection"),
        dcc.Store(id="session", data=session),
    ], style={"fontFamily": "sans-serif", "margin": "12px"})


def make_app(tabs, s: Settings, token: str, title: str = "", warm=None):
    """The Dash app under /TOKEN/ (every route: a request without the token finds nothing), one
    session of `tabs` (jobs.Sessions) a page load; warm: the jobs.Warmup whose status it shows."""
    from dash import Dash
    app = Dash(__name__, url_base_pathname=f"/{token}/", serve_locally=True, title="raykernel explore",
               update_title=None)
    app.layout = lambda: layout(s, title or tabs.label, tabs.scene.camera, tabs.issue())     # each load: a new id
    _controls(app, tabs, warm)
    _views(app, tabs)
    explained = Explained(tabs.scene, tabs.share)
    _pixel(app, tabs, explained)
    _structure(app, tabs, explained)
    return app


def _shown(tabs, sid):
    """What session `sid` shows (None: nothing yet, or an id not signed here, or closed)."""
    try:
        return tabs.get(sid).snapshot()[1]
    except RayKernelError:
        return None


def _controls(app, tabs, warm) -> None:
    from dash import Input, Output, State, dcc, no_update

    @app.callback(Output("error", "children", allow_duplicate=True), Input("render", "n_clicks"),
                  State("accels", "value"), State("resolution", "value"), State("eye", "value"),
                  State("look-at", "value"), State("up", "value"), State("angle", "value"), State("counter", "value"),
                  State("session", "data"), prevent_initial_call=True)
    def submit(_, accels, resolution, eye, look_at, up, angle, counter, sid):
        try:
            renderer = tabs.get(sid)
        except RayKernelError as e:
            return str(e)
        try:
            renderer.submit(settings_from_page(accels, resolution, eye, look_at, up, angle, counter))
        except RayKernelError as e:
            renderer.reject(f"{type(e).__name__}: {e}")     # the poll shows it too, until the next request
            return f"{type(e).__name__}: {e}"
        return ""

    @app.callback(Output("version", "data"), Output("status", "children"), Output("error", "children"),
                  Input("poll", "n_intervals"), State("version", "data"), State("session", "data"))
    def poll(_, shown, sid):
        kernels = "" if warm is None else warm.status + " | "
        try:
            version, ex, error, status = tabs.get(sid).snapshot()
        except RayKernelError as e:
            return no_update, kernels, str(e)
        message = error[1] if error else ""
        where = "" if ex is None else (f" | shown: {', '.join(ex.accels)} at {ex.shape[1]}x{ex.shape[0]} "
                                       f"({ex.stage}, {ex.seconds:.1f} s)")
        return (version if version != shown else no_update), kernels + status + where, message

    @app.callback(Output("download", "data"), Input("export", "n_clicks"), State("session", "data"),
                  prevent_initial_call=True)
    def export(_, sid):
        ex = _shown(tabs, sid)
        if ex is None:
            return no_update
        return dcc.send_string(ex.settings.to_json(), "explore-settings.json")

    @app.callback(Output("download-report", "data"), Input("export-report", "n_clicks"), State("counter", "value"),
                  State("session", "data"), prevent_initial_call=True)
    def report(_, counter, sid):
        ex = _shown(tabs, sid)
        if ex is None:
            return no_update
        return dcc.send_string(report_html(ex, counter), "explore-report.html")


def report_html(ex, counter: str) -> str:
    """The shown exploration as the self-contained HTML report (analysis/report.py) of `counter`."""
    from ..analysis.report import render_html
    name = counter if counter in ex.layer_names() else ex.settings.counter
    return render_html(ex.comparison(name), title=f"raykernel explore {ex.scene}")


def _mask(ex, selection):
    """The samples a selection names (a histogram's range or a box), and what to call them."""
    if not selection:
        return None, ""
    try:
        if selection["kind"] == "range":
            a, name, lo, hi = selection["accel"], selection["counter"], selection["low"], selection["high"]
            return ex.in_range(a, name, lo, hi), f"{a}'s {name} in {lo:,.0f} to {hi:,.0f}"
        run = ex.runs[selection["accel"]]
        mask = run.node_mask(int(selection["box"])) > 0
        return mask, f"{int(mask.sum())} samples' rays entered box {selection['box']} of {run.accel}"
    except (KeyError, IndexError, RayKernelError):
        return None, ""


def _views(app, tabs) -> None:
    from dash import Input, Output, State, html, no_update

    @app.callback(Output("layers", "figure"), Output("compare", "figure"), Output("histograms", "figure"),
                  Output("hottest", "children"), Output("time", "figure"), Output("time-note", "children"),
                  Output("counter", "options"), Output("lit", "children"),
                  Input("version", "data"), Input("counter", "value"), Input("scale", "value"),
                  Input("selection", "data"), State("session", "data"))
    def draw(_, counter, scale, selection, sid):
        ex = _shown(tabs, sid)
        if ex is None:
            return (no_update,) * 8
        names = ex.layer_names()
        counter = counter if counter in names else ex.settings.counter
        scale = None if scale == "auto" else scale
        mask, what = _mask(ex, selection)
        layers = figures.layers_figure(ex, counter, scale, mask, what)
        compare = figures.compare_figure(ex, counter) if len(ex.accels) > 1 else {}
        hot = ex.hottest(counter, 10)
        table = html.Table([html.Tr([html.Th("x"), html.Th("y")] + [html.Th(a) for a in ex.accels])]
                           + [html.Tr([html.Td(x), html.Td(y)] + [html.Td(f"{v[a]:,}") for a in ex.accels])
                              for x, y, v in hot], id="hottest-table")
        timing = figures.time_figure(ex)
        notes = [f"{a}: {r.note}" for a, r in ex.runs.items() if r.tile_seconds is None]
        note = ("Seconds each tile took on one thread, fastest of several traces; not counts. "
                + " ".join(notes))
        count = "" if "samples" in what else f" ({int(mask.sum()) if mask is not None else 0} samples)"
        lit = "" if mask is None else html.Span(f"lit on the image: {what}{count}",
                                                **{"data-lit": json.dumps(np.flatnonzero(mask).tolist())})
        return (layers, compare, figures.histograms_figure(ex, counter, scale), table,
                timing if timing is not None else {}, note, names, lit)

    @app.callback(Output("hover", "children"), Input("layers", "hoverData"), Input("compare", "hoverData"),
                  State("session", "data"))
    def hover(*events):
        *events, sid = events
        point = next((e["points"][0] for e in events if e and e.get("points")), None)
        ex = _shown(tabs, sid)
        if point is None or ex is None:
            return "move the mouse over an image: every structure's counts at that sample"
        x, y = int(point["x"]), int(point["y"])
        try:
            counts = ex.counts_at(x, y)
        except RayKernelError as e:
            return str(e)
        names = [n for n in ex.layer_names() if any(counts[a][n] for a in ex.accels)]
        rows = [html.Tr([html.Th(f"sample ({x}, {y})")] + [html.Th(a) for a in ex.accels])]
        rows += [html.Tr([html.Td(n)] + [html.Td(f"{counts[a][n]:,}") for a in ex.accels]) for n in names]
        return html.Table(rows, id="hover-table", **{"data-x": x, "data-y": y,
                                                     "data-counts": json.dumps(counts, sort_keys=True)})

    @app.callback(Output("selection", "data"), Input("histograms", "selectedData"),
                  Input("structure", "clickData"), Input("clear", "n_clicks"), State("counter", "value"),
                  State("accel", "value"), State("session", "data"), prevent_initial_call=True)
    def select(hist, box, _, counter, accel, sid):
        from dash import ctx
        ex = _shown(tabs, sid)
        if ex is None or ctx.triggered_id == "clear":
            return None
        if ctx.triggered_id == "histograms":
            return _range_selection(ex, hist, counter)
        point = (box or {}).get("points", [{}])[0]
        if "customdata" not in point or accel not in ex.runs:
            return no_update
        return {"kind": "box", "accel": accel, "box": int(point["customdata"])}


def _range_selection(ex, event, counter):
    """A histogram's box selection: the structure of the subplot it was made on and its x range."""
    if not event or "range" not in event:
        return None
    for key, (lo, hi) in event["range"].items():
        if key.startswith("x"):
            k = int(key[1:] or 1) - 1
            if 0 <= k < len(ex.accels):
                return {"kind": "range", "accel": ex.accels[k], "counter": counter, "low": float(min(lo, hi)),
                        "high": float(max(lo, hi))}
    return None


class Explained:
    """explain's answers for samples of the render shown, the last few kept: the rays list and
    the 3D view ask for the same one at once."""

    KEEP = 16

    def __init__(self, scene, max_memory=None):
        self.scene, self.max_memory, self.answers, self.lock = scene, max_memory, {}, threading.Lock()

    def __call__(self, ex, accel: str, x: int, y: int) -> dict:
        key = (ex.settings, ex.shape, accel, int(x), int(y))     # the same render: the same answer
        with self.lock:         # one explanation at a time: the second asker finds the first's
            if key not in self.answers:
                scene = viewed(self.scene, ex.settings)
                self.answers[key] = explain(scene, int(x), int(y), accel=accel, resolution=ex.shape[0],
                                            max_memory=self.max_memory)
                while len(self.answers) > self.KEEP:
                    self.answers.pop(next(iter(self.answers)))
            return self.answers[key]


def _pixel(app, tabs, explained) -> None:
    from dash import Input, Output, State, no_update

    @app.callback(Output("pixel", "data"), Input("layers", "clickData"), Input("compare", "clickData"),
                  prevent_initial_call=True)
    def click(*events):
        from dash import ctx
        event = events[0] if ctx.triggered_id == "layers" else events[1]
        if not event or not event.get("points"):
            return no_update
        p = event["points"][0]
        return {"x": int(p["x"]), "y": int(p["y"])}

    @app.callback(Output("rays", "children"), Input("pixel", "data"), Input("accel", "value"),
                  Input("version", "data"), State("session", "data"))
    def rays(pixel, accel, _, sid):
        ex = _shown(tabs, sid)
        if not pixel or ex is None or accel not in ex.runs:
            return "click a sample on an image: its rays, as `raykernel explain` gives them"
        try:
            return text(explained(ex, accel, pixel["x"], pixel["y"]))
        except RayKernelError as e:
            return f"{type(e).__name__}: {e}"


def _range(text_value, name):
    if not text_value or not str(text_value).strip():
        return None
    parts = str(text_value).replace(" ", "").split("-")
    try:
        lo, hi = (int(parts[0]), int(parts[-1]))
    except ValueError:
        raise RayKernelError(f"{name} must be a number or a range such as 0-3, got {text_value!r}") from None
    return min(lo, hi), max(lo, hi)


def _structure(app, tabs, explained) -> None:
    from dash import Input, Output, State, no_update

    @app.callback(Output("eye", "value"), Output("look-at", "value"), Output("up", "value"),
                  Input("structure", "relayoutData"), State("accel", "value"), State("accels", "value"),
                  State("resolution", "value"), State("angle", "value"), State("counter", "value"),
                  State("session", "data"), prevent_initial_call=True)
    def orbit(view, accel, accels, resolution, angle, counter, sid):
        # an orbit or a pan of the 3D view (plotly reports it when the drag ends): its camera into
        # the camera fields, and a render from there, which cancels the one in progress
        ex = _shown(tabs, sid)
        if not view or "scene.camera" not in view or ex is None or accel not in ex.runs:
            return no_update, no_update, no_update
        eye, look_at, up = (_vector_text(v) for v in
                            figures.camera_from_view(view["scene.camera"], figures.view_frame(ex.runs[accel])))
        renderer = tabs.get(sid)        # the one that showed ex
        try:
            renderer.submit(settings_from_page(accels, resolution, eye, look_at, up, angle, counter))
        except RayKernelError as e:
            renderer.reject(f"{type(e).__name__}: {e}")
        return eye, look_at, up

    @app.callback(Output("accel", "options"), Input("version", "data"), State("session", "data"))
    def structures(_, sid):
        ex = _shown(tabs, sid)
        return no_update if ex is None else ex.accels

    @app.callback(Output("structure", "figure"), Output("quality", "figure"), Output("node", "children"),
                  Input("version", "data"), Input("accel", "value"), Input("colour-by", "value"),
                  Input("levels", "value"), Input("depths", "value"), Input("pixel", "data"),
                  Input("selection", "data"), State("session", "data"))
    def draw(_, accel, what, levels, depths, pixel, selection, sid):
        ex = _shown(tabs, sid)
        if ex is None or accel not in ex.runs:
            return no_update, no_update, ""
        run = ex.runs[accel]
        try:
            lv, dp = _range(levels, "levels"), _range(depths, "depths")
        except RayKernelError as e:
            return no_update, no_update, str(e)
        visited = tested = rays = None
        notes = [run.note] if run.note else []
        if pixel and run.samples is not None:
            visited, tested = run.pixel_boxes(pixel["x"], pixel["y"])
            try:
                rays = explained(ex, accel, pixel["x"], pixel["y"])["rays"]
            except RayKernelError as e:
                notes.append(str(e))
            notes.append(f"sample ({pixel['x']}, {pixel['y']}): its rays entered {len(visited)} boxes and "
                         f"tested items in {len(tested)}")
            drawn = [tested_items(r) for r in rays or []]
            notes.append(f"the items each ray tested drawn in its colour ({sum(len(d) for d, _ in drawn)} in all)"
                         + (f"; {sum(h for _, h in drawn)} tested inside an instance, in its own space, not drawn"
                            if any(h for _, h in drawn) else ""))
        selected = None
        if selection and selection.get("kind") == "box" and selection.get("accel") == accel:
            selected = int(selection["box"])
            notes.append(_mask(ex, selection)[1])
        fig = figures.structure_figure(run, what, lv, dp, visited, tested, rays, selected)
        return fig, figures.quality_figure(run), " | ".join(n for n in notes if n)
