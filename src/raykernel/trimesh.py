"""raykernel as trimesh's ray engine: `mesh.ray = raykernel.trimesh.RayMeshIntersector(mesh)`.

See raykernel.casting.trimeshray for what each query answers.
"""

from .casting.trimeshray import RayMeshIntersector

__all__ = ["RayMeshIntersector"]
