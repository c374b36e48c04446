"""The limits a scene must keep, which the kernels are built for: numbers only, no numba.

    from raykernel.geometry.limits import MAX_COORDINATE, MIN_SIZE, MAX_NESTING

The scene model checks scenes against them without loading any kernel; the kernels freeze them.
"""

# The range raykernel answers exactly: every coordinate (of a primitive in its group's space, an
# instance's box in its parent's, a camera, a light, a ray's origin) within +-MAX_COORDINATE, and
# every size (a sphere's radius, a polygon's or triangle's extent, a ray direction's length) at
# least MIN_SIZE where it is not zero. Within it the float64 tests' products of three
# coordinates neither overflow nor lose the hit to underflow (they do near 1e100 and 1e-110),
# and the float32 node boxes (widebvh.py) hold every bound; outside it scenes and rays are refused.
MAX_COORDINATE = 1e30
MIN_SIZE = 1e-30

# aggregates along any path from the root, the root included: the deepest level a group may sit at (the
# root is level 1, each group within a group or an instance one more); the driver keeps one frame for each
MAX_NESTING = 16
