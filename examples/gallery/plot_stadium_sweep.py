"""
The teapot in a stadium, swept
==============================

Haines's pathological scene: a teapot at the centre of a stadium that grows around it
(``ratio``: the stadium's size over the teapot's). With one structure over the whole scene
(``teapot_bvh=0``) the whole teapot falls into one grid cell as the stadium grows, and into one
octree cell once the octree's depth limit can no longer separate its facets; the BVH adapts.
Haines's fix puts a bounding volume hierarchy into the problem voxel; here that is one nesting
away (``teapot_bvh=1`` gives the teapot its own BVH inside whatever is built over the stadium).

``raykernel sweep 'scene:stadium:ratio={ratio},teapot_bvh={tb}' --param ratio=1,100,10000,1000000
--param tb=0,1 --accel grid --accel bvh --accel octree --spd --resolution 64 --plot sweep.png``
"""

import matplotlib.pyplot as plt

from raykernel.analysis.compare import sweep, sweep_figure

cmp = sweep("scene:stadium:ratio={ratio},teapot_bvh={tb}",
            {"ratio": ["1", "100", "10000", "1000000"], "tb": ["0", "1"]},
            ["grid", "bvh", "octree"], spd=True, resolution=64, command="docs gallery")
assert not cmp.disagreements, [d.text() for d in cmp.disagreements]
for run in cmp.runs:
    print(f"{run.scene:45s} {run.accel:7s} tests/ray {run.stats['tests.per_ray']:9.1f}")
sweep_figure(cmp)
plt.show()
