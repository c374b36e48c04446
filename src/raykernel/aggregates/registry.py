"""The registry: every aggregate kind, as its module declares it, and what the engine builds from them.

    from raykernel.aggregates.registry import KINDS, parse_spec
    name, params = parse_spec("bvh(leaf=2)")
    KINDS[name].flatten(builder, params, refs, bounds, name, box)       # what engine/flatten.py calls
    walk_step(code, geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)  # the driver's one call to a walk

MODULES lists the kinds' modules; each declares its kind once, in KIND (or
KINDS, for several), with its walk (WALK), its lazy part and what the searches
may try of it (spec.Kind, walk.Walk). Everything else is derived here: the
walks by code, the Geometry fields they own, the counter names, the driver's
dispatch to the walks and to the operators' resolve, the lazy kinds and the
annealer's candidates. Adding a kind is adding its module to MODULES
(docs/adding-a-kind.md).
"""

from __future__ import annotations

from ..geometry import counters as C
from ..geometry.config import njit
from . import bruteforce, bvh, csg, grid, hgrid, hybrid, kdtree, lazyoctree, octree, rc, spec
from .walk import KEYED_FIELDS, Walk

# in this order the kinds are listed (raykernel accels) and offered to the annealer
MODULES = (bvh, grid, hgrid, octree, hybrid, bruteforce, lazyoctree, rc, csg, kdtree)


def kinds_of(modules) -> dict:
    """name -> Kind of every kind the modules declare (KIND, or KINDS for several), in their order."""
    declared = [kind for module in modules for kind in getattr(module, "KINDS", None) or (module.KIND,)]
    kinds = {kind.name: kind for kind in declared}
    if len(kinds) != len(declared):
        raise ImportError("registry: a kind name is declared twice")
    return kinds


def walks_of(kinds: dict) -> tuple[Walk, ...]:
    """The walks the kinds are stored with, by code: 0, 1, ... below counters.MAX_WALKS, none twice."""
    walks = {id(k.walk): k.walk for k in kinds.values()}.values()
    walks = tuple(sorted(walks, key=lambda w: w.code))
    if [w.code for w in walks] != list(range(len(walks))) or len(walks) > C.MAX_WALKS:
        raise ImportError(f"registry: walk codes must be 0, 1, ... below {C.MAX_WALKS}, none twice; got "
                          f"{[(w.name, w.code) for w in walks]}")
    return walks


KINDS = kinds_of(MODULES)
WALKS = walks_of(KINDS)
WALK_NAMES = tuple(w.name for w in WALKS)
FIELDS = KEYED_FIELDS + tuple(f for w in WALKS for f in w.fields)     # the Geometry fields the walks own
COUNTER_NAMES = C.names((w.code, w.name, [name for name, _ in w.counters]) for w in WALKS)
# every walk's own counters with the cost-model features they are priced as (analysis/costmodel.py)
WALK_COUNTERS = tuple(c for w in WALKS for c in w.counters)
LAZY_KINDS = tuple(k for k in KINDS.values() if k.lazy is not None)
EMPTY = bruteforce.KIND         # what an aggregate with no items is stored as, whatever its kind
DEFAULT = bvh.KIND.name         # the structure of groups that name none (render's accel="bvh")
SCENE_WALKS = tuple(k.scene_walk for k in KINDS.values() if k.scene_walk is not None)
if len(SCENE_WALKS) != 1:
    raise ImportError("registry: one kind declares the walk of a whole scene (spec.Kind.scene_walk)")
SCENE_WALK = SCENE_WALKS[0]     # the engine hands it every scene that is one such aggregate (engine/traverse.py)
OPERATORS = tuple(w for w in WALKS if w.resolve is not None)
if len(OPERATORS) > 1:
    raise ImportError("registry: the driver counts one operator walk's crossings (collect.py)")
# the column the driver counts operand crossings in: the operator walk's first own counter
CROSSINGS = C.own_columns(OPERATORS[0].code, 1)[0] if OPERATORS else C.N_COUNTERS - 1

# the annealer's (analysis/anneal.py): kinds it starts from at their defaults, other specs it starts
# from, every spec it may give a group, and the kinds offered only to small groups
START_SPECS = tuple(k.name for k in KINDS.values() if k.search.start)
START_VARIANTS = tuple(v for k in KINDS.values() for v in k.search.variants)
CANDIDATES = tuple(c for k in KINDS.values() for c in k.search.candidates)
SMALL_ONLY = {k.name: k.search.max_items for k in KINDS.values() if k.search.max_items}


def parse_spec(text: str) -> tuple[str, dict]:
    """'kind(key=value, ...)' -> (kind, parameters with defaults filled in); OptionError if not a spec."""
    return spec.parse(text, KINDS)


def format_spec(name: str, params: dict) -> str:
    """The canonical spec string: only parameters that differ from the defaults."""
    return spec.format_spec(name, params, KINDS)


def describe() -> str:
    """A plain-text list of every kind with its parameters and defaults."""
    return spec.describe(KINDS)


def _steps(walks):
    """walk_step(code, geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt): the step of the walk of
    `code` (walk.py's contract), as a chain of compares numba inlines into the driver."""
    first, call = walks[0].code, walks[0].step
    if len(walks) == 1:
        @njit(inline="always", cache=False)
        def last(code, geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
            return call(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)
        return last
    rest = _steps(walks[1:])

    @njit(inline="always", cache=False)
    def chain(code, geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
        if code == first:
            return call(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)
        return rest(code, geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)
    return chain


def _resolves(walks):
    """walk_resolve(code, geo, node, region, shift, operand, ws, cnt): the resolve of the operator
    walk of `code` (collect.py's contract); 0 surfaces for a scene without operators."""
    if not walks:
        @njit(inline="always", cache=False)
        def none(code, geo, node, region, shift, operand, ws, cnt):
            return 0
        return none
    first, call, rest = walks[0].code, walks[0].resolve, _resolves(walks[1:])

    @njit(inline="always", cache=False)
    def chain(code, geo, node, region, shift, operand, ws, cnt):
        if code == first:
            return call(geo, node, region, shift, operand, ws, cnt)
        return rest(code, geo, node, region, shift, operand, ws, cnt)
    return chain


walk_step = _steps(WALKS)
walk_resolve = _resolves(OPERATORS)
