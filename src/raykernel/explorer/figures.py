"""The explorer's views as plotly figures, drawn from an Exploration (model.py).

    layers_figure(ex, "tests.total")        # the image, then every structure's layer on one scale
    compare_figure(ex, "tests.total")       # ratios against the first structure, and the winner map
    histograms_figure(ex, "tests.total")    # a histogram per structure: select a range to light its samples
    time_figure(ex)                         # seconds per tile: time, on a scale of its own
    structure_figure(run, "visits")         # the boxes in 3D coloured by use or quality
    quality_figure(run)                     # SAH terms, overlap, depth and leaf-size histograms

Every heatmap puts the sample's column and row in its hover data (x, y), so a hover or a click
on any of them names one sample. A log scale draws log10 of the counts with the colour bar
labelled in counts; zeros are drawn black (no colour on a log scale).
"""

from __future__ import annotations

import numpy as np

from ..rendering.structure import CORNERS
from .model import DECADES, Exploration, Run, primitive_box, primitive_shape, tested_items
from .quality import depth_histogram, leaf_size_histogram, quality

MAX_DRAWN = 1500        # boxes drawn in 3D at most: those that score highest on the colour
EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7))
LEVEL_COLOURS = ("#e41a1c", "#377eb8", "#4daf4a", "#984ea3", "#ff7f00", "#a65628", "#f781bf", "#999999")
RAY_COLOURS = {"eye": "#000000", "reflect": "#1f77b4", "refract": "#17becf", "shadow": "#ff7f0e", None: "#7f7f7f"}
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")
OPENING_EYE = (0.8, -0.8, 0.6)      # the 3D view's first camera, in units of the structure's longest side
LEVEL_DASHES = ("solid", "dash", "dot", "longdash", "dashdot", "longdashdot")    # a tested item's level
COLOUR_BY = ("visits", "tests", "futile", "refined", "sah", "overlap", "depth", "items")


def _go():
    import plotly.graph_objects as go
    return go


def _subplots(rows, cols, titles, **kw):
    from plotly.subplots import make_subplots
    return make_subplots(rows=rows, cols=cols, subplot_titles=titles, **kw)


def _image_axes(fig, n: int) -> None:
    for k in range(1, n + 1):
        suffix = "" if k == 1 else str(k)
        # constrain="domain": the axes shrink to the image, no plot background beside it
        fig.layout[f"yaxis{suffix}"].update(autorange="reversed", scaleanchor=f"x{suffix}", showticklabels=False,
                                            constrain="domain", showgrid=False)
        fig.layout[f"xaxis{suffix}"].update(showticklabels=False, constrain="domain", showgrid=False)


def _rgb(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0.0, 1.0) * 255).round().astype(np.uint8)


def scaled(values: np.ndarray, scale: str) -> np.ndarray:
    """What a heatmap draws: the counts, or log10 of them (NaN for 0) on a log scale."""
    v = np.asarray(values, np.float64)
    if scale == "log":
        with np.errstate(divide="ignore"):
            return np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
    return v


def _colorbar(low: float, high: float, scale: str, title: str) -> dict:
    bar = {"title": {"text": title, "side": "right"}}
    if scale == "log":
        top = int(np.ceil(np.log10(max(high, 1.0))))
        ticks = list(range(0, max(top, 1) + 1))
        bar.update(tickvals=ticks, ticktext=[f"{10 ** t:,}" for t in ticks])
    return bar


def layers_figure(ex: Exploration, name: str, scale: str | None = None, mask: np.ndarray | None = None,
                  mask_title: str = ""):
    """The image (lit where `mask` is set, the rest dimmed) and each structure's layer `name`,
    all on one scale (scale: "linear", "log", or None for the one model.scale picks)."""
    go = _go()
    low, high, picked = ex.scale(name)
    scale = scale or picked
    titles = ["image" + (f": {mask_title}" if mask is not None else "")] + [f"{a}: {name}" for a in ex.accels]
    fig = _subplots(1, 1 + len(ex.accels), titles, horizontal_spacing=0.02)
    first = next(iter(ex.runs.values()))
    rgb = _rgb(first.image).astype(np.float64)
    if mask is not None:
        rgb = np.where(mask[..., None], 0.35 * rgb + 0.65 * np.array([255.0, 40.0, 40.0]), 0.3 * rgb)
    fig.add_trace(go.Image(z=rgb.astype(np.uint8), hovertemplate="x %{x}, y %{y}<extra>image</extra>"), 1, 1)
    zmin, zmax = (0.0, max(np.log10(max(high, 1.0)), 1.0)) if scale == "log" else (low, max(high, low + 1.0))
    for k, accel in enumerate(ex.accels):
        v = ex.layer(accel, name)
        fig.add_trace(go.Heatmap(z=scaled(v, scale), customdata=v, coloraxis="coloraxis", name=accel,
                                 hovertemplate=f"x %{{x}}, y %{{y}}<br>{accel} {name} %{{customdata:,}}<extra></extra>"),
                      1, k + 2)
    fig.update_layout(coloraxis={"colorscale": "Viridis", "cmin": zmin, "cmax": zmax,
                                 "colorbar": _colorbar(low, high, scale, f"{name} per sample ({scale}; black: 0)")},
                      plot_bgcolor="black", margin={"l": 10, "r": 10, "t": 40, "b": 10}, height=340)
    _image_axes(fig, 1 + len(ex.accels))
    return fig


