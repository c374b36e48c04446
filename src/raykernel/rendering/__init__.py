"""The Whitted-style renderer, its statistics and image files.

    result = render.render(scene, accel="bvh", spd=True)   # also raykernel.render
    imageio.save_image(result.image, "out.exr")
"""
