"""
The structure drawn over the image
==================================

``raykernel render scene:stadium --accel hybrid --draw 3`` draws the boxes of the structure,
three levels deep, over the render: Haines's octree with BVHs in its problem voxels, around the
teapot in the stadium. Boxes are drawn with the depth test against the image, so those behind
surfaces are hidden.
"""

import matplotlib.pyplot as plt

import raykernel
from raykernel.rendering.overlay import draw_structure

scene = raykernel.load("scene:stadium")
image = raykernel.render(scene, accel="hybrid", resolution=320).image
drawn = draw_structure(image, scene, "hybrid", depth=3)
fig, ax = plt.subplots(figsize=(6, 6))
ax.imshow(drawn.clip(0, 1))
ax.set_axis_off()
plt.show()