def compare_figure(ex: Exploration, name: str):
    """Each structure's log2 ratio against the first (red: more work) and the winner map."""
    go = _go()
    w = ex.work_images(name)
    others = [a for a in ex.accels if a != w.baseline]
    shares = w.shares
    titles = [f"{a} / {w.baseline}" for a in others] + ["least work: " + ", ".join(
        f"{a} {shares[a]:.0%}" for a in ex.accels) + f", tie {shares['tie']:.0%}"]
    fig = _subplots(1, len(others) + 1, titles, horizontal_spacing=0.03)
    ratios = {a: w.ratio(a) for a in others}
    span = max([1.0] + [float(np.abs(r).max()) for r in ratios.values()])
    for k, a in enumerate(others):
        fig.add_trace(go.Heatmap(z=ratios[a], zmin=-span, zmax=span, colorscale="RdBu_r", coloraxis=None,
                                 colorbar={"title": {"text": f"log2((a + 1) / ({w.baseline} + 1))", "side": "right"},
                                           "x": 1.0, "len": 0.9},
                                 showscale=k == 0,
                                 hovertemplate=f"x %{{x}}, y %{{y}}<br>log2 ratio %{{z:.2f}}<extra>{a}</extra>"),
                      1, k + 1)
    winner = w.winner
    names = np.array(ex.accels + ["tie"])
    codes = np.where(winner < 0, len(ex.accels), winner)
    colours = [PALETTE[k % len(PALETTE)] for k in range(len(ex.accels))] + ["#d9d9d9"]
    n = len(colours)
    scale = [[edge / n, c] for i, c in enumerate(colours) for edge in (i, i + 1)]     # one band a structure
    fig.add_trace(go.Heatmap(z=codes, customdata=names[codes], zmin=-0.5, zmax=n - 0.5, colorscale=scale,
                             showscale=False, hovertemplate="x %{x}, y %{y}<br>least work: %{customdata}<extra></extra>"),
                  1, len(others) + 1)
    fig.update_layout(margin={"l": 10, "r": 10, "t": 40, "b": 10}, height=300)
    _image_axes(fig, len(others) + 1)
    return fig


def histogram(values: np.ndarray, scale: str, bins: int = 40) -> tuple:
    """(bin edges, samples in each bin) of a layer: bins even in log10(value + 1) on a log scale."""
    v = np.asarray(values, np.float64).ravel()
    top = max(float(v.max()), 1.0)
    if scale == "log":
        edges = np.unique(np.round(np.logspace(0, np.log10(top + 1.0), bins + 1) - 1.0, 6))
    else:
        edges = np.linspace(float(v.min()), top, bins + 1)
    counts, edges = np.histogram(v, edges)
    return edges, counts


def histograms_figure(ex: Exploration, name: str, scale: str | None = None):
    """A histogram of layer `name` per structure (box-select a range of values: its samples light up)."""
    go = _go()
    low, high, picked = ex.scale(name)
    scale = scale or picked
    fig = _subplots(1, len(ex.accels), [f"{a}: samples by {name}" for a in ex.accels], horizontal_spacing=0.05)
    for k, a in enumerate(ex.accels):
        edges, counts = histogram(ex.layer(a, name), scale)
        mids = 0.5 * (edges[:-1] + edges[1:])
        fig.add_trace(go.Bar(x=mids, y=counts, width=np.diff(edges), name=a, marker_color=PALETTE[k % len(PALETTE)],
                             customdata=np.stack([edges[:-1], edges[1:]], axis=1),
                             hovertemplate="%{customdata[0]:,.0f} to %{customdata[1]:,.0f}: %{y} samples<extra></extra>"),
                      1, k + 1)
        fig.layout[f"xaxis{'' if k == 0 else k + 1}"].update(type="log" if scale == "log" else "linear",
                                                              title={"text": f"{name} ({scale})"})
    fig.update_layout(dragmode="select", selectdirection="h", showlegend=False, height=240,
                      margin={"l": 10, "r": 10, "t": 40, "b": 10})
    return fig


