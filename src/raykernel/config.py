"""How every compiled kernel is built: `from .config import njit`.

All kernels share one decorator so that caching, the GIL and fast-math are
the same everywhere. fastmath stays off: the tests compare structures to
1e-9 relative, and the counts must not depend on reassociation.
"""

import numba

KERNEL_OPTIONS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


def njit(*args, **kwargs):
    """numba.njit with the project's options; extra keywords override them."""
    options = dict(KERNEL_OPTIONS, **kwargs)
    if args and callable(args[0]):
        return numba.njit(**options)(args[0])
    return numba.njit(*args, **options)
