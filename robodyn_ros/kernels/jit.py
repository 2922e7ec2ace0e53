"""``njit`` for the kernels that must run even without numba: numba's when it can be imported,
else a decorator that returns the function unchanged, so the same source runs as plain Python
(slower, the same operations).

Used by the tree algorithms (:mod:`.tree`), the PFL law (:mod:`.pfl`), the command profiles
(:mod:`.profiles`) and the recorder's loops (:mod:`.records`): each is the one implementation of
its physics, which the Python side calls whether or not the compiled systems are in use
(``ROBODYN_BACKEND=numpy`` turns those off; these stay compiled while numba is installed).
"""
from __future__ import annotations

try:
    from numba import njit
    NUMBA = True
except ImportError:   # no numba: the kernels below run as Python functions
    NUMBA = False

    def njit(*args, **_):
        """``@njit(...)`` / ``@njit`` without numba: the function itself."""
        if len(args) == 1 and callable(args[0]):
            return args[0]
        return lambda f: f

__all__ = ['njit', 'NUMBA']