def time_figure(ex: Exploration):
    """Seconds per tile of each structure, one scale: time, kept apart from the counts."""
    go = _go()
    timed = {a: r.tile_seconds for a, r in ex.runs.items() if r.tile_seconds is not None}
    if not timed:
        return None
    micro = {a: t * 1e6 for a, t in timed.items()}
    top = max(float(t.max()) for t in micro.values())
    low = min(float(t[t > 0].min(initial=top)) for t in micro.values())
    scale = "log" if low > 0 and top / low > 10 ** DECADES else "linear"
    fig = _subplots(1, len(timed), [f"{a}: {t.sum() * 1e3:.2f} ms in all" for a, t in timed.items()],
                    horizontal_spacing=0.03)
    for k, (a, t) in enumerate(micro.items()):
        fig.add_trace(go.Heatmap(z=scaled(t, scale), customdata=t, coloraxis="coloraxis",
                                 hovertemplate=f"tile column %{{x}}, row %{{y}}: %{{customdata:,.1f}} µs<extra>{a}</extra>"),
                      1, k + 1)
    zmin, zmax = (np.log10(low), np.log10(top)) if scale == "log" else (0.0, top)
    bar = _colorbar(low, top, scale, f"TIME: µs per tile, one thread ({scale})")
    if scale == "log":
        bar.update(tickvals=list(range(int(np.floor(zmin)), int(np.ceil(zmax)) + 1)),
                   ticktext=[f"{10 ** t:,}" for t in range(int(np.floor(zmin)), int(np.ceil(zmax)) + 1)])
    fig.update_layout(coloraxis={"colorscale": "Inferno", "cmin": zmin, "cmax": zmax, "colorbar": bar},
                      margin={"l": 10, "r": 10, "t": 40, "b": 10}, height=260)
    _image_axes(fig, len(timed))
    return fig


def box_values(run: Run, what: str) -> np.ndarray:
    """The value of each box that colours it: a use (visits, tests, futile, refined), a quality
    (sah, overlap) or a value of the box (depth, items)."""
    if what in run.use:
        return np.asarray(run.use[what], np.float64)
    if what in ("sah", "overlap"):
        return quality(run.boxes)[what]
    return np.asarray(getattr(run.boxes, what), np.float64)


def chosen_boxes(run: Run, what: str, levels=None, depths=None) -> np.ndarray:
    """The boxes drawn: those of the levels and depths in range ((low, high), None: all), the
    MAX_DRAWN that score highest on `what` if there are more."""
    b = run.boxes
    keep = np.ones(len(b), bool)
    if levels is not None:
        keep &= (b.level >= levels[0]) & (b.level <= levels[1])
    if depths is not None:
        keep &= (b.depth >= depths[0]) & (b.depth <= depths[1])
    idx = np.flatnonzero(keep)
    if len(idx) > MAX_DRAWN:
        idx = idx[np.argsort(-box_values(run, what)[idx], kind="stable")[:MAX_DRAWN]]
    return np.sort(idx)


def _wire(corners: np.ndarray):
    """x, y, z of every box's twelve edges, None between segments."""
    seg = corners[:, list(EDGES)]                       # (n, 12, 2, 3)
    pts = np.concatenate([seg, np.full(seg.shape[:2] + (1, 3), np.nan)], axis=2).reshape(-1, 3)
    return pts[:, 0], pts[:, 1], pts[:, 2]


def view_frame(run: Run) -> tuple:
    """(low corner, high corner, middle, longest side) of the structure's boxes: the 3D view's
    axes span them, and plotly's camera is in units of the longest side from the middle."""
    pts = run.boxes.corners.reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return lo, hi, 0.5 * (lo + hi), float(max(np.max(hi - lo), np.finfo(float).tiny))


def camera_from_view(view: dict, frame) -> tuple:
    """(eye, look_at, up) in the scene's space of the 3D view's camera after an orbit or a pan."""
    _, _, mid, side = frame
    vec = lambda d: np.array([float(d[k]) for k in "xyz"])        # noqa: E731
    eye, centre = mid + vec(view["eye"]) * side, mid + vec(view.get("center", {"x": 0, "y": 0, "z": 0})) * side
    return tuple(eye.tolist()), tuple(centre.tolist()), tuple(vec(view.get("up", {"x": 0, "y": 0, "z": 1})).tolist())


