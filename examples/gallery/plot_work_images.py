"""
Where the work goes: the pathological scenes
============================================

Haines's pathological scenes, each rendered by several structures with a work layer kept
(``compare(..., work="tests.total")``): every sample's count of ray-primitive tests, over its
whole ray tree. Top row: each structure on one shared, logarithmic scale. Bottom row: each
structure's log2 ratio against the first (red: more work, blue: less), and which structure did
the least work at each sample.

The teapot in a stadium is the octree's worst case: its few deep cells around the teapot are
crossed by every ray that sees the teapot. Haines's hybrid (an octree with Goldsmith-Salmon
BVHs in its problem voxels) puts the teapot's triangles back into one tight hierarchy.
"""

import matplotlib.pyplot as plt

from raykernel.analysis.compare import compare
from raykernel.analysis.workimages import figure, work_images


def show(scene, accels):
    cmp = compare([scene], accels, resolution=96, model=None, work="tests.total", command="docs gallery")
    assert not cmp.disagreements, [d.text() for d in cmp.disagreements]
    w = work_images(cmp, scene)
    for run in cmp.runs:
        print(f"{run.accel:8s} tests {int(run.work.sum()):>12,}   least work at {w.shares[run.accel]:6.1%} of the samples")
    figure(w)
    plt.show()


# %%
# The teapot in the stadium
show("scene:stadium", ["octree", "hybrid", "grid", "bvh"])

# %%
# The satellite: a small satellite beside the earth, each at its real size
show("scene:satellite", ["octree", "grid", "bvh"])

# %%
# The sun: houses, trees and roads lit by a sun of its real size and distance
show("scene:sun", ["octree", "grid", "bvh"])
