"""The brute-force list: every child tested against every ray, no structure at all.

    spec "list"

Stored as a range of Geometry.refs: agg_start is the first reference,
agg_count how many. Its walk is that range: START answers it whole, and the
driver tests it. Every aggregate with no items is stored as a list.
"""

from ..geometry.config import njit
from .spec import Kind, Search
from .walk import FI_AGG, Walk, answer, one_cell


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """The list's references, refs[a:a + agg_count] (walk.py's step contract)."""
    return answer(sp, a, a + geo.agg_count[ws.frame_i[f, FI_AGG]], ray, best_t)


def refit_aggregate(flat, agg, memo, refs, old_bounds, bounds, params, threshold):
    """A list has no boxes of its own: it is kept whatever its items' moves (its box is set anew)."""
    return 0


def flatten(builder, params, refs, bounds, name, box):
    first = builder.flat.add_refs(refs)
    agg = builder.flat.add_aggregate(CODE, first, len(refs), box)
    return agg, {"nodes": 0, "inner": 0, "leaves": 1, "empty_leaves": int(len(refs) == 0), "refs": len(refs),
                 "bytes": refs.nbytes}


CODE = 0
WALK = Walk(code=CODE, name="list", step=walk_step,
            cells=lambda geo, a: one_cell(geo.agg_bounds[a], geo.agg_start[a], geo.agg_count[a]))
# the annealer offers it to groups of at most 16 primitives only: beyond that every structure beats it
KIND = Kind("list", "brute force: test every child", flatten=flatten, walk=WALK, refit=refit_aggregate,
            search=Search(candidates=("list",), max_items=16))
