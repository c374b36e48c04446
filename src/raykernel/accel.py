"""Accelerator specs: the little language that names an acceleration structure.

    kind, params = parse_spec("bvh(leaf=4, bins=16)")
    print(describe())          # every kind with its parameters and defaults

A spec is a kind name, optionally followed by `key=value` parameters in
parentheses. Each kind registers its parameters with defaults and checks;
unknown names, unknown parameters and values out of range are OptionErrors
that list what is allowed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from .errors import OptionError


@dataclass(frozen=True)
class Param:
    name: str
    default: object
    help: str
    kind: type = int            # int, float, str or bool
    low: float | None = None
    high: float | None = None
    choices: tuple = ()

    def parse(self, text: str, spec: str):
        text = text.strip()
        try:
            if self.kind is bool:
                if text.lower() not in ("on", "off", "true", "false", "1", "0", "yes", "no"):
                    raise ValueError
                value = text.lower() in ("on", "true", "1", "yes")
            elif self.kind is str:
                value = text
            else:
                value = self.kind(text)
        except ValueError:
            raise OptionError(f"accelerator spec {spec!r}: {self.name} must be {self._what()}, got {text!r}") from None
        self.check(value, spec)
        return value

    def check(self, value, spec: str):
        if self.choices and value not in self.choices:
            raise OptionError(f"accelerator spec {spec!r}: {self.name} must be one of "
                              f"{', '.join(map(str, self.choices))}, got {value!r}")
        if self.low is not None and value < self.low or self.high is not None and value > self.high:
            raise OptionError(f"accelerator spec {spec!r}: {self.name} must be {self._what()}, got {value!r}")

    def _what(self) -> str:
        if self.kind is bool:
            return "on or off"
        if self.choices:
            return "one of " + ", ".join(map(str, self.choices))
        name = {int: "an integer", float: "a number", str: "a word"}[self.kind]
        if self.low is not None and self.high is not None:
            return f"{name} in [{self.low}, {self.high}]"
        if self.low is not None:
            return f"{name} >= {self.low}"
        return name


@dataclass(frozen=True)
class Kind:
    name: str
    help: str
    params: tuple = ()
    builder: object = field(default=None, compare=False)

    def defaults(self) -> dict:
        return {p.name: p.default for p in self.params}


KINDS: dict[str, Kind] = {}


def register(kind: Kind) -> Kind:
    KINDS[kind.name] = kind
    return kind


_SPEC = re.compile(r"^\s*([A-Za-z_][\w-]*)\s*(?:\((.*)\))?\s*$", re.S)


def parse_spec(spec: str) -> tuple[str, dict]:
    """'kind(key=value, ...)' -> (kind, parameters with defaults filled in)."""
    if not isinstance(spec, str):
        raise OptionError(f"an accelerator spec must be a string, got {spec!r}")
    m = _SPEC.match(spec)
    if not m:
        raise OptionError(f"accelerator spec {spec!r} is not of the form kind or kind(key=value, ...); "
                          f"kinds: {', '.join(KINDS)}")
    name, body = m.group(1).lower(), m.group(2)
    if name not in KINDS:
        raise OptionError(f"unknown accelerator {name!r} in spec {spec!r}; kinds: {', '.join(KINDS)}")
    kind = KINDS[name]
    params = kind.defaults()
    allowed = {p.name: p for p in kind.params}
    if body is not None and body.strip():
        for item in body.split(","):
            if "=" not in item:
                raise OptionError(f"accelerator spec {spec!r}: expected key=value, got {item.strip()!r}")
            key, value = (s.strip() for s in item.split("=", 1))
            if key not in allowed:
                known = ", ".join(allowed) or "none"
                raise OptionError(f"accelerator spec {spec!r}: {name} has no parameter {key!r}; "
                                  f"its parameters: {known}")
            params[key] = allowed[key].parse(value, spec)
    return name, params


def format_spec(name: str, params: dict) -> str:
    """The canonical spec string: only parameters that differ from the defaults."""
    kind = KINDS[name]
    changed = [f"{p.name}={_fmt(params[p.name])}" for p in kind.params if params.get(p.name, p.default) != p.default]
    return f"{name}({', '.join(changed)})" if changed else name


def _fmt(value) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    return str(value)


def describe() -> str:
    """A plain-text list of every kind with its parameters and defaults."""
    lines = []
    for kind in KINDS.values():
        lines.append(f"{kind.name}: {kind.help}")
        for p in kind.params:
            lines.append(f"    {p.name}={_fmt(p.default)}  ({p._what()}) {p.help}")
    return "\n".join(lines)


register(Kind("list", "brute force: test every child"))
register(Kind("bvh", "bounding volume hierarchy: binned surface-area heuristic (build=sah) or "
              "Goldsmith-Salmon insertion (build=gs)", (
    Param("leaf", 4, "maximum items in a leaf the SAH may keep (sah only; gs leaves hold one item)", int, 1, 64),
    Param("bins", 16, "SAH bins per axis (sah only)", int, 2, 256),
    Param("build", "sah", "sah: top-down binned SAH; gs: Goldsmith-Salmon 1987 incremental insertion",
          str, choices=("sah", "gs")),
    Param("order", "file", "gs insertion order: file (as given), shuffle (seeded permutation) or curve "
          "(Morton order of the box centres); ignored by sah", str, choices=("file", "shuffle", "curve")),
    Param("seed", 1, "seed of order=shuffle (gs only)", int, 0, 2 ** 31 - 1),
)))
register(Kind("grid", "uniform grid (Fujimoto) traversed with the 3D-DDA (Amanatides-Woo)", (
    Param("res", "regular", "resolution rule: regular (about density*N cubic cells), woo "
          "(longest side density*N^(1/3) cells) or klimaszewski (our reading of Klimaszewski's heterogeneous "
          "rule: per axis, cells about the items' mean extent, scaled down to at most density*N cells; "
          "regular where the items have no extent)", str, choices=("regular", "woo", "klimaszewski")),
    Param("density", 2.0, "cells per item (regular) or per cube root of the item count (woo)", float, 0.001, 1000.0),
    Param("max_res", 256, "most cells along any axis", int, 1, 4096),
    Param("mailbox", True, "skip items already tested against the ray in an earlier cell", bool),
)))
register(Kind("hgrid", "hierarchical grid: a uniform grid whose cells with more than threshold references hold "
              "a sub-grid over those items instead, recursively", (
    Param("res", "regular", "resolution rule of every level: regular, woo or klimaszewski (see grid)", str,
          choices=("regular", "woo", "klimaszewski")),
    Param("density", 2.0, "cells per item at every level (see grid)", float, 0.001, 1000.0),
    Param("max_res", 256, "most cells along any axis of any level", int, 1, 4096),
    Param("threshold", 8, "a cell holding more references than this gets a sub-grid", int, 1, 1 << 30),
    Param("depth", 2, "most levels of sub-grids below the top grid (clamped so that no ray path nests more "
          "than 16 aggregates)", int, 0, 15),
    Param("mailbox", True, "skip items already tested against the ray in an earlier cell of the same grid", bool),
)))
register(Kind("rc", "ray classification (Arvo-Kirk 1987): rays as 5D points (origin, direction-cube face and "
              "u, v), six 5D bisection trees, candidate lists tested near first; lazy (default): each face's root "
              "starts as one leaf, and between passes of rays (those of lazyoctree) a leaf where at least `rays` "
              "rays arrived is split, several levels where the arrivals go on; lazy=off builds the whole trees "
              "before any ray", (
    Param("leaf", 8, "a hypercube with at most this many candidates is not split", int, 1, 1 << 20),
    Param("depth", 40, "most splits below a face's root hypercube", int, 0, 200),
    Param("budget_mb", 256.0, "MiB the trees and candidate lists may take; reaching it stops subdivision "
          "with a warning (hits stay exact)", float, 0.0, 1 << 20),
    Param("lazy", True, "on: subdivide lazily where rays arrive (Arvo and Kirk), a hypercube stopping after 40 "
          "splits in a row that each keep more than 3/4 of its candidates; off: eagerly, breadth first over all "
          "of 5D space until leaf, depth, 5 such splits or the budget stop it", bool),
    Param("rays", 1, "lazy: rays that must arrive at a leaf before it is split", int, 1, 1 << 40),
)))
register(Kind("octree", "octree (Glassner 1984): centre subdivision of the scene box (not made cubic), "
              "objects in every child their box overlaps; nodes with the most items times box area are split "
              "first, until depth, leaf, the criteria or the reference budget stop them. Defaults: depth 16 and "
              "budget 16 keep memory proportional to the items (under 20 MB on every SPD default scene; without "
              "a budget, items no split separates grow the tree as 8^depth: 11.6 GB on SPD shells at depth 8) "
              "while small clusters in big boxes still get resolved; rule60 stays off, as it stops subdivision "
              "early wherever a large floor polygon reaches into the other octants", (
    Param("depth", 16, "maximum subdivision depth (the root is level 0)", int, 0, 24),
    Param("leaf", 3, "a node holding at most this many items (or vertices, see vertexcount) is a leaf", int, 1,
          1 << 20),
    Param("rule60", False, "Haines's problem-voxel rule: keep a node a leaf when its largest child would "
          "still hold >= 60% of its items (unless it is the only occupied child)", bool),
    Param("density", 0.0, "Glassner's density criterion: subdivide only while the items' volume clipped to "
          "the cell, over the cell volume, is under this ratio (0: off)", float, 0.0, 1e6),
    Param("vertexcount", False, "count polygon/patch vertices and 3 per triangle instead of items against "
          "leaf (Glassner's measure)", bool),
    Param("collapse", True, "a node with one non-empty child takes that child's subtree and box; the walks "
          "step through the removed empty octants using the address bits", bool),
    Param("walk", "neighbor", "traversal: point (top-down point location with Lathrop's 28-bit addresses), "
          "neighbor (Glassner's 6 neighbour pointers per node, then descent), parametric (Revelles, Urena and "
          "Lastra 2000)", str, choices=("point", "neighbor", "parametric")),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
    Param("budget", 16.0, "the leaves together hold at most budget * items + 4096 references; a split that "
          "would exceed it is skipped (0: no limit)", float, 0.0, 1e6),
)))
register(Kind("hybrid", "Haines's hybrid (RTN 2(1), 1988): an octree whose problem voxels (leaves the "
              "subdivision left holding more than threshold items: depth limit, rule60, density) each hold "
              "a Goldsmith-Salmon BVH over their items, cut to the voxel", (
    Param("depth", 8, "maximum octree depth (see octree)", int, 0, 24),
    Param("leaf", 3, "an octree node holding at most this many items is a leaf (see octree)", int, 1, 1 << 20),
    Param("rule60", True, "Haines's 60% problem-voxel rule (see octree)", bool),
    Param("density", 0.0, "Glassner's density criterion, 0: off (see octree)", float, 0.0, 1e6),
    Param("vertexcount", False, "count vertices instead of items against leaf (see octree)", bool),
    Param("collapse", True, "collapse single-child chains (see octree)", bool),
    Param("budget", 16.0, "the octree's leaves hold at most budget * items + 4096 references, 0: no limit "
          "(see octree)", float, 0.0, 1e6),
    Param("threshold", 8, "a leaf holding more items than this is a problem voxel and gets a BVH", int, 1,
          1 << 30),
    Param("order", "file", "insertion order of the voxels' BVHs: file, shuffle or curve (see bvh, build=gs)",
          str, choices=("file", "shuffle", "curve")),
    Param("seed", 1, "seed of order=shuffle", int, 0, 2 ** 31 - 1),
    Param("walk", "neighbor", "octree traversal: point, neighbor or parametric (see octree)", str,
          choices=("point", "neighbor", "parametric")),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf of the octree", bool),
)))
register(Kind("lazyoctree", "lazy octree (Lathrop 1988): one leaf at first; between passes of rays (passes "
              "that trace a render coarse to fine: one sample per tile, then the samples between, level by "
              "level; RayScene from 16 rays up to 8 chunks of 8192) a leaf is split, as the octree splits, when "
              "it meets I-V (and VI with rule60) and the reference budget allows: I level < depth, II not empty, III more than one item (M > 1), IV at least `rays` rays passed through it "
              "without a hit in it since it was made (N >= rays), V M*k < N; passes beyond what a split needed "
              "are shared among the children, which may split in the same refinement", (
    Param("depth", 16, "criterion I: most levels (the root is level 0; 0 never refines)", int, 0, 24),
    Param("rays", 2, "criterion IV: rays that must pass through a leaf without a hit in it before it may split",
          int, 1, 1 << 40),
    Param("k", 0.0, "criterion V: a leaf of M items splits only after more than k*M passes (0: off)", float,
          0.0, 1e9),
    Param("rule60", False, "criterion VI, Haines's problem-voxel rule: a leaf whose largest child would still "
          "hold >= 60% of its items (unless the only occupied one) stays a leaf for good", bool),
    Param("budget", 16.0, "the leaves hold at most budget * items + 4096 references; a split past it is not made "
          "and its leaf stays a leaf (0: no budget)", float, 0.0, 1e6),
    Param("walk", "neighbor", "traversal: point, neighbor or parametric (see octree)", str,
          choices=("point", "neighbor", "parametric")),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
)))
