"""Ray casting for Python users: RayScene, the mesh kernel and hit surfaces.

    rs = rayscene.RayScene.from_mesh(vertices, faces)      # also raykernel.RayScene
"""
