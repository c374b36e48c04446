"""raykernel as trimesh's ray engine: ``mesh.ray = raykernel.trimesh.RayMeshIntersector(mesh)``.

RayMeshIntersector says what each query answers (its code is raykernel.casting.trimeshray)::

    import trimesh, raykernel.trimesh
    mesh = trimesh.creation.icosphere()
    mesh.ray = raykernel.trimesh.RayMeshIntersector(mesh)
    index_tri, index_ray = mesh.ray.intersects_id(origins, directions)
    mesh.contains(points)          # trimesh's own queries now cast with raykernel
"""

from .casting.trimeshray import RayMeshIntersector

__all__ = ["RayMeshIntersector"]
