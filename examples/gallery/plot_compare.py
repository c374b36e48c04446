"""
Structures side by side
=======================

``raykernel compare`` renders every scene with every structure and tabulates the work each did:
tests per ray (N_IT), traversal steps per ray (N_TS), trace time, and the time the cost model
predicts from the counts alone (this machine's costs where ``raykernel calibrate`` has fitted
them, else the reference costs shipped with raykernel). The ray counts must agree across structures, and are checked. Here: five SPD scenes
at their smallest size and the teapot in a stadium, each through a uniform grid, a BVH and an
octree.
"""

import matplotlib.pyplot as plt
from rich.console import Console

from raykernel.analysis.compare import compare, compare_figure, tables
from raykernel.analysis.costmodel import current

scenes = ["spd:balls:1", "spd:gears:1", "spd:rings:1", "spd:tree:1", "spd:shells:1", "scene:stadium"]
cmp = compare(scenes, ["grid", "bvh", "octree"], spd=True, resolution=96, model=current(), command="docs gallery")
assert not cmp.disagreements, [d.text() for d in cmp.disagreements]
console = Console(width=80, force_terminal=False, color_system=None)
for t in tables(cmp, width=80):
    console.print(t)
compare_figure(cmp)
plt.show()
