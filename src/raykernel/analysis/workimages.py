"""Work images of a comparison: where in the image each structure did its work, on one scale.

    cmp = compare(["scene:stadium"], ["grid", "octree", "bvh"], work="tests.total")
    w = work_images(cmp, "scene:stadium")            # the first structure is the baseline
    w.layers["octree"]          # (h, w) counts of each sample, the render's work layer
    w.ratio("octree")           # signed log2 ratio against the baseline, per sample
    w.winner, w.shares          # which structure did the least work at each sample; share of samples won
    write_figure(w, "stadium-work.png")

A layer holds each sample's whole ray tree's count of one counter (rendering/worklayers.py).
The ratio image is log2((this + 1) / (baseline + 1)): one is added to both so that samples where
neither did any work compare as equal, and one where the baseline did none stays finite. A
sample is won by the structure with the smallest count; where two or more share the smallest,
nobody won it (a tie).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

from ..errors import OptionError

TIE = -1


@dataclass
class WorkImages:
    scene: str
    counter: str
    layers: dict            # structure -> (h, w) array of the counter, one value a sample
    baseline: str

    @property
    def accels(self) -> list:
        return list(self.layers)

    def scale(self) -> tuple:
        """(low, high) of every structure's layer together: the one scale they are drawn on."""
        values = [np.asarray(v) for v in self.layers.values()]
        return float(min(v.min() for v in values)), float(max(v.max() for v in values))

    def ratio(self, accel: str) -> np.ndarray:
        """log2((this + 1) / (baseline + 1)) per sample: > 0 where `accel` did more work."""
        a = np.asarray(self.layers[accel], np.float64)
        b = np.asarray(self.layers[self.baseline], np.float64)
        return np.log2((a + 1.0) / (b + 1.0))

    @property
    def winner(self) -> np.ndarray:
        """Index (into accels) of the structure with the smallest count at each sample; TIE where shared."""
        stack = np.stack([np.asarray(v) for v in self.layers.values()])
        low = stack.min(axis=0)
        best = np.argmin(stack, axis=0).astype(np.int16)
        best[(stack == low).sum(axis=0) > 1] = TIE
        return best

    @property
    def shares(self) -> dict:
        """Share of samples each structure won outright, and "tie" for the rest."""
        w = self.winner
        out = {accel: float(np.mean(w == k)) for k, accel in enumerate(self.accels)}
        out["tie"] = float(np.mean(w == TIE))
        return out


def work_images(cmp, scene: str, baseline: str | None = None) -> WorkImages:
    """The work images of one scene of a comparison made with ``compare(..., work=COUNTER)``.

    Parameters
    ----------
    cmp : Comparison
        A comparison whose runs kept a work layer (`compare`'s `work`).
    scene : str
        The scene's label in the comparison.
    baseline : str, optional
        The structure the others are compared against (default: the first compared).

    Returns
    -------
    WorkImages
        ``layers``: structure -> (h, w) integer array of the counter, one value a sample;
        ``ratio(accel)``: the signed log2 ratio against the baseline, per sample,
        ``log2((this + 1) / (baseline + 1))``; ``winner`` and ``shares``: which structure did
        the least work at each sample (-1 for a tie), and the share of samples each won.

    Raises
    ------
    OptionError
        The comparison has no such scene or no work layers, or `baseline` was not compared.

    Examples
    --------
    >>> cmp = compare(["scene:stadium"], ["grid", "octree", "bvh"], work="tests.total")
    >>> w = work_images(cmp, "scene:stadium")
    >>> write_figure(w, "stadium-work.png")
    """
    runs = [r for r in cmp.runs if r.scene == scene]
    if not runs:
        raise OptionError(f"no scene {scene!r} in this comparison; it has: {', '.join(cmp.scenes())}")
    if any(r.work is None for r in runs):
        raise OptionError("this comparison has no work layers: compare(..., work=COUNTER) records them")
    layers = {r.accel: r.work for r in runs}
    baseline = baseline or runs[0].accel
    if baseline not in layers:
        raise OptionError(f"baseline {baseline!r} is not one of the structures compared: {', '.join(layers)}")
    return WorkImages(scene=scene, counter=cmp.work, layers=layers, baseline=baseline)


