"""
Ray casting a mesh, as trimesh and Open3D users do
==================================================

``RayScene`` builds a BVH over a triangle mesh and answers closest hits (distance, triangle,
barycentric coordinates, normal) for any rays; ``camera_rays`` makes a pinhole camera's.
Here: the depth and the normals of a bumped icosphere, and which points of a grid lie inside it.
"""

import matplotlib.pyplot as plt
import numpy as np
import trimesh

from raykernel import RayScene, camera_rays

mesh = trimesh.creation.icosphere(subdivisions=5)
v = mesh.vertices
mesh.vertices = v * (1 + 0.08 * np.sin(6 * v[:, [0]]) * np.cos(5 * v[:, [1]]))
scene = RayScene.from_trimesh(mesh)
print(scene)

origins, directions = camera_rays(eye=(0, -3.2, 1.2), look_at=(0, 0, 0), fov=40, width=256, height=256)
hits = scene.intersect(origins, directions)       # shaped as the rays: (256, 256)
hit = np.isfinite(hits.t)
depth = np.where(hit, hits.t, np.nan)
normal = np.where(hit[..., None], 0.5 * (hits.normal + 1), 1.0)

xs = np.linspace(-1.2, 1.2, 121)
grid = np.stack(np.meshgrid(xs, xs, [0.0], indexing="xy"), axis=-1).reshape(-1, 3)
inside = scene.contains(grid).reshape(121, 121)
print(f"{hit.sum():,} of {hit.size:,} rays hit; {inside.sum():,} of {inside.size:,} points inside")

fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
axes[0].imshow(depth, cmap="magma_r")
axes[0].set_title("depth (t)")
axes[1].imshow(normal)
axes[1].set_title("normal")
axes[2].imshow(inside, origin="lower", cmap="Greys", extent=(-1.2, 1.2, -1.2, 1.2))
axes[2].set_title("contains, the z = 0 plane")
for ax in axes[:2]:
    ax.set_axis_off()
fig.tight_layout()
plt.show()
