"""The input checks of RayScene: which rays the query kernels cast, and the numpy checks that name
a bad argument (RayInputError).

    o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax)   # flat float64 (N, 3), (N,) or (1,)
    if not valid_ray(ox, oy, oz, dx, dy, dz):       # in a kernel, per ray
        continue            # left out of the chunk's rays.cast
    check_ray_values(o, d)      # RayInputError naming the first ray valid_ray refuses
    o = read_only(o)            # as the kernels take the rays: one compiled kernel for any caller's flags
    v = real_array(vertices, "vertices")            # float64, or RayInputError naming the argument
    v = writable(v)             # as the kernels take a mesh's arrays (a copy where v is read-only)

The kernels cast the rays whose origin lies within +-MAX_COORDINATE and whose
direction's largest component lies between MIN_SIZE and MAX_COORDINATE
(geometry/primitives.py: the range raykernel answers exactly; NaN and
infinities fail too).

RayScene checks the values of its rays inside the kernels, as each ray is
read, rather than with numpy before them: the whole-array tests pass over
every ray's memory again, a sizeable share of a coherent query's time, where
the kernels' own test costs a few comparisons of numbers already loaded. A kernel skips a ray that fails and leaves it out of its
`rays.cast` counter; RayScene then runs the numpy checks over the rays to
raise the error that names the first bad one (check_ray_values).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import RayKernelError
from ..geometry.config import njit
from ..geometry.primitives import MAX_COORDINATE, MIN_SIZE


class RayInputError(RayKernelError, ValueError):
    """Rays or geometry given to RayScene are not valid; the message names the argument.

    It is a ValueError too.
    """


@njit(inline="always")
def valid_ray(ox, oy, oz, dx, dy, dz):
    """The origin and direction are in range (NaN fails every comparison)."""
    inside = abs(ox) <= MAX_COORDINATE and abs(oy) <= MAX_COORDINATE and abs(oz) <= MAX_COORDINATE
    bounded = abs(dx) <= MAX_COORDINATE and abs(dy) <= MAX_COORDINATE and abs(dz) <= MAX_COORDINATE
    return inside and bounded and (abs(dx) >= MIN_SIZE or abs(dy) >= MIN_SIZE or abs(dz) >= MIN_SIZE)


# ----------------------------------------------------------------- numpy checks, before the kernels

def real_array(value, name: str) -> np.ndarray:
    """`value` as a float64 array (no copy when it is one), or RayInputError naming it unless its dtype is real."""
    arr = np.asarray(value)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise RayInputError(f"{name} must be an array of real numbers, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def vectors(value, name: str, finite: bool = True) -> np.ndarray:
    """(..., 3) real array, finite unless finite=False; one (3,) vector is one row, (1, 3)."""
    arr = real_array(value, name)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise RayInputError(f"{name} must have shape (..., 3), e.g. (N, 3) or (3,), got {arr.shape}")
    if finite:
        _finite(arr, name)
    return arr


def _finite(arr: np.ndarray, name: str, offset: int = 0) -> None:
    if not np.isfinite(arr).all():        # (whole-array test first: reductions along rows are slow)
        flat = arr.reshape(-1, 3)
        i = int(np.flatnonzero(~np.all(np.isfinite(flat), axis=1))[0])
        raise RayInputError(f"{name}[{offset + i}] is not finite: {flat[i].tolist()}")


def _interval(value, name: str, shape: tuple) -> np.ndarray:
    """tmin or tmax flat, one per ray, or one number as a (1,) array: the kernels then read it for every ray."""
    if isinstance(value, float):        # one number, the common call: no array machinery (a few us a call)
        if value != value:
            raise RayInputError(f"{name}[0] is NaN")
        return np.array([value])
    arr = real_array(value, name)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    else:
        try:
            arr = np.broadcast_to(arr, shape)
        except ValueError:
            raise RayInputError(f"{name} must be a number or have shape {shape}, got {arr.shape}") from None
        arr = np.ascontiguousarray(arr).reshape(-1)
    if np.isnan(arr).any():
        raise RayInputError(f"{name}[{int(np.flatnonzero(np.isnan(arr))[0])}] is NaN")
    return arr


def check_rays(origins, directions, tmin=0.0, tmax=np.inf, budget=None):
    """Checked float64 copies, flat: origins (N, 3), directions (N, 3), tmin and tmax ((N,), or
    (1,) for one number), and the rays' shape: the leading dimensions of origins and directions
    broadcast together ((N,) for (N, 3) arrays, (H, W) for an image of rays, (1,) for one (3,) ray).
    The values of origins and directions are checked by the kernels as they cast (rayinput.py);
    check_ray_values names the first bad ray. budget(n, copied): called before anything is
    copied, with the rays' number and the bytes their copies take (rayqueries._budget)."""
    if _plain(origins, directions):
        o, d, shape = origins, directions, origins.shape[:1]      # the common call: nothing to broadcast
        if budget is not None:
            budget(len(o), 0)
    else:
        o = vectors(origins, "origins", finite=False)
        d = vectors(directions, "directions", finite=False)
        try:
            shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1])
        except ValueError:
            raise RayInputError(f"origins and directions differ in length: {o.shape[:-1]} vs "
                                f"{d.shape[:-1]}") from None
        if budget is not None:
            budget(math.prod(shape), 64 * math.prod(shape))    # origins, directions, tmin, tmax
        o = np.broadcast_to(o, shape + (3,)).reshape(-1, 3)
        d = np.broadcast_to(d, shape + (3,)).reshape(-1, 3)
    lo = _interval(tmin, "tmin", shape)
    hi = _interval(tmax, "tmax", shape)
    bad = lo > hi
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise RayInputError(f"tmin > tmax for ray {i}: {lo[i if len(lo) > 1 else 0]} > {hi[i if len(hi) > 1 else 0]}")
    return np.ascontiguousarray(o), np.ascontiguousarray(d), lo, hi, shape


