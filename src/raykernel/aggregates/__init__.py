"""Acceleration structures: one module per kind, each with its builder, its flat layout and its walk.

    from raykernel.aggregates import WALKS
    from raykernel.scene.accel import KINDS
    KINDS["bvh"].flatten(builder, params, refs, bounds, name, box)   # what flatten.py calls

The registry. KINDS (raykernel.scene.accel) maps each spec name to its Kind: help,
parameters, and `flatten`, which builds the aggregate into the flat arrays
and returns (aggregate index, build statistics). WALKS lists the modules
that own a walk, each with its CODE (agg_kind and stack-entry kind), the
Geometry FIELDS it stores and its compiled `step`, which the driver
(traverse.py) calls, and, if it counts work of its own, COUNTERS ((name,
cost-model feature or None), in columns it claims with counters.claim) and
`stats_rows(stats)`, its rows of the statistics table; kinds without a walk of their own store themselves
with another's (hgrid as grids, hybrid and lazyoctree as octrees).
docs/adding-a-kind.md is the checklist for a new one.
"""

from ..geometry import counters as C
from ..scene.accel import register
from . import bruteforce, bvh, csg, grid, hgrid, hybrid, lazyoctree, octree, rc

WALKS = (bruteforce, bvh, grid, octree, rc, csg)

for _module in (bruteforce, bvh, grid, hgrid, rc, octree, hybrid, lazyoctree, csg):
    for _kind in getattr(_module, "KINDS", None) or (_module.KIND,):     # a module may hold several kinds
        register(_kind)

if sorted(w.CODE for w in WALKS) != list(range(len(WALKS))):
    raise ImportError("aggregates: walk CODEs must be 0, 1, ... with none twice")
if len(WALKS) > C.MAX_WALKS:
    raise ImportError(f"aggregates: more walks than the {C.MAX_WALKS} counter columns of geometry/counters.py")
# the walks by CODE, named as their kinds (the brute-force module's kind is list); their counters
WALK_NAMES = tuple(m.KIND.name if hasattr(m, "KIND") else m.__name__.rsplit(".", 1)[1]
                   for m in sorted(WALKS, key=lambda m: m.CODE))
for _code, _walk in enumerate(WALK_NAMES):
    C.NAMES[C.WALK_ENTRIES + _code] = f"walk.{_walk}.entries"
    C.NAMES[C.WALK_BOUNDS + _code] = f"walk.{_walk}.bounds"
    C.NAMES[C.WALK_STEPS + _code] = f"walk.{_walk}.steps"
# the walks' own counters, and the cost-model features they are priced as (analysis/costmodel.py)
WALK_COUNTERS = tuple(c for w in WALKS for c in getattr(w, "COUNTERS", ()))
if {name for name, _ in WALK_COUNTERS} - set(C.NAMES.values()):
    raise ImportError("aggregates: a walk's COUNTERS must be claimed (counters.claim) when its module loads")
