"""The engine: flattening a scene into arrays (building every aggregate), the traversal
driver that runs the aggregates' walks, threads over kernels, compile-time accounting.

    geo, build = flatten.flatten(scene, "bvh")
    t, kind, index, inst, counters = traverse.cast_rays(geo, origins, directions)
"""