def structure_figure(run: Run, what: str = "visits", levels=None, depths=None, visited=None, tested=None,
                     rays=None, selected: int | None = None):
    """The boxes in 3D coloured by `what`; a marker at each box's centre names it (click: its
    pixel mask). visited/tested: boxes a pixel's rays entered and tested items in, drawn thick
    in the colour of their nesting level; rays: explain's rays of that pixel (one legend entry
    a ray type), each with every item it tested, hit or not, in its colour (_add_tested).
    The view opens on the whole structure; camera_from_view reads an orbit."""
    go = _go()
    idx = chosen_boxes(run, what, levels, depths)
    values = box_values(run, what)
    fig = go.Figure()
    corners = run.boxes.corners[idx]
    x, y, z = _wire(corners)
    colour = np.repeat(values[idx], 36)
    fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", name=f"boxes by {what}", hoverinfo="skip",
                               line={"color": colour, "colorscale": "Viridis", "width": 2,
                                     "colorbar": {"title": {"text": what}, "len": 0.6}}))
    centre = corners.mean(axis=1)
    b = run.boxes
    text = [f"box {i}: level {b.level[i]}, depth {b.depth[i]}, {'leaf of ' + str(b.items[i]) + ' items' if b.leaf[i] else 'inner'}"
            f"<br>{what} {values[i]:,.4g}" for i in idx]
    fig.add_trace(go.Scatter3d(x=centre[:, 0], y=centre[:, 1], z=centre[:, 2], mode="markers", name="box centres",
                               customdata=idx.tolist(), text=text, hovertemplate="%{text}<extra></extra>",
                               marker={"size": 3, "color": values[idx], "colorscale": "Viridis", "opacity": 0.6}))
    for label, boxes, width in (("entered", visited, 4), ("tested in", tested, 8)):
        if boxes is None or not len(boxes):
            continue
        for level in np.unique(b.level[boxes]):
            mine = boxes[b.level[boxes] == level]
            x, y, z = _wire(b.corners[mine])
            fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", hoverinfo="skip",
                                       name=f"{label} (level {level})",
                                       line={"color": LEVEL_COLOURS[int(level) % len(LEVEL_COLOURS)], "width": width}))
    if selected is not None and 0 <= selected < len(b):
        x, y, z = _wire(b.corners[[selected]])
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", name=f"box {selected}",
                                   line={"color": "#ff00ff", "width": 10}, hoverinfo="skip"))
    shown = set()
    for k, ray in enumerate(rays or []):
        _add_ray(fig, go, k, ray, run, ray.get("type") not in shown)
        _add_tested(fig, go, k, ray, run)
        shown.add(ray.get("type"))
    frame = view_frame(run)
    lo, hi, _, side = frame
    # the longest side spans one of plotly's units, the view's camera a little over one away
    scene = {"aspectmode": "manual", "aspectratio": dict(zip("xyz", ((hi - lo) / side).tolist())),
             "camera": {"eye": dict(zip("xyz", OPENING_EYE))},
             **{f"{axis}axis": {"range": [float(lo[k]), float(hi[k])], "autorange": False} for k, axis in enumerate("xyz")}}
    fig.update_layout(scene=scene, uirevision=run.accel, margin={"l": 0, "r": 0, "t": 30, "b": 0}, height=520,
                      title={"text": f"{run.accel}: {len(idx):,} of {len(b):,} boxes, coloured by {what}"},
                      legend={"x": 0, "y": 1})
    return fig


def _add_ray(fig, go, k: int, ray: dict, run: Run, legend: bool) -> None:
    if ray.get("culled"):
        return
    o = np.asarray(ray["origin"])
    d = np.asarray(ray["direction"])
    if ray["hit"] is not None:
        t = ray["hit"]["t"]
    else:
        lo, hi = run.boxes.corners.reshape(-1, 3).min(axis=0), run.boxes.corners.reshape(-1, 3).max(axis=0)
        t = ray["tmax"] if ray["tmax"] is not None else float(np.linalg.norm(hi - lo) + np.linalg.norm(o - lo))
    end = o + d * t
    tests = [s for step in ray["steps"] for s in step["tests"] if s["t"] is not None]
    fig.add_trace(go.Scatter3d(x=[o[0], end[0]], y=[o[1], end[1]], z=[o[2], end[2]], mode="lines",
                               name=f"ray {k + 1}: {ray['type']}", hoverinfo="name", legendgroup=str(ray["type"]),
                               showlegend=legend,
                               line={"color": RAY_COLOURS.get(ray["type"], "#7f7f7f"), "width": 5}))
    if tests:
        p = np.array([o + d * s["t"] for s in tests])
        fig.add_trace(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", showlegend=False,
                                   text=[f"{s['primitive']} {s['index']} t={s['t']:.4g}" for s in tests],
                                   hovertemplate="ray " + str(k + 1) + ": tested %{text}<extra></extra>",
                                   marker={"size": 4, "symbol": "x", "color": RAY_COLOURS.get(ray["type"])}))


