"""One pixel explained: its ray tree re-traced with every step of every walk logged.

    ex = explain(scene, 40, 12, accel="octree", resolution=64)     # column 40, row 12 from the top
    print(text(ex))                     # each ray: type, origin, direction, hit; its steps, level by level
    ex["totals"]["tests.total"]         # the pixel's value in the work layers of the same render
    write_json(ex, "pixel.json")

The render is the one `render(scene, ..., work=True)` makes with the same options: the pixel's
tile is traced alone (every tile starts from the same state), or, for lazy structures, which
refine between passes, the whole render. While it traces, the kernels log the pixel's events
(geometry/work.py, Probe): each search (traverse.intersect: origin, direction, mode), the root
and child aggregates it entered, each step of each walk (the nodes or cells visited and the
bounds tested on the way, the references reached), each primitive tested (and its t), the
search's answer and what it counted; the shading loop says which ray type each search was.
`totals` are the pixel's work layers; the searches' own counts add up to them, less what
Haines's tricks counted outside any search (the shadow cache's and the ray tree's tries),
which `outside` gives. In SPD mode the samples are the pixel corners: (X, Y) is the corner at
the top left of pixel (X, Y), as in the (height + 1, width + 1) work layers.
"""

from __future__ import annotations

import json
import math

import numpy as np

from ..aggregates.registry import KINDS
from ..atomicfile import write_text
from ..geometry.work import CULLED, ENTER, FIGURES, FOUND, OVERFLOW, SEARCH, STEP, TEST, TYPE, RAY_TYPES, probe
from ..errors import OptionError
from ..geometry.primitives import PRIMITIVE_KINDS as KIND_NAMES
from .render import TILE, RenderJob

MODES = {0: "closest", 1: "any hit", 2: "all hits", 3: "any opaque", 4: "closest (eager normals)"}