def figure_png(w: WorkImages, scale: str = "log") -> bytes:
    """figure(w, scale) as PNG bytes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig = figure(w, scale)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def figure(w: WorkImages, scale: str = "log"):
    """A matplotlib figure: every structure's layer on one shared scale (top row), each structure's
    signed log2 ratio against the baseline and the winner map with each structure's share (bottom
    row); every panel's legend (colour bar or key) in the picture."""
    import matplotlib.pyplot as plt
    from matplotlib import colors
    from matplotlib.patches import Patch

    from ..rendering.worklayers import summary, unit_of

    if scale not in ("linear", "log"):
        raise OptionError(f"scale must be linear or log, got {scale!r}")
    accels = w.accels
    n = len(accels)
    others = [a for a in accels if a != w.baseline]
    cols = max(n, len(others) + 1)
    h, wd = next(iter(w.layers.values())).shape
    size = 3.0
    fig = plt.figure(figsize=(size * cols + 1.2, 2 * size * h / wd + 2.2), dpi=100)
    grid = fig.add_gridspec(2, cols + 1, width_ratios=[1] * cols + [0.06], hspace=0.35, wspace=0.08)
    low, high = w.scale()
    if scale == "log":
        norm = colors.LogNorm(vmin=max(low, 1.0), vmax=max(high, 10.0))
    else:
        norm = colors.Normalize(vmin=low, vmax=max(high, low + 1.0))
    im = None
    for k, accel in enumerate(accels):
        ax = fig.add_subplot(grid[0, k])
        values = np.asarray(w.layers[accel], np.float64)
        shown = np.where(values > 0, values, np.nan) if scale == "log" else values
        cmap = plt.get_cmap("viridis").with_extremes(bad="black")
        im = ax.imshow(shown, cmap=cmap, norm=norm, interpolation="nearest")
        s = summary(values)
        ax.set_title(f"{accel}\nmean {s['mean']:,.1f}  max {s['max']:,.0f}", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    cb = fig.colorbar(im, cax=fig.add_subplot(grid[0, cols]))
    cb.set_label(f"{w.counter} ({unit_of(w.counter)} per sample, {scale}; black: 0)", fontsize=8)

    ratios = {a: w.ratio(a) for a in others}
    span = max([1.0] + [float(np.abs(r).max()) for r in ratios.values()])
    rim = None
    for k, accel in enumerate(others):
        ax = fig.add_subplot(grid[1, k])
        rim = ax.imshow(ratios[accel], cmap="RdBu_r", vmin=-span, vmax=span, interpolation="nearest")
        ax.set_title(f"{accel} / {w.baseline}\nred: more work, blue: less", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    if rim is not None:
        cb = fig.colorbar(rim, cax=fig.add_subplot(grid[1, cols]))
        cb.set_label(f"log2((structure + 1) / ({w.baseline} + 1))", fontsize=8)

    ax = fig.add_subplot(grid[1, len(others)])
    palette = plt.get_cmap("tab10")
    rgb = np.full(w.winner.shape + (3,), 0.85)
    for k in range(n):
        rgb[w.winner == k] = palette(k % 10)[:3]
    ax.imshow(rgb, interpolation="nearest")
    shares = w.shares
    ax.set_title("least work at each sample", fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])
    keys = [Patch(color=palette(k % 10), label=f"{a}: {shares[a]:.1%}") for k, a in enumerate(accels)]
    keys.append(Patch(color=(0.85, 0.85, 0.85), label=f"tie: {shares['tie']:.1%}"))
    ax.legend(handles=keys, loc="upper left", bbox_to_anchor=(0.0, -0.02), fontsize=7, frameon=False)
    fig.suptitle(f"{w.scene}: {w.counter}, every structure on one scale", fontsize=10)
    return fig


def write_figure(w: WorkImages, path, scale: str = "log") -> None:
    from ..atomicfile import write_bytes
    write_bytes(path, figure_png(w, scale))
