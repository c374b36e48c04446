"""
Heckbert's business-card ray tracer
===================================

Paul Heckbert's minimal ray tracer, printed in the newsletter, reproduced: its scene
(``example:heckbert``) and its shading model (``shading="heckbert"``, three levels deep),
rendered with raykernel's kernels.
"""

import matplotlib.pyplot as plt

import raykernel

scene = raykernel.load("example:heckbert")
result = raykernel.render(scene, resolution=256, shading="heckbert", max_depth=3)
print(f"{result.stats['rays.total']:,} rays, {result.stats['tests.total']:,} sphere tests")
fig, ax = plt.subplots(figsize=(5, 5))
ax.imshow(result.image.clip(0, 1))
ax.set_axis_off()
plt.show()