def _add_tested(fig, go, k: int, ray: dict, run: Run) -> None:
    """The items ray k tested, hit or not, in the ray's colour: each one's box as a wireframe
    (its points' text names it, "polygon 3"), polygons and triangles also as their shape; one pair
    of traces a nesting level, told apart by the box's dash and the shape's opacity."""
    items, _ = tested_items(ray)
    if run.geo is None or not items:
        return
    colour = RAY_COLOURS.get(ray.get("type"), "#7f7f7f")
    for level in sorted({lv for _, _, lv in items}):
        mine = [(kind, i) for kind, i, lv in items if lv == level]
        box = np.array([primitive_box(run.geo, kind, i) for kind, i in mine])          # (n, 2, 3)
        x, y, z = _wire(np.where(CORNERS[None], box[:, None, 1], box[:, None, 0]))
        names = [f"{kind} {i}" for kind, i in mine]
        group = f"tested-{k}-{level}"
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", name=f"ray {k + 1}: tested (level {level})",
                                   text=np.repeat(names, 3 * len(EDGES)).tolist(), legendgroup=group,
                                   hovertemplate=f"ray {k + 1} tested %{{text}} (level {level})<extra></extra>",
                                   line={"color": colour, "width": 3, "dash": LEVEL_DASHES[level % len(LEVEL_DASHES)]}))
        shapes = [primitive_shape(run.geo, kind, i) for kind, i in mine]
        shapes = [(np.asarray(p, np.float64), t) for p, t in (sh for sh in shapes if sh is not None)]
        if not shapes:
            continue
        starts = np.cumsum([0] + [len(p) for p, _ in shapes[:-1]])
        points = np.concatenate([p for p, _ in shapes])
        tri = np.concatenate([t + a for (_, t), a in zip(shapes, starts)])
        fig.add_trace(go.Mesh3d(x=points[:, 0], y=points[:, 1], z=points[:, 2], i=tri[:, 0], j=tri[:, 1], k=tri[:, 2],
                                color=colour, opacity=0.45 / (1 + level), name=f"ray {k + 1}: tested shapes (level {level})",
                                legendgroup=group, showlegend=False, hoverinfo="name", flatshading=True))


def quality_figure(run: Run):
    """Per-node quality: depth and leaf-size histograms, each box's SAH term and overlap."""
    go = _go()
    q = quality(run.boxes)
    depths, at_depth = depth_histogram(run.boxes)
    sizes, of_size = leaf_size_histogram(run.boxes)
    fig = _subplots(1, 4, ["leaves by depth", "leaves by references held", f"SAH terms (sum {q['sah'].sum():,.2f})",
                           f"overlap (boxes overlapping: {int((q['overlap'] > 0).sum()):,})"],
                    horizontal_spacing=0.06)
    fig.add_trace(go.Bar(x=depths, y=at_depth, name="depth"), 1, 1)
    fig.add_trace(go.Bar(x=sizes, y=of_size, name="references"), 1, 2)
    fig.add_trace(go.Histogram(x=q["sah"], nbinsx=40, name="SAH term"), 1, 3)
    fig.add_trace(go.Histogram(x=q["overlap"], nbinsx=40, name="overlap"), 1, 4)
    for k, title in enumerate(("depth", "references", "area share x cost", "shared volume / own volume"), 1):
        fig.layout[f"xaxis{'' if k == 1 else k}"].update(title={"text": title})
        fig.layout[f"yaxis{'' if k == 1 else k}"].update(type="log", title={"text": "boxes" if k == 1 else ""})
    fig.update_layout(showlegend=False, height=260, margin={"l": 10, "r": 10, "t": 40, "b": 10},
                      title={"text": f"{run.accel}: node quality", "x": 0.5, "y": 0.99})
    return fig


def mask_figure(ex: Exploration, accel: str, box: int):
    """The samples whose rays entered box `box` of `accel`, over the image."""
    run = ex.runs[accel]
    mask = run.node_mask(box) > 0
    return layers_figure(ex, ex.settings.counter, mask=mask,
                         mask_title=f"{int(mask.sum())} samples entered box {box} of {accel}")
