"""Acceleration structures: one module per kind, each with its builder, its flat layout and its walk.

    from raykernel.aggregates.registry import KINDS, parse_spec     # every kind, the spec language
    from raykernel.aggregates import bvh                            # one kind's builder and walk

registry.py collects the kinds their modules declare (spec.Kind, walk.Walk); a large
kind keeps its builder or walks in modules of their own (rc: rcbuild, rclazy, rcwalk;
octree: octbuild, octwalk, octpoint);
walk.py is the contract between a walk and the driver (engine/traverse.py);
docs/adding-a-kind.md walks through adding one.
"""
