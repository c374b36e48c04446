"""Which rays the query kernels cast: an origin within +-MAX_COORDINATE and a direction whose
largest component lies between MIN_SIZE and MAX_COORDINATE (geometry/primitives.py: the range
raykernel answers exactly; NaN and infinities fail too).

    if not valid_ray(ox, oy, oz, dx, dy, dz):
        continue            # left out of the chunk's rays.cast

RayScene checks the values of its rays inside the kernels, as each ray is
read, rather than with numpy before them: the whole-array tests pass over
every ray's memory again, a sizeable share of a coherent query's time, where
the kernels' own test costs a few comparisons of numbers already loaded. A kernel skips a ray that fails and leaves it out of its
`rays.cast` counter; RayScene then runs the numpy checks over the rays to
raise the error that names the first bad one (rayscene.check_ray_values).
"""

from ..geometry.config import njit
from ..geometry.primitives import MAX_COORDINATE, MIN_SIZE


@njit(inline="always")
def valid_ray(ox, oy, oz, dx, dy, dz):
    """The origin and direction are in range (NaN fails every comparison)."""
    inside = abs(ox) <= MAX_COORDINATE and abs(oy) <= MAX_COORDINATE and abs(oz) <= MAX_COORDINATE
    bounded = abs(dx) <= MAX_COORDINATE and abs(dy) <= MAX_COORDINATE and abs(dz) <= MAX_COORDINATE
    return inside and bounded and (abs(dx) >= MIN_SIZE or abs(dy) >= MIN_SIZE or abs(dz) >= MIN_SIZE)