def explain(scene, x: int, y: int, capacity: int = 1 << 14, **options) -> dict:
    """The ray tree of the sample at column x, row y, with render's options (accel, resolution,
    spd, shading, aa, tricks, ...): a dict with `pixel`, `rays` (one dict a search) and `totals`."""
    for name, value in (("x", x), ("y", y)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise OptionError(f"pixel {name} must be a whole number, got {value!r}")
    job = RenderJob(scene, **options, work=True)
    if not (0 <= x < job.sw and 0 <= y < job.sh):
        raise OptionError(f"pixel ({x}, {y}) is outside the {job.sw}x{job.sh} samples of this render "
                          f"(columns 0..{job.sw - 1}, rows 0..{job.sh - 1})")
    while True:
        job.probe = probe(y, x, capacity)
        _trace(job, x, y)
        if not job.probe.state[OVERFLOW]:
            break
        capacity *= 8
        job = RenderJob(scene, **options, work=True)
    log = job.probe.log[:job.probe.state[0]]
    rays, outside = _rays(log, job)
    totals = {name: int(layer[y, x]) for name, layer in _layers(job).items()}
    counted = {f: sum(r["counted"][f] for r in rays) for f in FIGURES}
    outside.update({f: totals[f] - counted[f] for f in FIGURES if totals[f] != counted[f]})
    return {"pixel": [int(x), int(y)], "accel": options.get("accel", "bvh"), "rays": rays, "outside": outside,
            "totals": totals, "culled": bool(any(row[0] == CULLED for row in log))}


def _trace(job: RenderJob, x: int, y: int) -> None:
    """Trace what the probed sample needs: its tile alone, or every pass of a lazy render."""
    if job.lazy_columns is None:
        tiles_x = -(-job.sw // TILE)
        tile = (y // TILE) * tiles_x + x // TILE
        job.trace(0, tile, tile + 1, threads=1)
        return
    for p in range(len(job.passes)):
        job.trace_pass(p, job.threads)
        job.end_pass(p)


def _layers(job: RenderJob) -> dict:
    from .worklayers import work_layers
    return work_layers(job.layer, job.levels)


def _kind_name(job: RenderJob, code: int) -> str:
    names = [k.walk.name for k in KINDS.values() if k.walk is not None and k.walk.code == code]
    return names[0] if names else f"kind {code}"


def _rays(log: np.ndarray, job: RenderJob):
    """The searches of the log, each with its steps and tests, typed by the TYPE marks."""
    rays, untyped, outside = [], [], {"tests": []}
    current = None
    for row in log:
        code = int(row[0])
        if code == SEARCH:
            current = {"type": None, "mode": MODES.get(int(row[1]), str(int(row[1]))),
                       "origin": [float(v) for v in row[2:5]], "direction": [float(v) for v in row[5:8]],
                       "tmin": float(row[8]), "tmax": _finite(row[9]), "hit": None, "entered": [], "steps": []}
        elif code == FOUND and current is not None:
            if row[1]:
                current["hit"] = {"t": float(row[2]), "primitive": KIND_NAMES[int(row[3])], "index": int(row[4]),
                                  "instance": int(row[5])}
            current["counted"] = dict(zip(FIGURES, (int(row[6]), int(row[7]), int(row[8]))))
            rays.append(current)
            untyped.append(current)
            current = None
        elif code == ENTER and current is not None:
            current["entered"].append({"level": int(row[1]), "aggregate": int(row[2]), "instance": int(row[3]),
                                       "bounds_hit": bool(row[4])})
        elif code == STEP and current is not None:
            current["steps"].append({"level": int(row[1]), "aggregate": int(row[2]),
                                     "walk": _kind_name(job, int(row[3])), "visited": int(row[4]),
                                     "bounds": int(row[5]), "references": [int(row[6]), int(row[7])], "tests": []})
        elif code == TEST:
            test = {"primitive": KIND_NAMES[int(row[3])], "index": int(row[4]), "t": _finite(row[5]),
                    "level": int(row[1])}
            if row[5] == -math.inf:
                test["t"], test["crossings"] = None, True
            if current is None:
                outside["tests"].append(test)
            elif current["steps"]:
                current["steps"][-1]["tests"].append(test)
            else:
                current.setdefault("tests", []).append(test)
        elif code == TYPE:
            for ray in untyped:
                ray["type"] = RAY_TYPES[int(row[1])]
            untyped = []
        elif code == CULLED:
            rays.append({"type": "eye", "mode": "closest", "culled": True, "hit": None, "entered": [], "steps": [],
                         "counted": {"tests.total": 0, "bounds.tests": 1, "cells.visited": 0}})
    if not outside["tests"]:
        del outside["tests"]
    return rays, outside


def _finite(v):
    return float(v) if math.isfinite(v) else None


def text(ex: dict) -> str:
    """The explanation as lines to read."""
    x, y = ex["pixel"]
    types = {}
    for r in ex["rays"]:
        types[r["type"]] = types.get(r["type"], 0) + 1
    lines = [f"pixel ({x}, {y}), accel {ex['accel']}: " + ", ".join(f"{n} {t} ray{'s' * (n > 1)}"
                                                                     for t, n in types.items())]
    for k, r in enumerate(ex["rays"], 1):
        if r.get("culled"):
            lines.append(f"{k}. eye ray: its tile's rays all miss the scene's box (frustum culled): 1 bound test")
            continue
        hit = r["hit"]
        found = (f"hit {hit['primitive']} {hit['index']} at t={hit['t']:.6g}" if hit else "no hit")
        lines.append(f"{k}. {r['type']} ray ({r['mode']}) from ({_v(r['origin'])}) along ({_v(r['direction'])}): "
                     f"{found}")
        for e in r["entered"]:
            what = "entered" if e["bounds_hit"] else "missed"
            lines.append(f"   {'  ' * e['level']}level {e['level']}: {what} the box of aggregate {e['aggregate']}"
                         + (f" (instance {e['instance']})" if e["instance"] >= 0 else ""))
        for s in r["steps"]:
            lo, hi = s["references"]
            leaf = f" -> references {lo}..{hi - 1}" if hi > lo else " -> no references"
            tests = ", ".join(_test(t) for t in s["tests"])
            lines.append(f"   {'  ' * s['level']}level {s['level']} {s['walk']} (aggregate {s['aggregate']}): "
                         f"{s['visited']} visited, {s['bounds']} bound tests{leaf}" + (f": {tests}" if tests else ""))
        c = r["counted"]
        lines.append(f"   counted: {c['tests.total']} tests, {c['bounds.tests']} bound tests, "
                     f"{c['cells.visited']} cells or nodes visited")
    if ex["outside"]:
        lines.append("counted outside the searches (Haines's tricks): " + ", ".join(
            f"{k} {v}" for k, v in ex["outside"].items() if k != "tests"))
    t = ex["totals"]
    shown = [k for k in ("tests.total", "bounds.tests", "cells.visited", "rays.total", "rays.shadow") if k in t]
    lines.append("totals (the work layers at this pixel): " + ", ".join(f"{k} {t[k]:,}" for k in shown))
    return "\n".join(lines)


def _v(values) -> str:
    return ", ".join(f"{v:.4g}" for v in values)


def _test(t: dict) -> str:
    if t.get("crossings"):
        return f"{t['primitive']} {t['index']} (crossings)"
    return f"{t['primitive']} {t['index']}" + (f" hit t={t['t']:.6g}" if t["t"] is not None else "")


def write_json(ex: dict, path) -> None:
    write_text(path, json.dumps(ex, indent=1) + "\n")
