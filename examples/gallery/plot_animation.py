"""
A frame of an animation
=======================

A moon orbits a planet, a ring of rocks turns the other way and the camera rises
(examples/orbit.json). Each frame moves the instances and rebuilds only the hierarchy above
them (incremental hierarchies); ``raykernel animate examples/orbit.json --frames 48 -o orbit.mp4``
renders the whole film, on Dask with ``--dask``.
"""

from pathlib import Path

import matplotlib.pyplot as plt

import raykernel

# examples/ (sphinx-gallery runs each script in its own folder, without __file__)
EXAMPLES = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd().parent
scene = raykernel.read_json(EXAMPLES / "orbit.json")
anim = scene.animation
times = anim.times(frames=3)
fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
for ax, t in zip(axes, times):
    anim.at(scene, t)
    result = raykernel.render(scene, accel="bvh", resolution=200)
    ax.imshow(result.image.clip(0, 1))
    ax.set_title(f"t = {t:.1f} s")
    ax.set_axis_off()
fig.tight_layout()
plt.show()