def read_only(arr: np.ndarray) -> np.ndarray:
    """A read-only view of arr. numba compiles a kernel once for each type of its arguments, and a
    read-only array is a type of its own: the query kernels only read the rays, so they are given
    them read-only whatever the caller passed (a broadcast origin, a memory-mapped file), and
    compile once, not once for each mix of flags. (setflags: numpy's flags object is slower.)"""
    view = arr.view()
    view.setflags(write=False)
    return view


def writable(arr: np.ndarray) -> np.ndarray:
    """arr, or a copy of it where it is read-only: a mesh's arrays, which a scene keeps and its
    kernels read as they read the arrays of a scene raykernel built (writable), so that a mesh read
    from a memory-mapped or frozen array compiles no kernels of its own (see read_only)."""
    return arr if arr.flags.writeable else arr.copy()


def _plain(origins, directions) -> bool:
    """Both are C-contiguous float64 ndarrays of the same shape (N, 3): check_rays then skips numpy's
    broadcasting machinery, most of a small batch's time."""
    return (type(origins) is np.ndarray and type(directions) is np.ndarray and origins.dtype == np.float64
            and directions.dtype == np.float64 and origins.ndim == 2 and origins.shape == directions.shape
            and origins.shape[1] == 3 and origins.flags.c_contiguous and directions.flags.c_contiguous)


def check_ray_values(o: np.ndarray, d: np.ndarray, offset: int = 0) -> None:
    """Raise RayInputError naming the first ray (of check_rays' flat arrays) that is not finite, has
    a zero direction or lies outside the range raykernel answers: what valid_ray refuses in the kernels.
    offset: the number of the first row, where these rays are a part of a larger batch."""
    _finite(o, "origins", offset)
    _finite(d, "directions", offset)
    zero = (d[:, 0] == 0.0) & (d[:, 1] == 0.0) & (d[:, 2] == 0.0)
    if zero.any():
        raise RayInputError(f"directions[{offset + int(np.flatnonzero(zero)[0])}] has zero length")
    far = np.any(np.abs(o) > MAX_COORDINATE, axis=1)
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise RayInputError(f"origins[{offset + i}] {o[i].tolist()} lies beyond +-{MAX_COORDINATE:g}, the range raykernel "
                            f"answers exactly")
    longest = np.max(np.abs(d), axis=1)
    odd = (longest < MIN_SIZE) | (longest > MAX_COORDINATE)
    if odd.any():
        i = int(np.flatnonzero(odd)[0])
        raise RayInputError(f"directions[{offset + i}] {d[i].tolist()}: its largest component must lie between {MIN_SIZE:g} "
                            f"and {MAX_COORDINATE:g} (scale the direction; only its way matters)")

