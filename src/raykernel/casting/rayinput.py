"""Which rays the query kernels cast: a finite origin and a finite, non-zero direction.

    if not valid_ray(ox, oy, oz, dx, dy, dz):
        continue            # left out of the chunk's rays.cast

RayScene checks the values of its rays inside the kernels, as each ray is
read, rather than with numpy before them: the whole-array tests cost about
7 ms per million rays on one thread, a fifth of a coherent query's time at 2
threads, where the kernels' own test costs a few comparisons of numbers
already loaded. A kernel skips a ray that fails and leaves it out of its
`rays.cast` counter; RayScene then runs the numpy checks over the rays to
raise the error that names the first bad one (rayscene.check_ray_values).
"""

from ..geometry.config import njit

_HUGE = 1.7976931348623157e308      # the largest finite double: NaN and +-inf fail abs(x) <= _HUGE


@njit(inline="always")
def valid_ray(ox, oy, oz, dx, dy, dz):
    """The origin and direction are finite and the direction is not (0, 0, 0)."""
    finite = (abs(ox) <= _HUGE and abs(oy) <= _HUGE and abs(oz) <= _HUGE and abs(dx) <= _HUGE and abs(dy) <= _HUGE
              and abs(dz) <= _HUGE)
    return finite and (dx != 0.0 or dy != 0.0 or dz != 0.0)
