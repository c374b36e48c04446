"""The brute-force list: every child tested against every ray, no structure at all.

    spec "list"

Stored as a range of Geometry.refs: agg_start is the first reference,
agg_count how many. It owns no fields and no walk: the driver (traverse.py)
tests a range itself. Every aggregate with no items is stored as a list.
"""

from ..scene.accel import Kind

CODE = 0
FIELDS = ()


def flatten(builder, params, refs, bounds, name, box):
    first = builder.flat.add_refs(refs)
    agg = builder.flat.add_aggregate(CODE, first, len(refs), box)
    return agg, {"nodes": 0, "inner": 0, "leaves": 1, "empty_leaves": int(len(refs) == 0), "refs": len(refs),
                 "bytes": refs.nbytes}


KIND = Kind("list", "brute force: test every child", flatten=flatten)
