"""Work layers: where in the image the work was done, counter by counter, exactly.

    result = render(scene, accel="octree", work=True)
    layers = result.work                    # name -> (h, w) integer array, one value a sample
    layers["tests.total"].sum() == result.stats["tests.total"]
    save_layers(layers, "work.npz")         # np.load("work.npz")["bounds.tests"]; .exr: one channel a layer
    picture(layers, "tests.total", "tests.png", title="balls, octree")    # false colour, legend inside

A layer holds, for every sample, the work of its whole ray tree: the eye ray and every
reflection, refraction and shadow ray it led to (with antialiasing, all of a pixel's samples).
A sample is a pixel, or in SPD mode a pixel corner: the layers of an SPD render are
(height + 1, width + 1), like its traced samples. Layers are named as the statistics table's
counters (every counter: `tests.sphere`, `bounds.tests`, `cells.visited`,
`rays.shadow`, `walk.grid.steps`, ...), with the totals the table shows (`tests.total`,
`hits.total`, `rays.total`), and the three main figures (`tests.total`, `bounds.tests`,
`cells.visited`) split by ray type (`tests.total.shadow`, ...) and, where aggregates nest, by
nesting level (`cells.visited.level1`: the frames one aggregate deep; level 0 the root's and
everything else). Every layer sums to its counter in the table, and the layers are the same at
any thread count and on Dask.
"""

from __future__ import annotations

import io

import numpy as np

from ..aggregates.registry import COUNTER_NAMES
from ..atomicfile import write_bytes
from ..geometry.work import FIGURES, RAY_TYPES, SPLIT
from ..geometry.work import names as split_names
from ..errors import OptionError
from ..geometry import counters as C

TOTALS = {"tests.total": range(C.TESTS, C.TESTS + 5), "hits.total": range(C.HITS, C.HITS + 5),
          "rays.total": (C.RAYS_EYE, C.RAYS_REFLECT, C.RAYS_REFRACT, C.RAYS_SHADOW, C.RAYS_CAST),
          "rays.refract_spd": (C.RAYS_REFRACT, C.RAYS_TIR)}
UNITS = {"tests": "ray/object tests", "hits": "tests that hit", "bounds": "bound tests",
         "cells": "cells or nodes", "rays": "rays", "walk": "steps or tests", "mailbox": "tests saved"}


def work_layers(layer: np.ndarray, levels: int) -> dict:
    """The named layers of a render's sample records (geometry/work.py): views of `layer` for the
    counters it counted, int64 arrays for the totals."""
    out = {}
    for column, name in sorted(COUNTER_NAMES.items()):
        out[name] = layer[:, :, column]
    for name, cols in TOTALS.items():
        out[name] = layer[:, :, list(cols)].sum(axis=2, dtype=np.int64)
    for k, name in enumerate(split_names(levels)):
        out[name] = layer[:, :, SPLIT + k]
    return out


def check_layer_name(name: str) -> None:
    """An OptionError unless a render with work layers can have a layer called `name`."""
    figure, _, part = name.rpartition(".")
    if name in COUNTER_NAMES.values() or name in TOTALS or (
            figure in FIGURES and (part in RAY_TYPES or (part.startswith("level") and part[5:].isdigit()))):
        return
    known = sorted(set(COUNTER_NAMES.values()) | set(TOTALS))
    raise OptionError(f"no work layer {name!r}; layers: {', '.join(known)}, and FIGURE.TYPE or FIGURE.levelN for "
                      f"FIGURE one of {', '.join(FIGURES)} and TYPE one of {', '.join(RAY_TYPES)}")


def unit_of(name: str) -> str:
    return UNITS.get(name.split(".")[0], "counts")


def work_file_format(path) -> str:
    """"npz" or "exr" by the name of `path`, else an OptionError (checked before a render)."""
    suffix = str(path).lower().rsplit(".", 1)[-1]
    if suffix not in ("npz", "exr"):
        raise OptionError(f"{path}: work layers are written as .npz or .exr")
    return suffix


def save_layers(layers: dict, path) -> None:
    """Every layer into `path`: .npz (np.load(path)[name]) or .exr (one 32-bit float channel a
    layer, OpenEXR: the exr extra), written atomically."""
    path = str(path)
    if work_file_format(path) == "npz":
        buf = io.BytesIO()
        np.savez_compressed(buf, **{k: np.asarray(v) for k, v in layers.items()})
        write_bytes(path, buf.getvalue())
    else:
        _save_exr(layers, path)


def _save_exr(layers: dict, path: str) -> None:
    try:
        import OpenEXR
    except ImportError:
        raise OptionError("writing work layers as .exr needs OpenEXR: pip install 'raykernel[exr]'") from None
    import tempfile
    from pathlib import Path
    channels = {name: np.ascontiguousarray(v, np.float32) for name, v in layers.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    target = Path(path)
    with tempfile.NamedTemporaryFile(suffix=".exr", dir=target.parent, delete=False) as tmp:
        pass
    try:
        with OpenEXR.File(header, channels) as f:
            f.write(tmp.name)
        Path(tmp.name).replace(target)
    finally:
        Path(tmp.name).unlink(missing_ok=True)


def summary(values: np.ndarray) -> dict:
    """min, mean, 99th percentile and max of a layer."""
    v = np.asarray(values, np.float64)
    return {"min": float(v.min()), "mean": float(v.mean()), "p99": float(np.percentile(v, 99)),
            "max": float(v.max())}


def picture(layers: dict, name: str, path, title: str = "", scale: str = "linear", vmax: float | None = None,
            cmap: str = "viridis") -> None:
    """A false-colour PNG of layer `name`, the legend in the picture: a colour bar with numbers,
    the counter's name and unit, min / mean / 99th percentile / max, the scale (linear or log)
    and `title` (the scene and the structure). vmax: the top of the scale (default: the layer's
    max), to draw several layers on one scale."""
    if name not in layers:
        raise OptionError(f"no work layer {name!r}; this render has: {', '.join(sorted(layers))}")
    values = np.asarray(layers[name], np.float64)
    _figure(values, name, path, title, scale, vmax, cmap)


def _figure(values, name, path, title, scale, vmax, cmap, label=None, norm=None, ticks=None):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import colors

    if scale not in ("linear", "log"):
        raise OptionError(f"scale must be linear or log, got {scale!r}")
    s = summary(values)
    top = float(vmax if vmax is not None else max(s["max"], 1.0))
    if norm is None:
        norm = colors.LogNorm(vmin=1.0, vmax=max(top, 10.0)) if scale == "log" else colors.Normalize(0.0, top)
    h, w = values.shape
    fig = plt.figure(figsize=(7.2, 7.2 * h / w + 1.4), dpi=110)
    ax = fig.add_axes([0.04, 0.2, 0.78, 0.72])
    shown = np.where(values > 0, values, np.nan) if scale == "log" else values
    im = ax.imshow(shown, cmap=cmap, norm=norm, interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=10)
    bar = fig.add_axes([0.85, 0.2, 0.03, 0.72])
    cb = fig.colorbar(im, cax=bar, ticks=ticks)
    cb.set_label(label or f"{name} ({unit_of(name)} per sample, {scale})", fontsize=9)
    fig.text(0.04, 0.07, f"{name}: min {s['min']:,.0f}   mean {s['mean']:,.2f}   99th percentile {s['p99']:,.0f}   "
                         f"max {s['max']:,.0f}   sum {values.sum():,.0f}", fontsize=9)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    write_bytes(path, buf.getvalue())
