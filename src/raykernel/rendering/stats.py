"""Statistics of a render or a ray batch: counts, build figures and times.

    stats = result.stats
    stats["rays.eye"], stats["tests.per_ray"]
    print(stats.table_text());  stats.to_json("stats.json")

Counts are exact integers summed over tiles. Per-ray figures (N_IT, N_TS,
N_ETS, N_EETS) divide by all rays cast (eye + reflect + refract + shadow).
"""

from __future__ import annotations

import json

import numpy as np

from ..aggregates.registry import COUNTER_NAMES, WALKS
from ..engine.transforms import AFFINE, TRANSFORM_MULTIPLIES

RAY_KINDS = ("eye", "reflect", "refract", "shadow")


class Stats(dict):
    """A flat dict of named figures, plus `aggregates` (one dict per built aggregate) and `info`."""

    aggregates: list
    info: dict

    @classmethod
    def from_counters(cls, totals: np.ndarray, build: dict, preprocess: float, trace: float, info: dict,
                      compile: float = 0.0, anneal: float = 0.0, load: float = 0.0, parse: float = 0.0):
        """compile, load: seconds spent compiling kernels and loading compiled ones from the cache
        (start-up), already left out of `preprocess` and `trace`; anneal: seconds spent finding
        the hierarchy of an `auto` spec, before the build; parse: seconds spent reading the scene."""
        s = cls()
        for column, name in COUNTER_NAMES.items():
            s[name] = int(totals[column])
        s["tests.total"] = sum(s[f"tests.{k}"] for k in ("sphere", "polygon", "patch", "cone", "triangle"))
        rays = s["rays.eye"] + s["rays.reflect"] + s["rays.refract"] + s["rays.shadow"] + s["rays.cast"]
        s["rays.total"] = rays
        # the SPD's published tables count a refraction ray at every transmitting hit below the
        # depth limit, total internal reflections included (docs/guide/rendering.md, "Shading")
        s["rays.refract_spd"] = s["rays.refract"] + s["rays.tir"]
        per = max(rays, 1)
        s["tests.per_ray"] = s["tests.total"] / per
        s["bounds.per_ray"] = s["bounds.tests"] / per
        s["cells.visited_per_ray"] = s["cells.visited"] / per
        s["cells.leaves_per_ray"] = s["cells.leaves"] / per
        s["cells.empty_per_ray"] = s["cells.empty"] / per
        for key, value in build.items():
            if key.startswith("build."):
                s[key] = value
        s["time.parse"] = parse
        s["time.preprocess"] = preprocess
        s["time.trace"] = trace
        s["time.compile"] = compile
        s["time.load"] = load
        s["time.anneal"] = anneal
        mapped = sum(s[f"transforms.{k}"] for k in ("identity", "translation", "scale", "affine"))
        s["transforms.multiplies_saved"] = TRANSFORM_MULTIPLIES[AFFINE] * mapped - s["transforms.multiplies"]
        s["time.rays_per_second"] = rays / trace if trace > 0 else 0.0
        s.aggregates = list(build.get("aggregates", []))
        s.info = dict(info)
        return s

    def to_dict(self) -> dict:
        return {"counters": dict(self), "aggregates": self.aggregates, "info": self.info}

    def to_json(self, path) -> None:
        from ..atomicfile import atomic_write
        with atomic_write(path) as f:
            json.dump(self.to_dict(), f, indent=2, default=jsonable)
            f.write("\n")

    def rows(self):
        """(section, name, value text) for a readable table."""
        out = []
        for kind in RAY_KINDS:
            hit = "blocked" if kind == "shadow" else "hit"
            out.append(("rays", kind, f"{self[f'rays.{kind}']:,}", f"{self[f'rays.{kind}_{hit}']:,} {hit}"))
        if self.get("rays.tir"):
            out.append(("rays", "total internal", f"{self['rays.tir']:,}",
                        f"reflections; {self['rays.refract_spd']:,} refraction rays as the SPD counts them"))
        if self.get("rays.cut_off"):
            out.append(("rays", "cut off", f"{self['rays.cut_off']:,}", "not cast: weight below the cut-off"))
        if self.get("rays.cast"):
            out.append(("rays", "cast", f"{self['rays.cast']:,}", ""))
        for k in ("sphere", "polygon", "patch", "cone", "triangle"):
            if self[f"tests.{k}"]:
                out.append(("tests", k, f"{self[f'tests.{k}']:,}", f"{self[f'hits.{k}']:,} hit"))
        if self.get("polygon.corners"):
            out.append(("tests", "polygon corners", f"{self['polygon.corners']:,}", "walked by inside tests"))
        out.append(("tests", "total", f"{self['tests.total']:,}", f"{self['tests.per_ray']:.2f} per ray (N_IT)"))
        out.append(("traversal", "bound tests", f"{self['bounds.tests']:,}", f"{self['bounds.per_ray']:.2f} per ray"))
        out.append(("traversal", "cells visited", f"{self['cells.visited']:,}",
                    f"{self['cells.visited_per_ray']:.2f} per ray (N_TS)"))
        out.append(("traversal", "leaves visited", f"{self['cells.leaves']:,}",
                    f"{self['cells.leaves_per_ray']:.2f} per ray (N_ETS)"))
        out.append(("traversal", "empty leaves", f"{self['cells.empty']:,}",
                    f"{self['cells.empty_per_ray']:.2f} per ray (N_EETS)"))
        if self.get("frustum.culled"):
            out.append(("traversal", "culled eye rays", f"{self['frustum.culled']:,}",
                        "tiles whose eye rays all miss the scene: not traced"))
        if self.get("mailbox.saved"):
            out.append(("traversal", "mailbox saved", f"{self['mailbox.saved']:,}", ""))
        for walk in WALKS:
            if walk.stats_rows is not None:
                out.extend(walk.stats_rows(self))       # the rows of its own counters
        out.append(("build", "nodes", f"{self.get('build.nodes', 0):,}",
                    f"{self.get('build.aggregates', 0)} aggregate(s)"))
        out.append(("build", "refs", f"{self.get('build.refs', 0):,}", ""))
        out.append(("build", "bytes", f"{self.get('build.bytes', 0):,}", ""))
        if self.get("time.parse"):
            out.append(("time", "parse", f"{self['time.parse']:.3f} s", "reading the scene"))
        out.append(("time", "preprocess", f"{self['time.preprocess']:.3f} s", ""))
        out.append(("time", "trace", f"{self['time.trace']:.3f} s",
                    f"{self['time.rays_per_second'] / 1e6:.2f} Mrays/s"))
        if self.get("time.anneal"):
            out.append(("time", "anneal", f"{self['time.anneal']:.1f} s", "finding the hierarchy (auto)"))
        if self.get("time.compile"):
            out.append(("time", "compile", f"{self['time.compile']:.1f} s", "kernels compiled (first run only)"))
        if self.get("time.load"):
            out.append(("time", "load", f"{self['time.load']:.3f} s", "compiled kernels loaded (start-up)"))
        return out

    def table(self, title: str | None = None):
        """A rich Table of the main figures."""
        from rich.table import Table
        table = Table(title=title, show_edge=False, header_style="bold")
        for col, justify in (("", "left"), ("", "left"), ("count", "right"), ("", "left")):
            table.add_column(col, justify=justify, overflow="fold")     # wrapped where narrow, never cut short
        last = None
        for section, name, value, note in self.rows():
            table.add_row(section if section != last else "", name, value, note)
            last = section
        return table

    def table_text(self) -> str:
        import io

        from rich.console import Console
        console = Console(width=100, file=io.StringIO(), emoji=False)
        console.print(self.table())
        return console.file.getvalue()

    def _repr_html_(self) -> str:
        cells = "".join(f"<tr><td>{s}</td><td>{n}</td><td style='text-align:right'>{v}</td><td>{note}</td></tr>"
                        for s, n, v, note in self.rows())
        return f"<table>{cells}</table>"


def jsonable(value):
    """value as JSON writes it: numpy numbers and arrays made Python ones, tuples lists, inside
    dicts and lists too; anything else JSON cannot write as its str (also json.dump's default=)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value)
