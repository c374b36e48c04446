"""Accelerator specs, and what every aggregate kind declares about itself.

    KIND = Kind("bvh", "help", (Param("leaf", 4, "help", int, 1, 64), ...), flatten=flatten, walk=WALK)
    name, params = parse(spec, KINDS)      # registry.parse_spec(spec) with the registered kinds
    format_spec(name, params, KINDS)       # the canonical string: only non-default parameters

A spec is a kind name, optionally followed by `key=value` parameters in
parentheses ("bvh(leaf=4, bins=16)"). Each kind declares its parameters with
defaults and checks; unknown names, unknown parameters and values out of
range are OptionErrors that list what is allowed. The kinds themselves are
collected by the registry (registry.py); this module only describes them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..errors import OptionError
from .walk import Walk


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
class Search:
    """What the searches for a hierarchy (analysis/anneal.py, the cost model's calibration) may try
    of a kind: `start`, the kind at its defaults, and `variants`, specs they start from over the
    whole target; `candidates`, specs a group may be given; `max_items`, when non-zero, the most
    primitives of a group it is offered to (and of a scene it is calibrated on: a brute-force
    search grows with the items)."""
    start: bool = False
    variants: tuple = ()
    candidates: tuple = ()
    max_items: int = 0


@dataclass(frozen=True)
class Kind:
    """One aggregate kind, as its module declares it (KIND, or KINDS for several):
    name and help, as `raykernel accels` lists them; params, its spec's parameters;
    flatten(builder, params, refs, bounds, name, box) -> (aggregate index, build statistics), which
    stores it in the flat arrays (engine/flatten.py's Builder); walk, the Walk its aggregates are
    stored with (another kind's where it builds those: hgrid grids, hybrid and lazyoctree octrees);
    lazy, a class that refines its aggregates between passes of rays, whose `attach(geo, records,
    base)` takes over the arrays flatten's records name (FlatArrays.lazy[name]); refit(flat, agg,
    memo, refs, old_bounds, bounds, params, threshold), where an animation's frame may keep an
    aggregate whose items moved (engine/incremental.py): the nodes it touched, or None to have it
    rebuilt (memo: a dict it may keep between frames); search, what the annealer may try of it. An operator (aggregates/collect.py) has `operands`: its items are the
    group's children, one reference each, never merged; in a JSON scene an item {name: {list:
    [items], ...}} for each of operand_lists, its operands their items in order, its group's spec
    operand_spec(the lists' lengths) (None: the kind's name), at most max_operands of them (0: no
    limit). scene_walk: a module that walks a whole scene that is one aggregate of this kind over
    primitives faster than the driver can (aggregates/widewalk.py: NO_WALK, prepare, walks,
    intersect, alone, with_driver, count_misses); one kind declares one (the registry holds it to
    that), and the engine hands it such scenes."""
    name: str
    help: str
    params: tuple = ()
    flatten: object = field(default=None, compare=False)
    walk: Walk | None = field(default=None, compare=False)
    lazy: object = field(default=None, compare=False)
    refit: object = field(default=None, compare=False)
    search: Search = Search()
    operands: bool = False
    operand_lists: tuple = ("items",)
    operand_spec: object = field(default=None, compare=False)
    max_operands: int = 0
    scene_walk: object = field(default=None, compare=False)

    def defaults(self) -> dict:
        return {p.name: p.default for p in self.params}


# not a structure but a search for one: raykernel.render anneals a hierarchy of the others (analysis/anneal.py)
AUTO = Kind("auto", "the hierarchy of structures found by simulated annealing (Arvo 1988) for this render's rays: "
            "groups, kinds and parameters chosen to minimise the cost model's predicted trace time", (
                Param("seconds", 30.0, "time budget of the search", float, 0.0, 1e7),
                Param("seed", 0, "random seed: the same seed finds the same hierarchy (within the budget)", int, 0,
                      2 ** 31 - 1),
                Param("memory", 0.0, "weight of memory: seconds of predicted time one MiB is worth", float, 0.0, 1e9),
                Param("evaluations", 0, "most candidates priced, 0: no limit (a limit that is reached first keeps "
                      "the search deterministic)", int, 0, 10 ** 9),
                Param("sample", 24, "candidates are traced at this many pixels along the longer side, the counts "
                      "scaled up", int, 2, 4096),
                Param("margin", 0.05, "the hierarchy found is kept only where it is predicted at least this "
                      "fraction faster than the best kind at its defaults, which is kept otherwise (smaller "
                      "gains are within the cost model's error)", float, 0.0, 0.9),
            ))


def is_auto(spec) -> bool:
    """Whether a spec asks for the annealed hierarchy (auto or auto(...))."""
    return isinstance(spec, str) and spec.strip().lower().split("(", 1)[0].strip() == AUTO.name


_SPEC = re.compile(r"^\s*([A-Za-z_][\w-]*)\s*(?:\((.*)\))?\s*$", re.S)


def parse(spec: str, kinds: dict) -> tuple[str, dict]:
    """'kind(key=value, ...)' -> (kind, parameters with defaults filled in), for the kinds given."""
    if not isinstance(spec, str):
        raise OptionError(f"an accelerator spec must be a string, got {spec!r}")
    m = _SPEC.match(spec)
    if not m:
        raise OptionError(f"accelerator spec {spec!r} is not of the form kind or kind(key=value, ...); "
                          f"kinds: {', '.join(kinds)}, auto")
    name, body = m.group(1).lower(), m.group(2)
    if name not in kinds and name != AUTO.name:
        raise OptionError(f"unknown accelerator {name!r} in spec {spec!r}; kinds: {', '.join(kinds)}, auto")
    kind = AUTO if name == AUTO.name else kinds[name]
    params = kind.defaults()
    allowed = {p.name: p for p in kind.params}
    given = set()
    if body is not None and body.strip():
        for item in body.split(","):
            if "=" not in item:
                raise OptionError(f"accelerator spec {spec!r}: expected key=value, got {item.strip()!r}")
            key, value = (s.strip() for s in item.split("=", 1))
            if key not in allowed:
                known = ", ".join(allowed) or "none"
                raise OptionError(f"accelerator spec {spec!r}: {name} has no parameter {key!r}; "
                                  f"its parameters: {known}")
            if key in given:
                raise OptionError(f"accelerator spec {spec!r}: {key} is given twice")
            given.add(key)
            params[key] = allowed[key].parse(value, spec)
    return name, params


def format_spec(name: str, params: dict, kinds: dict) -> str:
    """The canonical spec string: only parameters that differ from the defaults."""
    kind = AUTO if name == AUTO.name else kinds[name]
    changed = [f"{p.name}={_fmt(params[p.name])}" for p in kind.params if params.get(p.name, p.default) != p.default]
    return f"{name}({', '.join(changed)})" if changed else name


def _fmt(value) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    return str(value)


def describe(kinds: dict) -> str:
    """A plain-text list of every kind with its parameters and defaults."""
    lines = []
    for kind in [*kinds.values(), AUTO]:
        lines.append(f"{kind.name}: {kind.help}")
        for p in kind.params:
            lines.append(f"    {p.name}={_fmt(p.default)}  ({p._what()}) {p.help}")
    return "\n".join(lines)

