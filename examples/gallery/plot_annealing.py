"""
A hierarchy found by simulated annealing
========================================

Arvo and Kirk proposed searching for the best nesting of structures by simulated annealing.
``anneal`` does it: a state is a tree of groups, each with a structure; moves change a group's
kind, split, merge, move or wrap groups; the energy is the trace time the cost model predicts
from the exact counts of a small trial render. Here it searches the amusement park (rides of
many sizes, grouped by hand) for a bounded number of candidates, so the result is the same on
every machine. It prices every single structure and the scene's own hand-made hierarchy first,
starts from the best, and prints what it found.
"""

import matplotlib.pyplot as plt

import raykernel
from raykernel.analysis.anneal import anneal, figure

scene = raykernel.load("scene:park")
found = anneal(scene, evaluations=120, seconds=600, seed=0, options={"resolution": 128, "spd": True})
for name, energy in sorted(found.starts.items(), key=lambda kv: kv[1]):
    print(f"  start {name:36s} predicted {energy * 1e3:7.1f} ms")
print("started from:\n" + found.before)
print("found:\n" + found.after)
print(f"predicted trace {found.start_energy * 1e3:.1f} ms -> {found.energy * 1e3:.1f} ms "
      f"({found.evaluations} candidates, stopped: {found.stopped})")
figure(found)
plt.show()
